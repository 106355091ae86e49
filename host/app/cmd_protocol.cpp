// `eyesim protocol`: decode captures and raw streams to JSON Lines, and a self-check of the wire codec.
#include "eyesim/app/command.hpp"
#include "eyesim/protocol/capture.hpp"
#include "eyesim/protocol/capture_replay.hpp"
#include "eyesim/protocol/codec.hpp"
#include "eyesim/protocol/crc32c.hpp"
#include "eyesim/protocol/json.hpp"
#include "eyesim/protocol/stream_parser.hpp"

#include <nlohmann/json.hpp>

#include <cstdio>
#include <memory>
#include <random>
#include <string>
#include <vector>

namespace {

namespace proto = eyesim::protocol;

const char* status_name(proto::CaptureStatus s) {
    switch (s) {
        case proto::CaptureStatus::Ok: return "ok";
        case proto::CaptureStatus::End: return "end";
        case proto::CaptureStatus::Torn: return "torn";
        case proto::CaptureStatus::Corrupt: return "corrupt";
        case proto::CaptureStatus::IoError: return "io_error";
    }
    return "unknown";
}

struct DecodeOptions {
    std::string file;
    bool json = false;
};

int run_decode(const DecodeOptions& opt) {
    // The replay holds ~36 KiB of buffers: keep it off the stack.
    auto replay = std::make_unique<proto::CaptureReplay>();
    if (!replay->open(opt.file.c_str()))
        throw eyesim::app::Error(opt.file + ": " + replay->reader().open_error_message());
    // An empty file is not a stream that decoded cleanly: nothing was received at all.
    if (replay->reader().file_bytes() == 0) throw eyesim::app::Error(opt.file + ": no bytes");
    const bool is_capture = replay->kind() == proto::CaptureKind::Capture;
    std::vector<char> line(proto::kMaxJsonBytes + 1);
    std::uint64_t messages = 0;
    std::uint64_t rx_us = 0;
    proto::DecodedFrame frame;
    while (replay->next(frame, rx_us)) {
        const std::size_t n =
            proto::format_json(frame, std::span(line.data(), proto::kMaxJsonBytes), is_capture ? &rx_us : nullptr);
        line[n] = '\n';
        std::fwrite(line.data(), 1, n + 1, stdout);
        ++messages;
    }
    const proto::CaptureStatus status = replay->status();
    const std::uint64_t records = replay->records();
    const proto::CaptureReader* reader = &replay->reader();
    if (status == proto::CaptureStatus::IoError) throw eyesim::app::Error(opt.file + ": read error");
    std::fflush(stdout);

    const proto::ParserStats& s = replay->stats();
    const bool capture_ok = status == proto::CaptureStatus::End && reader->corrupt_regions() == 0;
    // Sequence gaps are frames lost before they reached the file: the stream is not complete either.
    const bool clean = s.errors() == 0 && s.skipped_bytes == 0 && s.sequence_gaps == 0 && capture_ok;
    if (opt.json) {
        char buf[proto::kMaxJsonBytes];
        proto::format_stats_json(s, buf);
        nlohmann::json j;
        j["file"] = opt.file;
        j["kind"] = is_capture ? "capture" : "raw_stream";
        j["messages"] = messages;
        j["errors"] = s.errors() + (capture_ok ? 0 : 1);
        j["parser"] = nlohmann::json::parse(buf);
        if (is_capture) {
            j["capture"] = {{"records", records},
                            {"sent_records", replay->sent_records()},
                            {"status", status_name(status)},
                            {"bad_offset", reader->bad_offset()},
                            {"dropped_bytes", reader->dropped_bytes()},
                            {"corrupt_regions", reader->corrupt_regions()},
                            {"corrupt_bytes", reader->corrupt_bytes()}};
        }
        std::fprintf(stderr, "%s\n", j.dump().c_str());
    } else {
        std::fprintf(stderr,
                     "eyesim protocol decode: %s (%s): %llu messages from %llu bytes; skipped %llu bytes in %llu "
                     "resyncs; errors: bad_version %llu, unknown_type %llu, bad_length %llu, crc_errors %llu, "
                     "truncated %llu, bad_payload %llu; sequence_gaps %llu",
                     opt.file.c_str(), is_capture ? "capture" : "raw stream",
                     static_cast<unsigned long long>(messages), static_cast<unsigned long long>(s.bytes_in),
                     static_cast<unsigned long long>(s.skipped_bytes), static_cast<unsigned long long>(s.resyncs),
                     static_cast<unsigned long long>(s.bad_version), static_cast<unsigned long long>(s.unknown_type),
                     static_cast<unsigned long long>(s.bad_length), static_cast<unsigned long long>(s.crc_errors),
                     static_cast<unsigned long long>(s.truncated), static_cast<unsigned long long>(s.bad_payload),
                     static_cast<unsigned long long>(s.sequence_gaps));
        if (is_capture)
            std::fprintf(stderr, "; %llu good records (%llu of them the host's own commands, not printed)",
                         static_cast<unsigned long long>(records), static_cast<unsigned long long>(replay->sent_records()));
        if (reader->corrupt_regions() > 0)
            std::fprintf(stderr, ", damaged stretches skipped: %llu (%llu bytes)",
                         static_cast<unsigned long long>(reader->corrupt_regions()),
                         static_cast<unsigned long long>(reader->corrupt_bytes()));
        if (status == proto::CaptureStatus::Torn)
            std::fprintf(stderr, ", torn tail at offset %llu (%llu bytes skipped)",
                         static_cast<unsigned long long>(reader->bad_offset()),
                         static_cast<unsigned long long>(reader->dropped_bytes()));
        std::fprintf(stderr, "\n");
    }
    return clean ? 0 : 3;
}

// ----------------------------------------------------------------------------------------------------------------

struct Selftest {
    int checks = 0, failures = 0;
    std::vector<std::string> failed;
    void expect(bool ok, const std::string& what) {
        ++checks;
        if (!ok) {
            ++failures;
            if (failed.size() < 20) failed.push_back(what);
        }
    }
};

template <class T>
T rnd(std::mt19937_64& rng, std::uint64_t lo, std::uint64_t hi) {
    return static_cast<T>(std::uniform_int_distribution<std::uint64_t>(lo, hi)(rng));
}

proto::Message random_message(std::mt19937_64& rng, int type) {
    switch (type) {
        case 1: {
            proto::FieldMarkers f;
            f.camera_id = rnd<std::uint8_t>(rng, 0, proto::kCameraCount - 1);
            f.field_parity = rnd<std::uint8_t>(rng, 0, 1);
            f.flags = rnd<std::uint8_t>(rng, 0, proto::kFieldFlagsDefined);
            f.marker_count = rnd<std::uint8_t>(rng, 0, proto::kMaxMarkersPerMessage);
            f.field_counter = rnd<std::uint32_t>(rng, 0, ~0u);
            f.field_end_us = rng();
            f.part_index = rnd<std::uint16_t>(rng, 0, 0xFFFF);
            for (std::size_t i = 0; i < f.marker_count; ++i) {
                auto& k = f.markers[i];
                k.colour_class = rnd<std::uint8_t>(rng, proto::kMinColourClass, proto::kMaxColourClass);
                k.flags = rnd<std::uint8_t>(rng, 0, proto::kMarkerFlagsDefined);
                k.bbox_x0 = rnd<std::uint16_t>(rng, 0, 719);
                k.bbox_x1 = rnd<std::uint16_t>(rng, k.bbox_x0, 719);
                k.bbox_y0 = rnd<std::uint16_t>(rng, 0, 287);
                k.bbox_y1 = rnd<std::uint16_t>(rng, k.bbox_y0, 287);
                k.x_q16 = rnd<std::uint32_t>(rng, 0, 719u * proto::kCoordScale);
                k.y_q16 = rnd<std::uint32_t>(rng, 0, 287u * proto::kCoordScale);
                k.area_px = rnd<std::uint32_t>(rng, 1, 5000);
                k.intensity_sum = rnd<std::uint32_t>(rng, 0, ~0u);
                k.complete_us = rng();
            }
            return f;
        }
        case 2:
            return proto::PedalState{rng(), {rnd<std::uint16_t>(rng, 0, 0xFFFF), rnd<std::uint16_t>(rng, 0, 0xFFFF),
                                             rnd<std::uint16_t>(rng, 0, 0xFFFF)}, rnd<std::uint16_t>(rng, 0, 0xFFFF)};
        case 3: {
            proto::DeviceStatus s{rng(), rng(), {rnd<std::uint32_t>(rng, 0, ~0u), rnd<std::uint32_t>(rng, 0, ~0u),
                                                 rnd<std::uint32_t>(rng, 0, ~0u)},
                                  rnd<std::uint32_t>(rng, 0, ~0u), rnd<std::uint32_t>(rng, 0, ~0u),
                                  rnd<std::uint32_t>(rng, 0, ~0u), rng(), rnd<std::uint32_t>(rng, 0, ~0u),
                                  rnd<std::uint32_t>(rng, 0, ~0u)};
            return s;
        }
        case 4:
            return proto::Command{rnd<std::uint32_t>(rng, 0, ~0u), rnd<std::uint8_t>(rng, 0, 255),
                                  rnd<std::uint32_t>(rng, 0, ~0u), rnd<std::uint32_t>(rng, 0, ~0u), rng()};
        case 6: {
            proto::BlobPatch b;
            b.camera_id = rnd<std::uint8_t>(rng, 0, proto::kCameraCount - 1);
            b.field_parity = rnd<std::uint8_t>(rng, 0, 1);
            b.colour_class = rnd<std::uint8_t>(rng, proto::kMinColourClass, proto::kMaxColourClass);
            b.flags = rnd<std::uint8_t>(rng, 0, proto::kPatchFlagsDefined);
            b.field_counter = rnd<std::uint32_t>(rng, 0, ~0u);
            b.blob_index = rnd<std::uint16_t>(rng, 0, 0xFFFF);
            b.width_px = static_cast<std::uint16_t>(2 * rnd<int>(rng, 1, proto::kPatchMaxWidthPx / 2));
            b.height_px = rnd<std::uint16_t>(rng, 1, proto::kPatchMaxHeightPx);
            b.origin_x = static_cast<std::uint16_t>(2 * rnd<int>(rng, 0, (proto::kPatchFieldWidthPx - b.width_px) / 2));
            b.origin_y = rnd<std::uint16_t>(rng, 0, static_cast<std::uint16_t>(proto::kPatchFieldHeightPx - b.height_px));
            b.fragment_count = static_cast<std::uint8_t>(
                proto::patch_fragment_count(proto::patch_bytes(b.width_px, b.height_px)));
            b.fragment_index = rnd<std::uint8_t>(rng, 0, static_cast<std::uint8_t>(b.fragment_count - 1));
            for (auto& v : b.samples) v = rnd<std::uint8_t>(rng, 0, 255);
            return b;
        }
        default: {
            const auto status = rnd<std::uint8_t>(rng, 0, 1);
            return proto::Reply{rnd<std::uint32_t>(rng, 0, ~0u), rnd<std::uint8_t>(rng, 0, 255), status,
                                status ? rnd<std::uint8_t>(rng, 1, proto::kMaxNackReason) : std::uint8_t{0},
                                rnd<std::uint32_t>(rng, 0, ~0u), rng(), rng()};
        }
    }
}

int run_selftest(bool json) {
    Selftest t;
    std::mt19937_64 rng(20261124);
    t.expect(proto::crc32c(std::string_view("123456789")) == proto::kCrc32cCheck, "CRC-32C check value");
    std::vector<std::uint8_t> stream;
    std::vector<proto::Message> sent;
    std::vector<std::uint8_t> frame(proto::kMaxFrameBytes);
    for (int type = 1; type <= static_cast<int>(proto::kMessageTypeCount); ++type) {
        const std::string name = proto::message_type_name(static_cast<proto::MessageType>(type));
        for (int i = 0; i < 1000; ++i) {
            const proto::Message m = random_message(rng, type);
            const std::size_t n = proto::encode_frame(m, static_cast<std::uint16_t>(sent.size()), frame);
            t.expect(n > 0 && n <= proto::kMaxFrameBytes, name + ": encode");
            proto::DecodedFrame d;
            std::size_t used = 0;
            const auto e = proto::decode_frame(std::span(frame.data(), n), d, used);
            t.expect(e == proto::DecodeError::None && used == n && d.message == m, name + ": decode round trip");
            // One flipped bit anywhere past the sync marker must be caught.
            auto bad = std::vector<std::uint8_t>(frame.begin(), frame.begin() + static_cast<std::ptrdiff_t>(n));
            bad[rnd<std::size_t>(rng, 2, n - 1)] ^= static_cast<std::uint8_t>(1u << rnd<int>(rng, 0, 7));
            t.expect(proto::decode_frame(bad, d, used) != proto::DecodeError::None, name + ": bit flip detected");
            stream.insert(stream.end(), frame.begin(), frame.begin() + static_cast<std::ptrdiff_t>(n));
            sent.push_back(m);
        }
    }
    // The whole stream through the incremental parser, in random chunks, with garbage in front.
    std::vector<std::uint8_t> noisy = {0x00, proto::kSync0, proto::kSync1, 0x01, 0x01, 0x00, 0x00, 0xEE, 0x01};
    noisy.insert(noisy.end(), stream.begin(), stream.end());
    auto parser = std::make_unique<proto::StreamParser>();
    std::size_t k = 0;
    bool order_ok = true;
    auto on = [&](const proto::DecodedFrame& f) {
        order_ok = order_ok && k < sent.size() && f.message == sent[k];
        ++k;
    };
    for (std::size_t i = 0; i < noisy.size();) {
        const std::size_t n = std::min(noisy.size() - i, rnd<std::size_t>(rng, 1, 700));
        parser->parse(std::span(noisy).subspan(i, n), on);
        i += n;
    }
    parser->finish(on);
    t.expect(order_ok && k == sent.size(), "stream parser: every frame after garbage, in order");
    t.expect(parser->stats().skipped_bytes == 9, "stream parser: skipped exactly the garbage");
    t.expect(parser->stats().sequence_gaps == 0, "stream parser: no sequence gaps");

    if (json) {
        nlohmann::json j{{"checks", t.checks}, {"failures", t.failures}, {"errors", t.failures},
                         {"messages", sent.size()}, {"failed", t.failed}, {"ok", t.failures == 0}};
        std::printf("%s\n", j.dump().c_str());
    } else {
        for (const auto& f : t.failed) std::fprintf(stderr, "selftest: FAILED: %s\n", f.c_str());
        std::printf("eyesim protocol selftest: %d checks over %zu messages of %zu types, %d failures: %s\n", t.checks,
                    sent.size(), proto::kMessageTypeCount, t.failures, t.failures == 0 ? "OK" : "FAILED");
    }
    return t.failures == 0 ? 0 : 1;
}

eyesim::app::Registrar reg{"protocol", "Wire protocol tools: decode captures/streams, self-test", [](CLI::App& sub) {
    sub.require_subcommand(1);
    auto dec = std::make_shared<DecodeOptions>();
    CLI::App* decode = sub.add_subcommand("decode", "Print each message of a capture file or raw stream as JSON Lines");
    decode->add_option("FILE", dec->file, "capture file (EYESIMCP) or raw byte stream")->required();
    decode->add_flag("--json", dec->json, "error summary on stderr as one JSON object");
    auto self_json = std::make_shared<bool>(false);
    CLI::App* selftest = sub.add_subcommand("selftest", "Encode and decode every message type; exit 0 on success");
    selftest->add_flag("--json", *self_json, "print one JSON summary object");
    return [dec, self_json, decode, selftest]() -> int {
        if (decode->parsed()) return run_decode(*dec);
        if (selftest->parsed()) return run_selftest(*self_json);
        return 2;
    };
}};

}  // namespace
