// Video as PAL cameras record it: FFV1 4:2:2 back to the raw fields bit for bit, 4:2:0 / 4:1:1 chroma that stays
// with its field and pixel, opening without decoding the file, damaged files, field order, random access.
#include "recording_dirs.hpp"

#include "eyesim/rig/error.hpp"
#include "eyesim/rig/recording.hpp"
#include "eyesim/rig/synth.hpp"
#include "eyesim/rig/video.hpp"

#include <Eigen/Core>
#include <catch2/catch.hpp>
#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <random>
#include <string>
#include <vector>

using namespace eyesim::rig;
using namespace rigtest;
namespace fs = std::filesystem;

namespace {

/// A 0.4 s `surgery` recording (20 fields, noise on) as raw fields and as `format`, from the same seed.
struct Pair {
    std::string raw, video;
};

Pair make_recordings(const std::string& name, const std::string& format, int first_field_parity = 0) {
    Pair p{temp_dir(name + "_raw"), temp_dir(name + "_" + format)};
    SynthRequest req;
    req.scenario = "surgery";
    req.seconds = 0.4;
    req.seed = 5;
    for (CameraModel& c : req.cameras) c.first_field_parity = first_field_parity;
    req.out_dir = p.raw;
    write_recording(req);
    req.out_dir = p.video;
    req.format = format;
    write_recording(req);
    return p;
}

std::vector<uint8_t> field_of(Recording& rec, int cam, int64_t i) {
    std::vector<uint8_t> f(kFieldBytes);
    const bool ok = rec.read_field(cam, i, f.data());
    if (!ok)
        for (const std::string& w : rec.warnings()) UNSCOPED_INFO(w);
    REQUIRE(ok);
    return f;
}

void write_manifest_key(const std::string& dir, const nlohmann::json& patch) {
    const fs::path m = fs::path(dir) / "manifest.json";
    std::ifstream in(m);
    nlohmann::json j = nlohmann::json::parse(in);
    in.close();
    j.merge_patch(patch);
    std::ofstream(m) << j.dump();
}

bool has_warning(const Recording& rec, const std::vector<std::string>& needles) {
    for (const std::string& w : rec.warnings()) {
        bool all = true;
        for (const std::string& n : needles) all = all && w.find(n) != std::string::npos;
        if (all) return true;
    }
    return false;
}

}  // namespace

TEST_CASE("FFV1 4:2:2 video gives back the raw fields bit for bit, opening decodes one frame",
          "[rig][recording][video]") {
    for (int first : {0, 1}) {  // top field first, and a rig whose cameras start with a bottom field
        INFO("first_field_parity " << first);
        const Pair p = make_recordings("ffv1_" + std::to_string(first), "ffv1", first);
        Recording raw = Recording::open(p.raw);
        Recording vid = Recording::open(p.video);
        CHECK(vid.warnings().empty());
        for (int c = 0; c < 3; ++c) {
            REQUIRE(vid.format(c) == StreamFormat::kVideo);
            CHECK(fs::path(vid.stream_path(c)).extension() == ".mkv");
            CHECK(vid.decoded_frames(c) == 1);  // the header and the first frame, nothing more
            CHECK(vid.field_count(c) == 20);
            CHECK(vid.cameras()[c].first_field_parity == first);
            CHECK(vid.stream_description(c).find("yuv422p") != std::string::npos);
        }
        for (int64_t i = 0; i < 20; ++i)
            for (int c = 0; c < 3; ++c) {
                INFO("camera " << c << " field " << i);
                CHECK(vid.field_parity(c, i) == raw.field_parity(c, i));
                CHECK(field_of(vid, c, i) == field_of(raw, c, i));
            }
        for (int c = 0; c < 3; ++c) CHECK(vid.decoded_frames(c) == 10);  // each frame decoded once for its two fields
        // Random access: backwards and jumping, still exact.
        for (int64_t i : {19, 0, 7, 6, 15, 2}) CHECK(field_of(vid, 1, i) == field_of(raw, 1, i));
        CHECK(vid.lost_fields(1) == 0);
        fs::remove_all(p.raw);
        fs::remove_all(p.video);
    }
}

