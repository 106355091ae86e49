// Stream parser throughput (MB/s, messages/s) on a realistic device→host stream, clean and with injected
// damage, against a naive peer parser measured in the same run. Medians of repeats (the machine is shared).
//   bench_protocol [--mb N] [--repeats N]
#include "eyesim/protocol/codec.hpp"
#include "eyesim/protocol/stream_parser.hpp"
#include "thread_cpu.hpp"

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <ctime>
#include <memory>
#include <random>
#include <string>
#include <vector>

using namespace eyesim::protocol;
using Bytes = std::vector<std::uint8_t>;
using Clock = std::chrono::steady_clock;

namespace {

struct Stream {
    Bytes bytes;
    std::size_t frames = 0;          // frames encoded
    std::size_t intact_frames = 0;   // frames left undamaged (the most a parser can deliver)
    std::size_t garbage_bytes = 0;   // injected garbage
};

// A device's output: per 20 ms field period three FieldMarkers (4-12 markers each), two PedalState, and a
// DeviceStatus once per second; Replies now and then.
Stream make_stream(std::size_t target_bytes, double garbage_fraction, double flip_fraction, std::uint64_t seed) {
    std::mt19937_64 rng(seed);
    Stream s;
    Bytes frame(kMaxFrameBytes);
    std::uint16_t seq = 0;
    std::uint64_t t_us = 0;
    std::uint32_t field = 0;
    auto emit = [&](const Message& m) {
        const std::size_t n = encode_frame(m, seq++, frame);
        const std::size_t at = s.bytes.size();
        s.bytes.insert(s.bytes.end(), frame.begin(), frame.begin() + static_cast<std::ptrdiff_t>(n));
        ++s.frames;
        if (std::uniform_real_distribution<double>(0, 1)(rng) < flip_fraction) {
            s.bytes[at + 8 + rng() % (n - 8)] ^= static_cast<std::uint8_t>(1u << (rng() % 8));
        } else {
            ++s.intact_frames;
        }
        if (std::uniform_real_distribution<double>(0, 1)(rng) < garbage_fraction * 20) {
            const std::size_t g = 1 + rng() % 40;
            for (std::size_t i = 0; i < g; ++i)
                s.bytes.push_back(i % 7 == 0 ? kSync0 : static_cast<std::uint8_t>(rng()));
            s.garbage_bytes += g;
        }
    };
    while (s.bytes.size() < target_bytes) {
        t_us += 20000;
        ++field;
        for (std::uint8_t cam = 0; cam < 3; ++cam) {
            FieldMarkers f;
            f.camera_id = cam;
            f.field_parity = field & 1;
            f.field_counter = field;
            f.field_end_us = t_us;
            f.marker_count = static_cast<std::uint8_t>(4 + rng() % 9);
            for (std::size_t i = 0; i < f.marker_count; ++i) {
                Marker& k = f.markers[i];
                k.colour_class = static_cast<std::uint8_t>(1 + rng() % 4);
                k.bbox_x0 = static_cast<std::uint16_t>(rng() % 700);
                k.bbox_y0 = static_cast<std::uint16_t>(rng() % 270);
                k.bbox_x1 = static_cast<std::uint16_t>(k.bbox_x0 + 8);
                k.bbox_y1 = static_cast<std::uint16_t>(k.bbox_y0 + 5);
                k.x_q16 = (k.bbox_x0 + 4u) * kCoordScale + static_cast<std::uint32_t>(rng() % kCoordScale);
                k.y_q16 = (k.bbox_y0 + 2u) * kCoordScale + static_cast<std::uint32_t>(rng() % kCoordScale);
                k.area_px = static_cast<std::uint32_t>(30 + rng() % 40);
                k.intensity_sum = k.area_px * 200;
                k.complete_us = t_us - 1000 + rng() % 1000;
            }
            emit(f);
        }
        for (int p = 0; p < 2; ++p)
            emit(PedalState{t_us - 10000u * static_cast<std::uint64_t>(p), {static_cast<std::uint16_t>(rng()), 0, 0}, 1});
        if (field % 50 == 0) emit(DeviceStatus{t_us, t_us, {field, field, field}, 0, 0, 0, s.bytes.size(), 0, 0});
        if (field % 100 == 0) emit(Reply{field, 5, 0, 0, 0, t_us, t_us});
    }
    return s;
}

/// The naive peer: a std::vector receive buffer, one byte appended at a time; after every byte it re-scans
/// from the buffer's start (drop a non-sync byte, drop a bad header's first byte, wait for the whole frame,
/// try decode_frame, drop one byte on failure).
class NaiveParser {
public:
    template <class F>
    void feed(std::span<const std::uint8_t> bytes, F&& on) {
        for (std::uint8_t b : bytes) {
            buf_.push_back(b);
            rescan(on);
        }
    }
    template <class F>
    void rescan(F&& on) {
        for (;;) {
            if (buf_.empty()) return;
            if (buf_[0] != kSync0 || (buf_.size() >= 2 && buf_[1] != kSync1)) {
                buf_.erase(buf_.begin());
                continue;
            }
            if (buf_.size() < kFrameHeaderBytes) return;
            const std::size_t len = buf_[6] | (buf_[7] << 8);
            const bool header_ok = buf_[2] == kProtocolVersion && buf_[3] >= 1 && buf_[3] <= kMessageTypeCount &&
                                   valid_payload_length(static_cast<MessageType>(buf_[3]), len);
            if (!header_ok) {
                buf_.erase(buf_.begin());
                continue;
            }
            if (buf_.size() < frame_size(len)) return;
            std::size_t used = 0;
            const DecodeError e = decode_frame(buf_, frame_, used);
            if (e == DecodeError::None) {
                on(frame_);
                buf_.erase(buf_.begin(), buf_.begin() + static_cast<std::ptrdiff_t>(used));
            } else if (e == DecodeError::BadPayload) {
                buf_.erase(buf_.begin(), buf_.begin() + static_cast<std::ptrdiff_t>(frame_size(len)));
            } else {
                buf_.erase(buf_.begin());
            }
        }
    }

private:
    std::vector<std::uint8_t> buf_;
    DecodedFrame frame_;
};

struct Result {
    double seconds = 0;       // thread CPU time (not inflated by other processes on a shared machine)
    double wall_seconds = 0;  // wall-clock time
    std::size_t frames = 0;
};

template <class Run>
Result median_of(int repeats, Run&& run) {
    std::vector<Result> rs;
    for (int i = 0; i < repeats; ++i) {
        const auto t0 = Clock::now();
        const double c0 = eyesim::bench::thread_cpu_s();
        Result r;
        r.frames = run();
        r.seconds = eyesim::bench::thread_cpu_s() - c0;
        r.wall_seconds = std::chrono::duration<double>(Clock::now() - t0).count();
        rs.push_back(r);
    }
    std::sort(rs.begin(), rs.end(), [](const Result& a, const Result& b) { return a.seconds < b.seconds; });
    return rs[rs.size() / 2];
}

std::size_t run_parser(const Bytes& bytes, std::size_t chunk) {
    auto p = std::make_unique<StreamParser>();
    std::size_t n = 0;
    auto on = [&](const DecodedFrame&) { ++n; };
    for (std::size_t i = 0; i < bytes.size(); i += chunk)
        p->parse(std::span(bytes).subspan(i, std::min(chunk, bytes.size() - i)), on);
    p->finish(on);
    return n;
}

std::size_t run_feed_next(const Bytes& bytes, std::size_t chunk) {
    auto p = std::make_unique<StreamParser>();
    std::size_t n = 0;
    DecodedFrame f;
    for (std::size_t i = 0; i < bytes.size(); i += chunk) {
        std::span<const std::uint8_t> rest = std::span(bytes).subspan(i, std::min(chunk, bytes.size() - i));
        while (!rest.empty()) {
            rest = rest.subspan(p->feed(rest));
            while (p->next(f)) ++n;
        }
    }
    p->finish([&](const DecodedFrame&) { ++n; });
    return n;
}

std::size_t run_naive(const Bytes& bytes, std::size_t chunk) {
    NaiveParser p;
    std::size_t n = 0;
    for (std::size_t i = 0; i < bytes.size(); i += chunk)
        p.feed(std::span(bytes).subspan(i, std::min(chunk, bytes.size() - i)), [&](const DecodedFrame&) { ++n; });
    return n;
}

}  // namespace

