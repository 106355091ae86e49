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
/// - or a video `cam<k>.avi` / `.mkv` / `.mp4` / `.mov` / `.mpg` / `.mpeg` / `.vob` / `.ts` / `.m2ts` / `.mts` /
///   `.dv` (first found in that order), 720×576 frames, read through FFmpeg in the decoder's own YUV planes
///   (video.hpp: chroma re-sited per pixel format; a lossless 4:2:2 file gives the raw fields bit for bit).
///   Opening reads the container header and decodes the first frame only: the field count comes from the
///   container (frame count, or duration × frame rate).
///   At about 25 frames/s the frames are interlaced: frame n gives fields 2n and 2n+1 in temporal order. Field
///   order: manifest.json's `field_order` if it has one, else the stream's (codec flags, else container), else
///   rig.yaml's first_field_parity with a warning. A stated order sets the camera's first_field_parity in
///   cameras() (a warning when rig.yaml said otherwise), so field_parity() and field_timing() follow the video.
///   A stream that says it is progressive at 25 frames/s gives two fields per frame with progressive 4:2:0
///   chroma (a warning). At about 50 frames/s the video is taken as progressive (a warning): frame n gives one
///   field of parity field_parity(n) (its rows of that parity). Other rates: a warning, taken as interlaced.
///   A field that cannot be read (the stream ends early, a frame is missing or decodes with errors) is a
///   warning naming the camera and field; read_field gives a black field and returns false; lost_fields()
///   counts them. A file that is no video, or whose first frame does not decode, is an error at open.
/// - `manifest.json` (optional, never required): {"format":"uyvy"|"video", "codec":"ffv1"|..., "field_width":720,
///   "field_height":288, "field_rate_hz":50, "field_order":"tff"|"bff"|"progressive",
///   "cameras":[{"name":"cam0","file":"cam0.uyvy","fields":N,"field_order":...},...]}. `field_order` (top level
///   for every camera, or per camera) overrides the order a video stream states; for raw fields it must agree
///   with rig.yaml.
///   When present it is checked against the files; disagreement is an error.
/// - `truth.jsonl` (optional here; see truth.hpp).
/// Every problem at open() throws RigError naming the file and what is wrong.

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
    /// `uyvy_out` and returns true. A video field that cannot be read (see the file comment) is black, adds a
    /// warning naming the camera and field (take_warnings()), and returns false. Throws RigError on a bad index
    /// or an unreadable raw file. Sequential access is fastest; any order is correct.
    bool read_field(int cam, int64_t index, uint8_t* uyvy_out);
    /// Parity of field `index` of camera `cam` (0 = top).
    int field_parity(int cam, int64_t index) const;
    /// Timing of field `index` of camera `cam` (pal.hpp model, rig.yaml clock offset and shutter).
    FieldTiming field_timing(int cam, int64_t index) const;
    /// Time the last active pixel of field `index` of camera `cam` is delivered, µs on the recording clock.
    double field_end_time_us(int cam, int64_t index) const { return field_timing(cam, index).end_us; }

    /// Directory this recording was opened from.
    const std::string& dir() const noexcept;
    /// Non-fatal findings so far, one line each: those of open() (e.g. progressive video) and those read_field()
    /// has added (lost fields).
    const std::vector<std::string>& warnings() const noexcept;
    /// The findings not taken before: on the first call all of open()'s, then those read_field() has added since.
    /// Tools print these as they go.
    std::vector<std::string> take_warnings();
    /// Fields of camera `cam` that read_field() could not deliver (each counted once).
    int64_t lost_fields(int cam) const;
    /// Frames camera `cam`'s video decoder has output so far, open() included (0 for raw fields).
    int64_t decoded_frames(int cam) const;
    /// One line on camera `cam`'s stream: codec, pixel format, chroma siting, rate, frames, field order.
    std::string stream_description(int cam) const;
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
    std::string codec;                         ///< video: "ffv1", "dv", "dv411", "mpeg2", "h264" (video.hpp)
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