namespace {

/// Where the test blob is in field `i` (field pixels). `moving`: a new place every field (0.37, 0.61 px per
/// field: the two fields of a frame show different instants); else a place fixed in the frame for both fields
/// of a frame (frame row 2y + parity), moving from frame to frame: what a codec that mixes the two fields of a
/// frame leaves in place.
Eigen::Vector2d blob_at(int i, bool moving) {
    if (moving) return {300.0 + 0.37 * i, 120.0 + 0.61 * i};
    const int n = i / 2, parity = i % 2;
    return {300.0 + 0.74 * n, (240.0 + 1.22 * n - parity) / 2.0};
}

/// Fields with one Gaussian blob (σ 2.2 px) in luma, Cb and Cr, chroma point-sampled at the even pixels.
std::vector<std::vector<uint8_t>> blob_fields(int n, bool moving) {
    std::vector<std::vector<uint8_t>> fields(static_cast<size_t>(n), std::vector<uint8_t>(kFieldBytes));
    for (int i = 0; i < n; ++i) {
        const Eigen::Vector2d b = blob_at(i, moving);
        uint8_t* f = fields[static_cast<size_t>(i)].data();
        for (int y = 0; y < kFieldHeight; ++y)
            for (int x = 0; x < kFieldWidth; ++x) {
                const double g = std::exp(-(Eigen::Vector2d(x, y) - b).squaredNorm() / (2.0 * 2.2 * 2.2));
                uint8_t* px = f + (static_cast<size_t>(y) * kFieldWidth + x) * 2;
                px[1] = static_cast<uint8_t>(std::lround(30 + 150 * g));
                if (x % 2 == 0) {
                    px[0] = static_cast<uint8_t>(std::lround(128 - 70 * g));  // Cb
                    px[2] = static_cast<uint8_t>(std::lround(128 + 90 * g));  // Cr
                }
            }
    }
    return fields;
}

/// Centroid of the blob's chroma, component byte 0 (Cb, weight 128 − Cb) or 2 (Cr, weight Cr − 128), over the
/// chroma samples (even pixels) of a 25 × 25 window centred on the pixel nearest `at`. Signed weights: codec
/// noise around the blob averages out instead of pulling the centroid to the window's centre.
Eigen::Vector2d chroma_centroid(const std::vector<uint8_t>& f, int byte, const Eigen::Vector2d& at) {
    const int cx = static_cast<int>(std::lround(at.x())), cy = static_cast<int>(std::lround(at.y()));
    double sw = 0, sx = 0, sy = 0;
    for (int y = cy - 12; y <= cy + 12; ++y)
        for (int x = cx - 12 + (cx % 2); x <= cx + 12 - (cx % 2); x += 2) {
            const int v = f[(static_cast<size_t>(y) * kFieldWidth + x) * 2 + byte];
            const double w = byte == 0 ? 128.0 - v : v - 128.0;
            sw += w;
            sx += w * x;
            sy += w * y;
        }
    return {sx / sw, sy / sw};
}

struct Bias {
    double x[2] = {0, 0}, y[2] = {0, 0};  // mean chroma-centroid shift per parity (decoded − written), field px
};

/// Writes `fields` (temporal order, top field first) with `codec` / `chroma`, reads them back (chroma per field,
/// or as if the frames were progressive) and returns the mean chroma-centroid shift per parity of component byte
/// `byte` against the same measurement on the fields written.
Bias round_trip_bias(VideoCodec codec, VideoChroma chroma, const std::vector<std::vector<uint8_t>>& fields,
                     bool moving, int byte, bool interlaced) {
    const std::string dir = temp_dir(std::string("blob_") + to_string(codec));
    const std::string path = dir + "/v" + extension(codec);
    {
        VideoWriter w(path, codec, FieldOrder::kTopFirst, chroma);
        for (size_t i = 0; i + 1 < fields.size(); i += 2) w.write(fields[i].data(), fields[i + 1].data());
        w.close();
    }
    VideoReader r(path);
    CHECK(r.info().order == FieldOrder::kTopFirst);
    Bias b;
    int n[2] = {0, 0};
    std::vector<uint8_t> out(kFieldBytes);
    for (size_t i = 0; i < fields.size(); ++i) {
        std::string why;
        REQUIRE(r.load_frame(static_cast<int64_t>(i / 2), why) == FrameStatus::kOk);
        const int parity = static_cast<int>(i % 2);
        r.extract_field(parity, interlaced, out.data());
        const Eigen::Vector2d at = blob_at(static_cast<int>(i), moving);
        const Eigen::Vector2d d = chroma_centroid(out, byte, at) - chroma_centroid(fields[i], byte, at);
        b.x[parity] += d.x();
        b.y[parity] += d.y();
        ++n[parity];
    }
    for (int p = 0; p < 2; ++p) {
        b.x[p] /= n[p];
        b.y[p] /= n[p];
    }
    fs::remove_all(dir);
    return b;
}

}  // namespace