int main(int argc, char** argv) {
    double mb = 16;
    int repeats = 5;
    for (int i = 1; i + 1 < argc; i += 2) {
        if (!std::strcmp(argv[i], "--mb")) mb = std::atof(argv[i + 1]);
        else if (!std::strcmp(argv[i], "--repeats")) repeats = std::atoi(argv[i + 1]);
    }
    const auto target = static_cast<std::size_t>(mb * 1e6);
    struct Case {
        const char* name;
        Stream s;
    };
    Case cases[] = {{"clean", make_stream(target, 0, 0, 1)}, {"damaged", make_stream(target, 0.01, 0.01, 2)}};
    std::printf("stream: %.1f MB per case, median of %d repeats\n", mb, repeats);
    for (const Case& c : cases)
        std::printf("%s: %zu frames, %.2f%% of bytes injected garbage, %.2f%% of frames with a flipped bit\n", c.name,
                    c.s.frames, 100.0 * static_cast<double>(c.s.garbage_bytes) / static_cast<double>(c.s.bytes.size()),
                    100.0 * static_cast<double>(c.s.frames - c.s.intact_frames) / static_cast<double>(c.s.frames));
    std::printf("\n");
    std::printf("| stream | parser | chunk | MB/s (CPU) | Mmsg/s (CPU) | MB/s (wall) | frames delivered / intact | lost | "
                "speed vs naive |\n");
    std::printf("|---|---|---:|---:|---:|---:|---:|---:|---:|\n");
    for (const Case& c : cases) {
        const double mbytes = static_cast<double>(c.s.bytes.size()) / 1e6;
        const Result naive = median_of(std::max(1, repeats / 2), [&] { return run_naive(c.s.bytes, 512); });
        struct Row {
            const char* parser;
            std::size_t chunk;
            Result r;
        };
        const Row rows[] = {
            {"StreamParser::parse", 512, median_of(repeats, [&] { return run_parser(c.s.bytes, 512); })},
            {"StreamParser::parse", 16384, median_of(repeats, [&] { return run_parser(c.s.bytes, 16384); })},
            {"StreamParser feed/next", 512, median_of(repeats, [&] { return run_feed_next(c.s.bytes, 512); })},
            {"naive vector re-scan", 512, naive},
        };
        for (const Row& row : rows) {
            std::printf("| %s | %s | %zu | %.0f | %.2f | %.0f | %zu / %zu | %zu | %.1fx |\n", c.name, row.parser,
                        row.chunk, mbytes / row.r.seconds, static_cast<double>(row.r.frames) / row.r.seconds / 1e6,
                        mbytes / row.r.wall_seconds,
                        row.r.frames, c.s.intact_frames, c.s.intact_frames - std::min(c.s.intact_frames, row.r.frames),
                        naive.seconds / row.r.seconds);
        }
    }
    return 0;
}
