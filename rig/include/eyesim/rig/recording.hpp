#pragma once
/// \file
/// Reading a recording directory: rig.yaml + one field stream per camera, optional manifest.json.
///
/// Directory contract
/// - `rig.yaml` (required): the cameras (camera.hpp). Its `camera_count` says how many streams to expect.
/// - `cam<k>.uyvy`: raw 720×288 UYVY fields (414,720 bytes each) concatenated, first field top (parity per
///   rig.yaml's first_field_parity). Byte order per pixel pair: Cb Y0 Cr Y1 (BT.656 / BT.601 4:2:2, Y in
///   16..235, Cb/Cr in 16..240, Cb/Cr co-sited with Y0). Field count = file size / 414,720; any remainder is
///   a truncated file and an error.
/// - or `cam<k>.avi` / `.mkv` / `.mp4`: any video OpenCV reads, 720×576 frames. At about 25 frames/s the frames
///   are interlaced: frame n gives field 2n (rows 0,2,...; top) and 2n+1 (rows 1,3,...; bottom). At about
///   50 frames/s the video is taken as progressive (a warning is recorded in `warnings()`): frame n gives one
///   field of parity n mod 2 (its rows of that parity). Colour is converted BGR → BT.601 studio-swing YCbCr
///   with [1 2 1]/4 co-sited chroma filtering, as the synthetic renderer does.
/// - `manifest.json` (optional, never required): {"format":"uyvy"|"video", "field_width":720,
///   "field_height":288, "field_rate_hz":50, "cameras":[{"name":"cam0","file":"cam0.uyvy","fields":N},...]}.
///   When present it is checked against the files; disagreement is an error.
/// - `truth.jsonl` (optional here; see truth.hpp).
/// Every problem throws RigError naming the file and what is wrong.

#include "eyesim/rig/camera.hpp"

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

namespace eyesim::rig {

/// Storage of one camera's stream.
enum class StreamFormat { kRawUyvy, kVideo };

/// An opened, validated recording directory. Reading is thread-compatible (one reader per thread).
class Recording {
public:
    /// Opens and validates `dir` (see the file comment). Throws RigError.
    static Recording open(const std::string& dir);

    Recording(Recording&&) noexcept;
    Recording& operator=(Recording&&) noexcept;
    ~Recording();

    /// Number of cameras (rig.yaml camera_count).
    int camera_count() const noexcept;
    /// The cameras from rig.yaml.
    const std::vector<CameraModel>& cameras() const noexcept;
    /// Number of fields in camera `cam`'s stream.
    int64_t field_count(int cam) const;
    /// Smallest field count over all cameras.
    int64_t common_field_count() const;
    /// Storage of camera `cam`'s stream.
    StreamFormat format(int cam) const;
    /// Path of camera `cam`'s stream file.
    const std::string& stream_path(int cam) const;

    /// Copies field `index` of camera `cam` as UYVY (kFieldBytes bytes, row-major, 1440 bytes per line) into
    /// `uyvy_out`. Throws RigError on a bad index or a read/decode failure. Sequential access is fastest.
    void read_field(int cam, int64_t index, uint8_t* uyvy_out);
    /// Parity of field `index` of camera `cam` (0 = top).
    int field_parity(int cam, int64_t index) const;
    /// Timing of field `index` of camera `cam` (pal.hpp model, rig.yaml clock offset and shutter).
    FieldTiming field_timing(int cam, int64_t index) const;
    /// Time the last active pixel of field `index` of camera `cam` is delivered, µs on the recording clock.
    double field_end_time_us(int cam, int64_t index) const { return field_timing(cam, index).end_us; }

    /// Directory this recording was opened from.
    const std::string& dir() const noexcept;
    /// Non-fatal findings (e.g. progressive video), one line each.
    const std::vector<std::string>& warnings() const noexcept;
    /// Path of truth.jsonl if the directory has one, else empty.
    std::string truth_path() const;

private:
    struct Impl;
    explicit Recording(std::unique_ptr<Impl> impl);
    std::unique_ptr<Impl> impl_;
};

/// Manifest written by the synthesiser (and optionally by capture tools); see the file comment.
struct Manifest {
    std::string format = "uyvy";               ///< "uyvy" or "video"
    int field_width = kFieldWidth;             ///< 720
    int field_height = kFieldHeight;           ///< 288
    double field_rate_hz = kFieldRateHz;       ///< 50
    std::vector<std::string> files;            ///< stream file name per camera
    std::vector<int64_t> fields;               ///< field count per camera
    std::string scenario;                      ///< free text (synthetic recordings: scenario name)
    uint64_t seed = 0;                         ///< synthetic recordings: the seed
};

/// Writes `<dir>/manifest.json`. Throws RigError if it cannot be written.
void write_manifest(const std::string& dir, const Manifest& manifest);

/// Converts a BGR 8-bit image row range to UYVY with the BT.601 studio-swing matrix and [1 2 1]/4 co-sited
/// chroma; `bgr` is `width`×`rows` (3 bytes per pixel, `bgr_stride` bytes per row), width even.
void bgr_to_uyvy(const uint8_t* bgr, int bgr_stride, int width, int rows, uint8_t* uyvy, int uyvy_stride);
/// Converts UYVY to BGR (chroma linearly interpolated to odd pixels), inverse BT.601 studio swing.
void uyvy_to_bgr(const uint8_t* uyvy, int uyvy_stride, int width, int rows, uint8_t* bgr, int bgr_stride);

}  // namespace eyesim::rig