TEST_CASE("4:2:0 and 4:1:1 chroma is read where it was sited: each field's own, at its own lines and pixels",
          "[rig][recording][video]") {
    // Lossless FFV1 files holding the planes a 4:2:0 (MPEG-2 / H.264 siting) and a 4:1:1 camera stream holds:
    // only the subsampling and the re-siting remain. The blob moves between the two fields of a frame.
    const auto fields = blob_fields(80, true);
    for (VideoChroma chroma : {VideoChroma::k420, VideoChroma::k411})
        for (int byte : {0, 2}) {
            INFO((chroma == VideoChroma::k420 ? "4:2:0" : "4:1:1") << (byte ? " Cr" : " Cb"));
            const Bias b = round_trip_bias(VideoCodec::kFfv1, chroma, fields, true, byte, true);
            INFO("x bias top " << b.x[0] << " bottom " << b.x[1] << ", y bias top " << b.y[0] << " bottom " << b.y[1]);
            for (int p = 0; p < 2; ++p) {
                CHECK(std::abs(b.x[p]) < 0.02);
                CHECK(std::abs(b.y[p]) < 0.02);
            }
        }
    // The same 4:2:0 file read as if its chroma were progressive mixes the two fields' instants: each field's
    // chroma is pulled towards the other field's blob, down for the top field, up for the bottom one.
    const Bias wrong = round_trip_bias(VideoCodec::kFfv1, VideoChroma::k420, fields, true, 2, false);
    INFO("progressive reading: y bias top " << wrong.y[0] << " bottom " << wrong.y[1]);
    CHECK(wrong.y[0] - wrong.y[1] > 0.1);
}

TEST_CASE("lossy 4:2:0 and 4:1:1 video keeps each field's chroma in place to within the codec's quantisation",
          "[rig][recording][video]") {
    // Interlaced codecs code the two fields of a frame together and mix them a little at their quantisation;
    // a blob fixed in the frame for both of its fields leaves that mixing nothing to move. What is left is the
    // siting: a quarter field line wrong (DV's line-alternate chroma read as MPEG's) is 0.25 px and more.
    const auto fields = blob_fields(120, false);
    std::vector<VideoCodec> codecs{VideoCodec::kMpeg2, VideoCodec::kDv, VideoCodec::kDv411};
    if (encoder_available(VideoCodec::kH264)) codecs.push_back(VideoCodec::kH264);
    for (VideoCodec codec : codecs)
        for (int byte : {0, 2}) {
            INFO(to_string(codec) << (byte ? " Cr" : " Cb"));
            const Bias b = round_trip_bias(codec, VideoChroma::kCodec, fields, false, byte, true);
            INFO("x bias top " << b.x[0] << " bottom " << b.x[1] << ", y bias top " << b.y[0] << " bottom " << b.y[1]);
            for (int p = 0; p < 2; ++p) {
                CHECK(std::abs(b.x[p]) < 0.1);
                CHECK(std::abs(b.y[p]) < 0.1);
            }
        }
    const Bias wrong = round_trip_bias(VideoCodec::kDv, VideoChroma::kCodec, fields, false, 0, false);
    INFO("DV read as progressive: Cb y bias top " << wrong.y[0] << " bottom " << wrong.y[1]);
    CHECK(std::min(std::abs(wrong.y[0]), std::abs(wrong.y[1])) > 0.2);
}

