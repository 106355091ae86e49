// USB transport: bulk framing (short/zero-length packet ends a transfer) and reconnect with backoff.
#include "eyesim/transport/usb.hpp"

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <thread>

namespace eyesim::transport {
namespace {

long long now_ms() {
    using namespace std::chrono;
    return duration_cast<milliseconds>(steady_clock::now().time_since_epoch()).count();
}

std::string ids_text(const UsbIds& ids) {
    char buf[32];
    std::snprintf(buf, sizeof buf, "usb://%04x:%04x", ids.vendor_id, ids.product_id);
    return buf;
}

/// Largest OUT transfer handed to the backend at once (a multiple of every wMaxPacketSize).
constexpr std::size_t kOutChunkBytes = 16384;

}  // namespace

const char* to_string(UsbStatus s) {
    switch (s) {
        case UsbStatus::ok: return "ok";
        case UsbStatus::timeout: return "timeout";
        case UsbStatus::no_device: return "no_device";
        case UsbStatus::not_found: return "not_found";
        case UsbStatus::access: return "access";
        case UsbStatus::busy: return "busy";
        case UsbStatus::overflow: return "overflow";
        case UsbStatus::pipe: return "pipe";
        case UsbStatus::io: return "io";
    }
    return "unknown";
}

UsbTransport::UsbTransport(std::unique_ptr<UsbBackend> backend, UsbOptions options)
    : backend_(std::move(backend)), options_(options), staging_(kUsbInTransferBytes) {
    options_.reconnect_initial_ms = std::max(options_.reconnect_initial_ms, 1);
    options_.reconnect_max_ms = std::max(options_.reconnect_max_ms, options_.reconnect_initial_ms);
    backoff_ms_ = options_.reconnect_initial_ms;
}

UsbTransport::~UsbTransport() { close(); }

std::string UsbTransport::describe() const { return ids_text(options_.ids); }

bool UsbTransport::open_first(std::string& why) {
    ++stats_.open_attempts;
    const UsbStatus s = backend_->open(options_.ids, device_, why);
    if (s != UsbStatus::ok) {
        device_.reset();
        error_ = why;
        return false;
    }
    error_.clear();
    return true;
}

void UsbTransport::close() {
    device_.reset();
    closed_ = true;
}

void UsbTransport::lost(UsbStatus why) {
    device_.reset();
    staged_begin_ = staged_end_ = 0;
    ++stats_.disconnects;
    backoff_ms_ = options_.reconnect_initial_ms;
    next_attempt_ms_ = now_ms();  // try at once: an unplug glitch may already be over
    lost_why_ = std::string("device lost (") + to_string(why) + "); reconnecting";  // callers prefix describe()
    error_ = lost_why_;
}

bool UsbTransport::ensure_connected(int timeout_ms) {
    if (device_) return true;
    if (closed_) return false;
    const long long deadline = now_ms() + std::max(timeout_ms, 0);
    for (;;) {
        const long long now = now_ms();
        if (now >= next_attempt_ms_) {
            ++stats_.open_attempts;
            std::string why;
            const UsbStatus s = backend_->open(options_.ids, device_, why);
            if (s == UsbStatus::ok) {
                ++stats_.reconnects;
                backoff_ms_ = options_.reconnect_initial_ms;
                error_.clear();
                lost_why_.clear();
                return true;
            }
            device_.reset();
            // While away after a loss the error keeps saying so, whichever call (read or write) saw it first.
            error_ = lost_why_.empty() ? why + " (reconnecting, next try in " + std::to_string(backoff_ms_) + " ms)"
                                       : lost_why_ + " (" + why + "; next try in " + std::to_string(backoff_ms_) + " ms)";
            next_attempt_ms_ = now + backoff_ms_;
            backoff_ms_ = std::min(backoff_ms_ * 2, options_.reconnect_max_ms);
        }
        const long long left = deadline - now_ms();
        if (left <= 0) return false;
        const long long wait = std::min(left, std::max(next_attempt_ms_ - now_ms(), 0LL));
        // A hotplug arrival cuts the backoff short.
        if (backend_->wait_for_arrival(static_cast<int>(wait))) next_attempt_ms_ = 0;
    }
}

IoResult UsbTransport::read(std::span<std::uint8_t> out, int timeout_ms) {
    if (closed_) return {0, IoStatus::closed};
    if (out.empty()) return {0, IoStatus::ok};
    if (staged_begin_ == staged_end_) {
        const long long start = now_ms();
        if (!ensure_connected(timeout_ms)) return {0, IoStatus::error};
        const int left = static_cast<int>(std::max<long long>(timeout_ms - (now_ms() - start), 0));
        std::size_t got = 0;
        // libusb treats 0 as "no timeout"; a poll is a 1 ms wait.
        const UsbStatus s = device_->bulk_in(staging_.data(), staging_.size(), got, static_cast<unsigned>(std::max(left, 1)));
        if (s == UsbStatus::ok || s == UsbStatus::timeout) {
            if (s == UsbStatus::ok) ++stats_.in_transfers;
            staged_begin_ = 0;
            staged_end_ = got;
            if (got == 0) return {0, IoStatus::timeout};
        } else {
            lost(s);
            return {0, IoStatus::error};
        }
    }
    const std::size_t n = std::min(out.size(), staged_end_ - staged_begin_);
    std::memcpy(out.data(), staging_.data() + staged_begin_, n);
    staged_begin_ += n;
    return {n, IoStatus::ok};
}

IoResult UsbTransport::write(std::span<const std::uint8_t> data, int timeout_ms) {
    if (closed_) return {0, IoStatus::closed};
    if (!ensure_connected(timeout_ms)) return {0, IoStatus::error};
    const unsigned t = static_cast<unsigned>(std::max(timeout_ms, 1));
    std::size_t done = 0;
    while (done < data.size()) {
        const std::size_t chunk = std::min(kOutChunkBytes, data.size() - done);
        std::size_t sent = 0;
        const UsbStatus s = device_->bulk_out(data.data() + done, chunk, sent, t);
        done += sent;
        ++stats_.out_transfers;
        if (s == UsbStatus::timeout) return {done, IoStatus::timeout};
        if (s != UsbStatus::ok) {
            lost(s);
            return {done, IoStatus::error};
        }
    }
    // A transfer that filled its last packet exactly needs a zero-length packet to end it.
    const std::uint16_t mps = device_->max_packet_out();
    if (!data.empty() && mps != 0 && data.size() % mps == 0) {
        std::size_t sent = 0;
        const UsbStatus s = device_->bulk_out(nullptr, 0, sent, t);
        ++stats_.out_transfers;
        ++stats_.zero_length_out;
        if (s == UsbStatus::timeout) return {done, IoStatus::timeout};
        if (s != UsbStatus::ok) {
            lost(s);
            return {done, IoStatus::error};
        }
    }
    return {done, IoStatus::ok};
}

std::unique_ptr<Transport> connect_usb(const UsbOptions& options) {
    auto transport = std::make_unique<UsbTransport>(make_libusb_backend(options.ids), options);
    std::string why;
    if (!transport->open_first(why)) throw TransportError(why);
    return transport;
}

UsbIds parse_usb_uri(const std::string& uri) {
    UsbIds ids;
    if (uri == "usb" || uri == "usb://") return ids;
    if (uri.rfind("usb://", 0) != 0) throw TransportError(uri + ": expected usb or usb://VID:PID");
    const std::string rest = uri.substr(6);
    unsigned vid = 0, pid = 0;
    char tail = 0;
    if (rest.size() != 9 || std::sscanf(rest.c_str(), "%4x:%4x%c", &vid, &pid, &tail) != 2)
        throw TransportError(uri + ": expected usb://VID:PID with 4 hex digits each, e.g. usb://1209:0001");
    ids.vendor_id = static_cast<std::uint16_t>(vid);
    ids.product_id = static_cast<std::uint16_t>(pid);
    return ids;
}

}  // namespace eyesim::transport
