#include "eyesim/rig/recording.hpp"

#include "eyesim/rig/error.hpp"
#include "eyesim/rig/video.hpp"

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>

namespace eyesim::rig {

namespace fs = std::filesystem;

void bgr_to_uyvy(const uint8_t* bgr, int bgr_stride, int width, int rows, uint8_t* uyvy, int uyvy_stride) {
    const float ky = 219.f / 255.f, kc = 224.f / 255.f;
    for (int r = 0; r < rows; ++r) {
        const uint8_t* in = bgr + static_cast<ptrdiff_t>(r) * bgr_stride;
        uint8_t* o = uyvy + static_cast<ptrdiff_t>(r) * uyvy_stride;
        for (int x = 0; x + 1 < width; x += 2) {
            const uint8_t* p0 = in + x * 3;
            const uint8_t* p1 = p0 + 3;
            const uint8_t* pm = x > 0 ? p0 - 3 : p0;
            // BGR order in memory.
            const float l0 = 0.299f * p0[2] + 0.587f * p0[1] + 0.114f * p0[0];
            const float l1 = 0.299f * p1[2] + 0.587f * p1[1] + 0.114f * p1[0];
            const float fr = 0.25f * (pm[2] + 2.f * p0[2] + p1[2]);
            const float fg = 0.25f * (pm[1] + 2.f * p0[1] + p1[1]);
            const float fb = 0.25f * (pm[0] + 2.f * p0[0] + p1[0]);
            const float lf = 0.299f * fr + 0.587f * fg + 0.114f * fb;
            o[x * 2 + 0] = static_cast<uint8_t>(std::clamp(std::lrint(128.f + kc * (fb - lf) / 1.772f), 16l, 240l));
            o[x * 2 + 1] = static_cast<uint8_t>(std::clamp(std::lrint(16.f + ky * l0), 16l, 235l));
            o[x * 2 + 2] = static_cast<uint8_t>(std::clamp(std::lrint(128.f + kc * (fr - lf) / 1.402f), 16l, 240l));
            o[x * 2 + 3] = static_cast<uint8_t>(std::clamp(std::lrint(16.f + ky * l1), 16l, 235l));
        }
    }
}

void uyvy_to_bgr(const uint8_t* uyvy, int uyvy_stride, int width, int rows, uint8_t* bgr, int bgr_stride) {
    const float iy = 255.f / 219.f, ic = 255.f / 224.f;
    for (int r = 0; r < rows; ++r) {
        const uint8_t* in = uyvy + static_cast<ptrdiff_t>(r) * uyvy_stride;
        uint8_t* o = bgr + static_cast<ptrdiff_t>(r) * bgr_stride;
        for (int x = 0; x < width; ++x) {
            const int pair = x / 2;
            const float Y = (in[x * 2 + 1] - 16.f) * iy;
            float cb = in[pair * 4] - 128.f, cr = in[pair * 4 + 2] - 128.f;
            if ((x & 1) && pair + 1 < width / 2) {
                cb = 0.5f * (cb + in[(pair + 1) * 4] - 128.f);
                cr = 0.5f * (cr + in[(pair + 1) * 4 + 2] - 128.f);
            }
            const float R = Y + 1.402f * cr * ic;
            const float B = Y + 1.772f * cb * ic;
            const float G = (Y - 0.299f * R - 0.114f * B) / 0.587f;
            o[x * 3 + 0] = static_cast<uint8_t>(std::clamp(std::lrint(B), 0l, 255l));
            o[x * 3 + 1] = static_cast<uint8_t>(std::clamp(std::lrint(G), 0l, 255l));
            o[x * 3 + 2] = static_cast<uint8_t>(std::clamp(std::lrint(R), 0l, 255l));
        }
    }
}

struct Recording::Impl {
    std::string dir;
    std::vector<CameraModel> cams;
    std::vector<std::string> warnings;
    size_t warnings_taken = 0;
    struct Stream {
        std::string path;
        StreamFormat format = StreamFormat::kRawUyvy;
        int64_t fields = 0;
        std::ifstream raw;
        std::unique_ptr<VideoReader> video;
        bool progressive = false;        // about 50 frames/s: one field per frame
        bool chroma_interlaced = true;   // 4:2:0 chroma rows alternate between the fields
        std::vector<bool> lost_mask;     // fields read_field could not deliver
        int64_t lost = 0;                // how many
        int loss_lines = 0;              // lost-field warnings written for this camera
        bool end_reported = false;       // the early end of the stream has been reported
    };
    std::vector<Stream> streams;