TEST_CASE("opening a video costs its first frame, a corrupt tail is found when read, named by camera and field",
          "[rig][recording][video][errors]") {
    const Pair p = make_recordings("tail", "ffv1");
    const fs::path cam1 = fs::path(p.video) / "cam1.mkv";
    const auto size = fs::file_size(cam1);
    {
        // Overwrite the last 40 % with random bytes: opening cannot see it without decoding the whole file.
        std::fstream f(cam1, std::ios::in | std::ios::out | std::ios::binary);
        f.seekp(static_cast<std::streamoff>(size * 6 / 10));
        std::mt19937 rng(7);
        for (uintmax_t k = size * 6 / 10; k < size; ++k) f.put(static_cast<char>(rng() & 0xff));
    }
    Recording vid = Recording::open(p.video);
    Recording raw = Recording::open(p.raw);
    CHECK(vid.take_warnings().empty());
    CHECK(vid.decoded_frames(1) == 1);
    CHECK(vid.field_count(1) == 20);  // what the container says
    std::vector<uint8_t> f(kFieldBytes);
    int64_t first_lost = -1, lost = 0;
    for (int64_t i = 0; i < 20; ++i) {
        if (vid.read_field(1, i, f.data())) {
            if (first_lost < 0) CHECK(f == field_of(raw, 1, i));  // the data before the damage is intact
            continue;
        }
        if (first_lost < 0) first_lost = i;
        ++lost;
        bool black = true;  // Y 16, Cb = Cr = 128
        for (size_t k = 0; k < f.size(); k += 2) black = black && f[k] == 128 && f[k + 1] == 16;
        CHECK(black);
    }
    INFO("first lost field " << first_lost);
    REQUIRE(first_lost > 0);
    CHECK(vid.lost_fields(1) == lost);
    CHECK(vid.decoded_frames(1) <= 10);
    const std::vector<std::string> w = vid.take_warnings();
    REQUIRE(!w.empty());
    CHECK(w[0].find("cam1.mkv") != std::string::npos);
    CHECK(w[0].find("camera 1") != std::string::npos);
    CHECK(w[0].find("field " + std::to_string(first_lost)) != std::string::npos);
    CHECK(vid.take_warnings().empty());  // taken once
    CHECK(vid.warnings().size() == w.size());
    fs::remove_all(p.raw);
    fs::remove_all(p.video);
}

