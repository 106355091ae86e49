// In-process transport pair: two bounded byte pipes guarded by a mutex and condition variables.
#include "eyesim/transport/inproc.hpp"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <mutex>
#include <vector>

namespace eyesim::transport {
namespace {

/// One direction: a bounded byte ring, filled at construction (no allocation afterwards).
struct Pipe {
    explicit Pipe(std::size_t capacity) : ring(capacity) {}
    std::mutex mutex;
    std::condition_variable readable;
    std::condition_variable writable;
    std::vector<std::uint8_t> ring;
    std::size_t head = 0;
    std::size_t size = 0;
    bool writer_closed = false;
    bool reader_closed = false;
};

struct Shared {
    explicit Shared(std::size_t capacity) : a_to_b(capacity), b_to_a(capacity) {}
    Pipe a_to_b;
    Pipe b_to_a;
};

class InprocEndpoint final : public Transport {
public:
    InprocEndpoint(std::shared_ptr<Shared> shared, bool is_a)
        : shared_(std::move(shared)),
          out_(is_a ? shared_->a_to_b : shared_->b_to_a),
          in_(is_a ? shared_->b_to_a : shared_->a_to_b),
          name_(is_a ? "inproc://a" : "inproc://b") {}
    ~InprocEndpoint() override { close(); }
    InprocEndpoint(const InprocEndpoint&) = delete;
    InprocEndpoint& operator=(const InprocEndpoint&) = delete;

    IoResult read(std::span<std::uint8_t> out, int timeout_ms) override {
        std::unique_lock lock(in_.mutex);
        if (closed_) return {0, IoStatus::closed};
        const auto ready = [&] { return in_.size > 0 || in_.writer_closed; };
        if (!ready()) {
            if (timeout_ms <= 0 || !in_.readable.wait_for(lock, std::chrono::milliseconds(timeout_ms), ready))
                return {0, IoStatus::timeout};
        }
        if (in_.size == 0) return {0, IoStatus::closed};
        const std::size_t cap = in_.ring.size();
        const std::size_t n = std::min(out.size(), in_.size);
        for (std::size_t i = 0; i < n; ++i) out[i] = in_.ring[(in_.head + i) % cap];
        in_.head = (in_.head + n) % cap;
        in_.size -= n;
        in_.writable.notify_all();
        return {n, IoStatus::ok};
    }

    IoResult write(std::span<const std::uint8_t> data, int timeout_ms) override {
        std::unique_lock lock(out_.mutex);
        std::size_t done = 0;
        const std::size_t cap = out_.ring.size();
        const auto deadline = std::chrono::steady_clock::now() + std::chrono::milliseconds(std::max(timeout_ms, 0));
        while (done < data.size()) {
            if (closed_) return {done, IoStatus::closed};
            if (out_.reader_closed) return {done, IoStatus::closed};
            const std::size_t free = cap - out_.size;
            if (free == 0) {
                if (out_.writable.wait_until(lock, deadline) == std::cv_status::timeout && out_.size == cap)
                    return {done, IoStatus::timeout};
                continue;
            }
            const std::size_t n = std::min(free, data.size() - done);
            for (std::size_t i = 0; i < n; ++i) out_.ring[(out_.head + out_.size + i) % cap] = data[done + i];
            out_.size += n;
            done += n;
            out_.readable.notify_all();
        }
        return {done, IoStatus::ok};
    }

    bool connected() const override {
        std::scoped_lock lock(in_.mutex);
        return !closed_ && !in_.writer_closed;
    }

    void close() override {
        {
            std::scoped_lock lock(out_.mutex);
            out_.writer_closed = true;
            out_.readable.notify_all();
        }
        std::scoped_lock lock(in_.mutex);
        in_.reader_closed = true;
        closed_ = true;
        in_.writable.notify_all();
    }

    std::string describe() const override { return name_; }
    std::string last_error() const override { return {}; }

private:
    std::shared_ptr<Shared> shared_;
    Pipe& out_;
    Pipe& in_;
    std::string name_;
    std::atomic<bool> closed_{false};
};

}  // namespace

std::pair<std::unique_ptr<Transport>, std::unique_ptr<Transport>> make_inproc_pair(std::size_t capacity_bytes) {
    auto shared = std::make_shared<Shared>(std::max<std::size_t>(capacity_bytes, 1));
    return {std::make_unique<InprocEndpoint>(shared, true), std::make_unique<InprocEndpoint>(shared, false)};
}

}  // namespace eyesim::transport
