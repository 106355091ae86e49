// Reading a recording directory: what opening costs against reading the first field, and sequential reading.
//
//   bench_recording DIR [--repeats N]
//
// Prints one JSON object: open_ms (Recording::open, median of N fresh opens), first_field_ms (reading field 0 of
// every camera right after such an open, median), decoded_frames_at_open (frames the video decoders had output
// when open returned, summed over the cameras: 0 for raw fields), fields_per_s (every field of every camera read
// in recording order, one pass, wall time), lost_fields, and each camera's stream description. Wall times on
// this machine; the median makes a busy machine matter less.
#include "eyesim/rig/error.hpp"
#include "eyesim/rig/recording.hpp"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>
#include <vector>

using namespace eyesim::rig;

namespace {

double now_s() { return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count(); }

double median(std::vector<double> v) {
    std::sort(v.begin(), v.end());
    return v.empty() ? 0.0 : v[v.size() / 2];
}

}  // namespace

int main(int argc, char** argv) {
    if (argc < 2 || std::strcmp(argv[1], "--help") == 0) {
        std::fprintf(stderr, "usage: bench_recording DIR [--repeats N]\n");
        return 2;
    }
    const std::string dir = argv[1];
    int repeats = 5;
    if (argc == 4 && std::strcmp(argv[2], "--repeats") == 0) repeats = std::max(1, std::atoi(argv[3]));
    try {
        std::vector<double> open_ms, first_ms;
        int64_t decoded_at_open = 0;
        std::vector<uint8_t> field(kFieldBytes);
        for (int r = 0; r < repeats; ++r) {
            const double t0 = now_s();
            Recording rec = Recording::open(dir);
            const double t1 = now_s();
            decoded_at_open = 0;
            for (int c = 0; c < rec.camera_count(); ++c) decoded_at_open += rec.decoded_frames(c);
            for (int c = 0; c < rec.camera_count(); ++c) rec.read_field(c, 0, field.data());
            const double t2 = now_s();
            open_ms.push_back((t1 - t0) * 1e3);
            first_ms.push_back((t2 - t1) * 1e3);
        }
        Recording rec = Recording::open(dir);
        const int64_t n = rec.common_field_count();
        const double t0 = now_s();
        for (int64_t i = 0; i < n; ++i)
            for (int c = 0; c < rec.camera_count(); ++c) rec.read_field(c, i, field.data());
        const double read_s = now_s() - t0;
        nlohmann::json j;
        j["recording"] = dir;
        j["open_ms"] = median(open_ms);
        j["first_field_ms"] = median(first_ms);
        j["decoded_frames_at_open"] = decoded_at_open;
        j["fields"] = n;
        j["cameras"] = rec.camera_count();
        j["fields_per_s"] = read_s > 0 ? static_cast<double>(n * rec.camera_count()) / read_s : 0.0;
        int64_t lost = 0;
        nlohmann::json streams = nlohmann::json::array();
        for (int c = 0; c < rec.camera_count(); ++c) {
            lost += rec.lost_fields(c);
            streams.push_back(rec.stream_description(c));
        }
        j["lost_fields"] = lost;
        j["streams"] = streams;
        j["warnings"] = rec.warnings();
        std::printf("%s\n", j.dump().c_str());
        return 0;
    } catch (const RigError& e) {
        std::fprintf(stderr, "bench_recording: error: %s\n", e.what());
        return 1;
    }
}