TEST_CASE("a truncated video: the fields before the cut read, then one warning naming camera and field",
          "[rig][recording][video][errors]") {
    // Formats whose container states the length (FFV1 in Matroska, DV in AVI): the cut is found when read.
    for (const std::string format : {"ffv1", "dv"}) {
        INFO(format);
        const Pair p = make_recordings("trunc", format);
        const std::string file = p.video + (format == "ffv1" ? "/cam2.mkv" : "/cam2.avi");
        const std::string intact = temp_dir("trunc_intact");
        copy_dir(p.video, intact);
        fs::resize_file(file, fs::file_size(file) / 2);
        Recording vid = Recording::open(p.video);
        Recording ref = Recording::open(intact);
        CHECK(vid.take_warnings().empty());
        CHECK(vid.field_count(2) == 20);
        std::vector<uint8_t> f(kFieldBytes);
        int64_t good = 0;
        while (good < 20 && vid.read_field(2, good, f.data())) {
            CHECK(f == field_of(ref, 2, good));  // as the whole file reads
            ++good;
        }
        INFO("fields read " << good);
        CHECK(good >= 4);
        CHECK(good < 20);
        for (int64_t i = good; i < 20; ++i) CHECK_FALSE(vid.read_field(2, i, f.data()));
        CHECK(vid.lost_fields(2) == 20 - good);
        const std::vector<std::string> w = vid.take_warnings();
        REQUIRE(!w.empty());
        CHECK(w.size() <= 3);  // the cut (and the one frame it halves), not one line per field
        CHECK(w.front().find(fs::path(file).filename().string()) != std::string::npos);
        CHECK(w.front().find("camera 2") != std::string::npos);
        CHECK(w.front().find("field " + std::to_string(good)) != std::string::npos);
        CHECK(vid.read_field(0, 19, f.data()));  // cameras that were not cut read on
        fs::remove_all(intact);
        fs::remove_all(p.raw);
        fs::remove_all(p.video);
    }
    // An MPEG program stream states no length: its duration is estimated from its last timestamps, so a cut file
    // is a shorter stream (and manifest.json's field count, when there is one, an error).
    const Pair p = make_recordings("trunc_ps", "mpeg2");
    const std::string file = p.video + "/cam2.mpg";
    fs::resize_file(file, fs::file_size(file) / 2);
    expect_open_error(p.video, "manifest.json: cameras[2].fields: says 20, cam2.mpg holds");
    fs::remove(p.video + "/manifest.json");
    Recording vid = Recording::open(p.video);
    CHECK(vid.field_count(2) < 20);
    CHECK(vid.common_field_count() == vid.field_count(2));
    fs::remove_all(p.raw);
    fs::remove_all(p.video);
}

TEST_CASE("not a video: random bytes, an empty file, a text file are one-line errors", "[rig][recording][video][errors]") {
    const Pair p = make_recordings("junk", "ffv1");
    std::mt19937 rng(3);
    for (const std::string name : {"cam0.mkv", "cam0.avi", "cam0.mp4", "cam0.mpg"}) {
        INFO(name);
        const std::string d = temp_dir("junk_copy");
        copy_dir(p.video, d);
        fs::remove(fs::path(d) / "cam0.mkv");
        fs::remove(fs::path(d) / "manifest.json");
        {
            std::ofstream o(fs::path(d) / name, std::ios::binary);
            for (int k = 0; k < 1 << 20; ++k) o.put(static_cast<char>(rng() & 0xff));
        }
        expect_open_error(d, name);
        std::ofstream(fs::path(d) / name, std::ios::trunc) << "not a video\n";
        expect_open_error(d, name);
        std::ofstream(fs::path(d) / name, std::ios::trunc).close();
        expect_open_error(d, name);
        fs::remove_all(d);
    }
    fs::remove_all(p.raw);
    fs::remove_all(p.video);
}

TEST_CASE("field order: from the stream, overridden by manifest.json field_order", "[rig][recording][video]") {
    const Pair p = make_recordings("order", "ffv1");
    Recording raw = Recording::open(p.raw);
    SECTION("the stream's order") {
        Recording vid = Recording::open(p.video);
        CHECK(vid.stream_description(0).find("field order tff (codec)") != std::string::npos);
    }
    SECTION("manifest says bottom first: field 2n is the bottom rows of frame n") {
        write_manifest_key(p.video, {{"field_order", "bff"}});
        Recording vid = Recording::open(p.video);
        for (int c = 0; c < 3; ++c) CHECK(vid.cameras()[c].first_field_parity == 1);
        CHECK(has_warning(vid, {"cam0.mkv", "bottom field first", "manifest.json field_order"}));
        for (int64_t n = 0; n < 3; ++n) {
            CHECK(vid.field_parity(1, 2 * n) == 1);
            CHECK(field_of(vid, 1, 2 * n) == field_of(raw, 1, 2 * n + 1));
            CHECK(field_of(vid, 1, 2 * n + 1) == field_of(raw, 1, 2 * n));
        }
    }
    SECTION("one camera's own field_order") {
        write_manifest_key(p.video, {{"cameras", nlohmann::json::array({nlohmann::json::object(),
                                                                         {{"field_order", "bff"}},
                                                                         nlohmann::json::object()})}});
        // merge_patch replaced the camera list: the entries no longer name files, which is allowed.
        Recording vid = Recording::open(p.video);
        CHECK(vid.cameras()[0].first_field_parity == 0);
        CHECK(vid.cameras()[1].first_field_parity == 1);
        CHECK(field_of(vid, 1, 0) == field_of(raw, 1, 1));
    }
    SECTION("progressive: two fields of one frame, no warning when the manifest says so") {
        write_manifest_key(p.video, {{"field_order", "progressive"}});
        Recording vid = Recording::open(p.video);
        CHECK(vid.warnings().empty());
        CHECK(vid.field_count(0) == 20);
        CHECK(field_of(vid, 0, 3) == field_of(raw, 0, 3));  // 4:2:2: the chroma needs no vertical siting
    }
    SECTION("a bad value is an error") {
        write_manifest_key(p.video, {{"field_order", "upside-down"}});
        expect_open_error(p.video, "manifest.json: field_order: is \"upside-down\", expected");
    }
    SECTION("raw fields: the manifest must agree with rig.yaml") {
        write_manifest_key(p.raw, {{"field_order", "bff"}});
        expect_open_error(p.raw, "manifest.json: field_order: says bff, but the raw fields of cam0.uyvy");
    }
    fs::remove_all(p.raw);
    fs::remove_all(p.video);
}