    [[noreturn]] void fail(const std::string& file, const std::string& key, const std::string& why) const {
        throw RigError(fmt::format("{}: {}: {}", (fs::path(dir) / file).string(), key, why));
    }
    void open_video(size_t cam, Stream& s, FieldOrder override_order);
    void lost(int cam, int64_t index, int64_t frame, FrameStatus status, const std::string& why);
};

/// Video streams: which file extensions are looked for, in order after `.uyvy`.
constexpr const char* kVideoExtensions[] = {".avi", ".mkv", ".mp4", ".mov", ".mpg", ".mpeg", ".vob",
                                            ".ts",  ".m2ts", ".mts", ".dv"};
/// Lost-field lines per camera before the rest are only counted.
constexpr int kMaxLossLines = 10;

void Recording::Impl::open_video(size_t cam, Stream& s, FieldOrder override_order) {
    s.video = std::make_unique<VideoReader>(s.path);  // RigError names the file
    const VideoInfo& vi = s.video->info();
    const double fps = vi.frame_rate_hz;
    CameraModel& cm = cams[cam];
    const FieldOrder order = override_order != FieldOrder::kUnknown ? override_order : vi.order;
    s.progressive = std::abs(fps - 50.0) < 2.0;
    s.chroma_interlaced = order == FieldOrder::kTopFirst || order == FieldOrder::kBottomFirst;
    if (s.progressive)
        warnings.push_back(
            fmt::format("{}: {:.3g} frames/s: taken as progressive, one field per frame", s.path, fps));
    else if (std::abs(fps - 25.0) > 1.0)
        warnings.push_back(fmt::format("{}: {:.3g} frames/s (PAL is 25): taken as interlaced, two fields per frame",
                                       s.path, fps > 0 ? fps : 0.0));
    if (order == FieldOrder::kTopFirst || order == FieldOrder::kBottomFirst) {
        // The stream (or the manifest) says which field comes first: the camera's parities follow it.
        const int first = order == FieldOrder::kTopFirst ? 0 : 1;
        if (first != cm.first_field_parity)
            warnings.push_back(fmt::format(
                "{}: {} field first ({}): rig.yaml's first_field_parity {} for {} is taken as {}", s.path,
                first ? "bottom" : "top",
                override_order != FieldOrder::kUnknown ? "manifest.json field_order" : "the stream says so",
                cm.first_field_parity, cm.name, first));
        cm.first_field_parity = first;
    } else if (!s.progressive && order == FieldOrder::kProgressive && override_order == FieldOrder::kUnknown) {
        warnings.push_back(fmt::format(
            "{}: the stream says its frames are progressive: each frame gives two fields of one instant, 4:2:0 "
            "chroma sited as progressive (manifest.json field_order \"tff\" or \"bff\" if the camera was "
            "interlaced)",
            s.path));
    } else if (!s.progressive && order == FieldOrder::kUnknown) {
        warnings.push_back(fmt::format(
            "{}: the stream does not say its field order: taken as interlaced, {} field first (rig.yaml "
            "first_field_parity {}; manifest.json field_order overrides)",
            s.path, cm.first_field_parity ? "bottom" : "top", cm.first_field_parity));
    }
    s.fields = s.progressive ? vi.frames : 2 * vi.frames;
}

void Recording::Impl::lost(int cam, int64_t index, int64_t frame, FrameStatus status, const std::string& why) {
    Stream& s = streams[static_cast<size_t>(cam)];
    if (s.lost_mask.empty()) s.lost_mask.assign(static_cast<size_t>(s.fields), false);
    if (!s.lost_mask[static_cast<size_t>(index)]) {
        s.lost_mask[static_cast<size_t>(index)] = true;
        ++s.lost;
    }
    if (status == FrameStatus::kPastEnd) {
        if (s.end_reported) return;
        s.end_reported = true;
        warnings.push_back(fmt::format("{}: camera {} ({}) field {} (frame {}) lost: {}: fields {}..{} are lost",
                                       s.path, cam, cams[static_cast<size_t>(cam)].name, index, frame, why, index,
                                       s.fields - 1));
        return;
    }
    if (s.loss_lines > kMaxLossLines) return;
    if (++s.loss_lines > kMaxLossLines) {
        warnings.push_back(fmt::format("{}: camera {}: more lost fields: counted, not listed", s.path, cam));
        return;
    }
    warnings.push_back(fmt::format("{}: camera {} ({}) field {} (frame {}) lost: {}", s.path, cam,
                                   cams[static_cast<size_t>(cam)].name, index, frame, why));
}

Recording::Recording(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
Recording::Recording(Recording&&) noexcept = default;
Recording& Recording::operator=(Recording&&) noexcept = default;
Recording::~Recording() = default;

Recording Recording::open(const std::string& dir) {
    auto d = std::make_unique<Impl>();
    d->dir = dir;
    if (!fs::is_directory(dir)) throw RigError(fmt::format("{}: directory: missing", dir));
    d->cams = load_rig_yaml((fs::path(dir) / "rig.yaml").string());
    // Optional manifest: read first (its field_order overrides what video streams say), checked against the
    // files after they are opened.
    const fs::path mpath = fs::path(dir) / "manifest.json";
    const bool have_manifest = fs::exists(mpath);
    nlohmann::json j;
    if (have_manifest) {
        std::ifstream in(mpath);
        try {
            j = nlohmann::json::parse(in);
        } catch (const nlohmann::json::parse_error& e) {
            d->fail("manifest.json", "file", fmt::format("malformed JSON at byte {}", e.byte));
        }
        if (!j.is_object()) d->fail("manifest.json", "file", "not a JSON object");
    }
    auto field_order_at = [&](const nlohmann::json& o, const std::string& key) {
        FieldOrder f = FieldOrder::kUnknown;
        if (!o.is_object() || !o.contains("field_order")) return f;
        if (!o["field_order"].is_string() || !parse_field_order(o["field_order"].get<std::string>(), f))
            d->fail("manifest.json", key,
                    fmt::format("is {}, expected \"tff\", \"bff\" or \"progressive\"", o["field_order"].dump()));
        return f;
    };
    const FieldOrder order_all = field_order_at(j, "field_order");
    d->streams.resize(d->cams.size());
    for (size_t c = 0; c < d->cams.size(); ++c) {
        Impl::Stream& s = d->streams[c];
        const std::string stem = d->cams[c].name;
        std::string tried = stem + ".uyvy";
        if (fs::exists(fs::path(dir) / tried)) s.path = (fs::path(dir) / tried).string();
        for (const char* e : kVideoExtensions) {
            if (!s.path.empty()) break;
            const fs::path p = fs::path(dir) / (stem + e);
            if (fs::exists(p)) {
                s.path = p.string();
                s.format = StreamFormat::kVideo;
            }
        }
        if (s.path.empty())
            d->fail(stem + ".uyvy", "file", fmt::format("missing (nor a video {}.avi, .mkv, .mp4, .mpg, ...)", stem));
        const std::string fname = fs::path(s.path).filename().string();
        FieldOrder order = order_all;
        const std::string cam_key = fmt::format("cameras[{}].field_order", c);
        if (have_manifest && j.contains("cameras") && j["cameras"].is_array() && c < j["cameras"].size())
            if (const FieldOrder f = field_order_at(j["cameras"][c], cam_key); f != FieldOrder::kUnknown) order = f;
        if (s.format == StreamFormat::kRawUyvy) {
            if (order == FieldOrder::kProgressive ||
                (order != FieldOrder::kUnknown && (order == FieldOrder::kBottomFirst) != (d->cams[c].first_field_parity == 1)))
                d->fail("manifest.json", "field_order",
                        fmt::format("says {}, but the raw fields of {} take their parity from rig.yaml "
                                    "(first_field_parity {})",
                                    to_string(order), fname, d->cams[c].first_field_parity));
            std::error_code ec;
            const auto size = fs::file_size(s.path, ec);
            if (ec) d->fail(fname, "file", "size unreadable");
            if (size == 0) d->fail(fname, "size", "empty file (0 fields)");
            if (size % kFieldBytes != 0)
                d->fail(fname, "size",
                        fmt::format("{} bytes is not a whole number of 720x288 UYVY fields ({} bytes each): "
                                    "truncated or wrong field size ({} whole fields + {} bytes)",
                                    size, kFieldBytes, size / kFieldBytes, size % kFieldBytes));
            s.fields = static_cast<int64_t>(size / kFieldBytes);
            s.raw.open(s.path, std::ios::binary);
            if (!s.raw) d->fail(fname, "file", "cannot be opened");
        } else {
            d->open_video(c, s, order);
        }
    }
    if (have_manifest) {
        auto num = [&](const char* key, double expect) {
            if (!j.contains(key)) return;
            if (!j[key].is_number()) d->fail("manifest.json", key, "not a number");
            if (j[key].get<double>() != expect)
                d->fail("manifest.json", key, fmt::format("is {}, expected {}", j[key].dump(), expect));
        };
        num("field_width", kFieldWidth);
        num("field_height", kFieldHeight);
        num("field_rate_hz", kFieldRateHz);
        num("field_bytes", kFieldBytes);
        if (j.contains("format")) {
            // The streams found decide how fields are read; a manifest saying otherwise describes other files.
            const bool raw = d->streams[0].format == StreamFormat::kRawUyvy;
            if (!j["format"].is_string() || (j["format"] != "uyvy" && j["format"] != "video"))
                d->fail("manifest.json", "format", fmt::format("is {}, expected \"uyvy\" or \"video\"", j["format"].dump()));
            if ((j["format"] == "uyvy") != raw)
                d->fail("manifest.json", "format",
                        fmt::format("says {}, but {} is {}", j["format"].dump(),
                                    fs::path(d->streams[0].path).filename().string(), raw ? "raw UYVY" : "video"));
        }
        if (j.contains("cameras")) {
            const auto& cj = j["cameras"];
            if (!cj.is_array() || cj.size() != d->cams.size())
                d->fail("manifest.json", "cameras",
                        fmt::format("must list {} cameras (rig.yaml camera_count)", d->cams.size()));
            for (size_t c = 0; c < cj.size(); ++c) {
                const std::string at = fmt::format("cameras[{}]", c);
                if (!cj[c].is_object()) d->fail("manifest.json", at, "not a JSON object");
                const std::string found = fs::path(d->streams[c].path).filename().string();
                if (cj[c].contains("file") && (!cj[c]["file"].is_string() || cj[c]["file"] != found))
                    d->fail("manifest.json", at + ".file",
                            fmt::format("says {}, but camera {}'s stream is {}", cj[c]["file"].dump(), c, found));
                if (cj[c].contains("fields")) {
                    if (!cj[c]["fields"].is_number_integer())
                        d->fail("manifest.json", fmt::format("cameras[{}].fields", c), "not an integer");
                    const int64_t f = cj[c]["fields"].get<int64_t>();
                    if (f != d->streams[c].fields)
                        d->fail("manifest.json", fmt::format("cameras[{}].fields", c),
                                fmt::format("says {}, {} holds {}", f, fs::path(d->streams[c].path).filename().string(),
                                            d->streams[c].fields));
                }
            }
        }
    }
    return Recording(std::move(d));
}

int Recording::camera_count() const noexcept { return static_cast<int>(impl_->cams.size()); }
const std::vector<CameraModel>& Recording::cameras() const noexcept { return impl_->cams; }
const std::string& Recording::dir() const noexcept { return impl_->dir; }
const std::vector<std::string>& Recording::warnings() const noexcept { return impl_->warnings; }

namespace {
void check_cam_index(const std::string& dir, size_t count, int cam) {
    if (cam < 0 || cam >= static_cast<int>(count))
        throw RigError(fmt::format("{}: camera: index {} out of range 0..{}", dir, cam, count - 1));
}
}  // namespace

int64_t Recording::field_count(int cam) const {
    check_cam_index(impl_->dir, impl_->cams.size(), cam);
    return impl_->streams[cam].fields;
}

int64_t Recording::common_field_count() const {
    int64_t n = INT64_MAX;
    for (const auto& s : impl_->streams) n = std::min(n, s.fields);
    return impl_->streams.empty() ? 0 : n;
}

StreamFormat Recording::format(int cam) const {
    check_cam_index(impl_->dir, impl_->cams.size(), cam);
    return impl_->streams[cam].format;
}

const std::string& Recording::stream_path(int cam) const {
    check_cam_index(impl_->dir, impl_->cams.size(), cam);
    return impl_->streams[cam].path;
}

int Recording::field_parity(int cam, int64_t index) const {
    check_cam_index(impl_->dir, impl_->cams.size(), cam);
    return impl_->cams[cam].field_parity(index);
}

FieldTiming Recording::field_timing(int cam, int64_t index) const {
    check_cam_index(impl_->dir, impl_->cams.size(), cam);
    return impl_->cams[cam].field_timing(index);
}

std::string Recording::truth_path() const {
    const fs::path p = fs::path(impl_->dir) / "truth.jsonl";
    return fs::exists(p) ? p.string() : std::string();
}

bool Recording::read_field(int cam, int64_t index, uint8_t* uyvy_out) {
    check_cam_index(impl_->dir, impl_->cams.size(), cam);
    Impl::Stream& s = impl_->streams[cam];
    const std::string fname = fs::path(s.path).filename().string();
    if (index < 0 || index >= s.fields)
        impl_->fail(fname, "field", fmt::format("index {} out of range 0..{}", index, s.fields - 1));
    if (s.format == StreamFormat::kRawUyvy) {
        s.raw.clear();
        s.raw.seekg(static_cast<std::streamoff>(index) * kFieldBytes);
        s.raw.read(reinterpret_cast<char*>(uyvy_out), kFieldBytes);
        if (s.raw.gcount() != kFieldBytes) impl_->fail(fname, "field", fmt::format("field {} could not be read", index));
        return true;
    }
    const int parity = impl_->cams[cam].field_parity(index);
    const int64_t frame = s.progressive ? index : index / 2;
    std::string why;
    const FrameStatus st = s.video->load_frame(frame, why);
    if (st != FrameStatus::kOk) {
        // Black (Y 16, Cb = Cr = 128): nothing in it is taken for a marker.
        for (size_t k = 0; k < static_cast<size_t>(kFieldBytes); k += 2) {
            uyvy_out[k] = 128;
            uyvy_out[k + 1] = 16;
        }
        impl_->lost(cam, index, frame, st, why);
        return false;
    }
    s.video->extract_field(parity, s.chroma_interlaced, uyvy_out);
    return true;
}

std::vector<std::string> Recording::take_warnings() {
    std::vector<std::string> out(impl_->warnings.begin() + static_cast<std::ptrdiff_t>(impl_->warnings_taken),
                                 impl_->warnings.end());
    impl_->warnings_taken = impl_->warnings.size();
    return out;
}

int64_t Recording::lost_fields(int cam) const {
    check_cam_index(impl_->dir, impl_->cams.size(), cam);
    return impl_->streams[cam].lost;
}

int64_t Recording::decoded_frames(int cam) const {
    check_cam_index(impl_->dir, impl_->cams.size(), cam);
    const Impl::Stream& s = impl_->streams[cam];
    return s.video ? s.video->decoded_frames() : 0;
}

std::string Recording::stream_description(int cam) const {
    check_cam_index(impl_->dir, impl_->cams.size(), cam);
    const Impl::Stream& s = impl_->streams[cam];
    if (!s.video) return "raw UYVY 4:2:2 fields";
    const VideoInfo& v = s.video->info();
    return fmt::format("{} {} ({}, chroma {}), {:.4g} frames/s, {} frames, field order {} ({}), {}", v.codec,
                       v.pixel_format, v.chroma, v.chroma_location, v.frame_rate_hz, v.frames, to_string(v.order),
                       v.order_source,
                       s.progressive ? "one field per frame"
                       : s.chroma_interlaced ? "two fields per frame, chroma per field"
                                             : "two fields per frame, progressive chroma");
}

void write_manifest(const std::string& dir, const Manifest& m) {
    nlohmann::json j;
    j["format"] = m.format;
    j["field_width"] = m.field_width;
    j["field_height"] = m.field_height;
    j["field_rate_hz"] = m.field_rate_hz;
    j["field_bytes"] = kFieldBytes;
    if (!m.codec.empty()) j["codec"] = m.codec;
    j["pixel_format"] = m.format == "uyvy" ? "UYVY (Cb Y0 Cr Y1), BT.601 studio swing, first field top"
                                           : "woven 720x576 frames, 25 frames/s, interlaced, BT.601 studio swing";
    nlohmann::json cams = nlohmann::json::array();
    for (size_t c = 0; c < m.files.size(); ++c)
        cams.push_back({{"name", fmt::format("cam{}", c)}, {"file", m.files[c]},
                        {"fields", c < m.fields.size() ? m.fields[c] : 0}});
    j["cameras"] = cams;
    if (!m.scenario.empty()) j["scenario"] = m.scenario;
    j["seed"] = m.seed;
    const fs::path p = fs::path(dir) / "manifest.json";
    std::ofstream out(p);
    out << j.dump(2) << '\n';
    if (!out) throw RigError(fmt::format("{}: file: cannot be written", p.string()));
}

}  // namespace eyesim::rig