TEST_CASE("MPEG-2 with B-frames: any reading order gives the fields of a sequential reading",
          "[rig][recording][video]") {
    const Pair p = make_recordings("gop", "mpeg2");
    Recording seq = Recording::open(p.video);
    std::vector<std::vector<uint8_t>> want;
    for (int64_t i = 0; i < 20; ++i) want.push_back(field_of(seq, 0, i));
    CHECK(seq.warnings().empty());
    Recording rnd = Recording::open(p.video);
    std::vector<int64_t> order(20);
    for (int64_t i = 0; i < 20; ++i) order[static_cast<size_t>(i)] = i;
    std::shuffle(order.begin(), order.end(), std::mt19937(11));
    for (int64_t i : order) {
        INFO("field " << i);
        CHECK(field_of(rnd, 0, i) == want[static_cast<size_t>(i)]);
    }
    for (int64_t i = 19; i >= 0; --i) CHECK(field_of(rnd, 0, i) == want[static_cast<size_t>(i)]);
    fs::remove_all(p.raw);
    fs::remove_all(p.video);
}

TEST_CASE("synth writes each format as cameras record it: interlaced, top field first, 25 frames/s",
          "[rig][recording][video]") {
    const std::string d = temp_dir("formats");
    for (const std::string format : {"ffv1", "dv", "dv411", "mpeg2", "mpeg2-422", "h264", "ffv1-420", "ffv1-411"}) {
        VideoCodec codec;
        VideoChroma chroma;
        REQUIRE(parse_video_format(format, codec, chroma));
        if (!encoder_available(codec)) {
            SynthRequest req;
            req.out_dir = d;
            req.format = format;
            CHECK_THROWS_WITH(write_recording(req), Catch::Contains("no libx264"));
            continue;
        }
        const std::string path = d + "/v" + extension(codec);
        {
            VideoWriter w(path, codec, FieldOrder::kTopFirst, chroma);
            const std::vector<uint8_t> black = [] {
                std::vector<uint8_t> b(kFieldBytes);
                for (size_t k = 0; k < b.size(); k += 2) b[k] = 128, b[k + 1] = 16;
                return b;
            }();
            for (int k = 0; k < 3; ++k) w.write(black.data(), black.data());
            w.close();
        }
        VideoReader r(path);
        INFO(format << ": " << r.info().codec << " " << r.info().pixel_format);
        CHECK(r.info().order == FieldOrder::kTopFirst);
        CHECK(r.info().frame_rate_hz == Approx(25.0));
        CHECK(r.info().frames == 3);
        CHECK(r.info().width == 720);
        CHECK(r.info().height == 576);
        CHECK(r.info().chroma == (format == "ffv1" || format == "mpeg2-422"       ? "4:2:2"
                                  : format == "dv411" || format == "ffv1-411" ? "4:1:1"
                                                                              : "4:2:0"));
    }
    fs::remove_all(d);
}

TEST_CASE("encoder options: an interlaced-DCT metric the MPEG-2 encoder crashes on is a one-line error",
          "[rig][recording][video][errors]") {
    // FFmpeg's MPEG-2 encoder calls a null function in the first frame for most ildctcmp metrics; the writer
    // refuses them before the encoder sees a frame, and keeps the ones that work.
    const std::string d = temp_dir("ildct");
    const std::vector<uint8_t> black = [] {
        std::vector<uint8_t> b(kFieldBytes);
        for (size_t k = 0; k < b.size(); k += 2) b[k] = 128, b[k + 1] = 16;
        return b;
    }();
    for (VideoCodec codec : {VideoCodec::kMpeg2, VideoCodec::kMpeg2_422}) {
        for (const char* bad : {"ildctcmp=sse", "ildctcmp=sad", "ildctcmp=dct", "ildctcmp=nsse", "ildctcmp=1"}) {
            INFO(to_string(codec) << " " << bad);
            CHECK_THROWS_WITH(VideoWriter(d + "/bad.mpg", codec, FieldOrder::kTopFirst, VideoChroma::kCodec, bad),
                              Catch::Contains(bad) && Catch::Contains("vsad"));
        }
        for (const char* good : {"ildctcmp=vsse", "ildctcmp=satd", "ildctcmp=zero"}) {
            INFO(to_string(codec) << " " << good);
            VideoWriter w(d + "/good.mpg", codec, FieldOrder::kTopFirst, VideoChroma::kCodec, good);
            for (int k = 0; k < 3; ++k) w.write(black.data(), black.data());
            w.close();
            CHECK(VideoReader(d + "/good.mpg").info().frames == 3);
        }
    }
    fs::remove_all(d);
}

namespace {

/// Writes a `sweep` recording as MPEG-2 program streams and checks that opening counts every field of every
/// camera (Recording::open throws on a count that disagrees with manifest.json) and that the last one reads.
void check_program_stream_counts(const std::string& name, double seconds, uint64_t seed, const std::string& options) {
    const std::string d = temp_dir(name);
    SynthRequest req;
    req.scenario = "sweep";
    req.seconds = seconds;
    req.seed = seed;
    req.out_dir = d;
    req.format = "mpeg2";
    req.encoder_options = options;
    write_recording(req);
    Recording vid = Recording::open(d);
    const int64_t fields = std::llround(seconds * 50.0);
    std::vector<uint8_t> f(kFieldBytes);
    for (int cam = 0; cam < vid.camera_count(); ++cam) {
        INFO("camera " << cam);
        CHECK(vid.field_count(cam) == fields);
        CHECK(vid.read_field(cam, fields - 1, f.data()));
    }
    CHECK(vid.take_warnings().empty());
    fs::remove_all(d);
}

}  // namespace

TEST_CASE("an MPEG program stream of large frames counts its last frame (its length from the tail's timestamps)",
          "[rig][recording][video]") {
    // At the finest quantiser the frames are large, and FFmpeg's length estimate from the last few hundred KB
    // misses the last one: cam1 of this recording counted 99 of its 100 frames, and the manifest check refused
    // it (without a manifest its last frame would never have been read).
    check_program_stream_counts("ps_tail", 4.0, 2, "qmin=1:qmax=1:non_linear_quant=1");
}

TEST_CASE("an MPEG program stream whose last packet has no timestamp counts its last frame",
          "[rig][recording][video]") {
    // The program stream muxer can leave the last packet without a PTS: in cam1 of this recording a P frame after
    // the last I frame and its two B frames. Counted from the largest timestamp alone, that camera held 49 of its
    // 50 frames and the manifest check refused the recording; packets without a timestamp after the largest are
    // frames after it.
    check_program_stream_counts("ps_untimed_tail", 2.0, 97, "");
}
