#pragma once
/// \file
/// Video files as PAL cameras record them, read and written through the FFmpeg libraries (libavformat,
/// libavcodec) in the decoder's own YUV planes: no RGB round trip.
///
/// Reading (VideoReader): one persistent demuxer + decoder per file. Opening reads the container header and
/// decodes the first frame only; the frame count comes from the container (frame count, or duration × rate).
/// Each woven 720×576 frame splits into two UYVY 720×288 fields (field parity p = frame rows 2y + p) with the
/// chroma re-sited to the raw fields' convention (camera.hpp, renderer.hpp: 4:2:2, Cb/Cr co-sited with even
/// pixels):
/// - 4:2:2 (FFV1, MPEG-2 4:2:2, DVCPRO50, packed UYVY/YUYV): horizontally co-sited chroma is copied as is, so a
///   lossless 4:2:2 file gives back the raw fields bit for bit; horizontally centred chroma (JPEG) is
///   interpolated to the even pixels.
/// - 4:2:0 interlaced (MPEG-2, H.264): the chroma plane's rows alternate between the fields (row 2j + p is
///   field p's chroma row j) and sit between the field's lines, at field line 2j + 1/4 (top) and 2j + 3/4
///   (bottom); each field's chroma is interpolated within that field only. DV (625/50) is line-alternate: in
///   each field Cr sits on the even field lines 2j and Cb on the odd lines 2j + 1. Chroma sited at the top
///   (FFmpeg's "topleft") sits on field line 2j.
/// - 4:2:0 progressive (only when the stream says so): chroma row j sits at frame line 2j + 1/2 ("left",
///   "center", unspecified) or 2j ("topleft") and is interpolated at each field line's frame position.
/// - 4:1:1 (NTSC DV, DVCPRO25): chroma co-sited with every fourth pixel, interpolated to the even pixels.
/// - 4:4:4: the renderer's [1 2 1]/4 filter at the even pixels. Full-range (JPEG) YUV is scaled to studio swing;
///   10- and 16-bit samples are rounded to 8 bits; RGB frames go through the BT.601 matrix (bgr_to_uyvy).
/// Field order: the codec's own flags (interlaced, top field first) of the first frame, else the container's
/// field order (its first letter: FFmpeg's "tb" is top first, as FFmpeg writes woven top-first video), else
/// unknown. VideoReader only reports it; Recording decides (recording.hpp).
///
/// Writing (VideoWriter): woven 720×576 frames at 25 frames/s from pairs of UYVY fields, flagged interlaced with
/// the given field order in the bitstream and the container, subsampled from the fields' own chroma (never across
/// the woven frame) with the siting above.

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

namespace eyesim::rig {

/// Temporal order of the two fields of a frame.
enum class FieldOrder {
    kUnknown,      ///< not recorded in the stream
    kTopFirst,     ///< interlaced, top field (frame rows 0, 2, ...) first
    kBottomFirst,  ///< interlaced, bottom field first
    kProgressive,  ///< the stream says its frames are progressive
};

/// "tff", "bff", "progressive" or "unknown".
const char* to_string(FieldOrder order);
/// Parses "tff" / "bff" / "progressive" (also "top", "bottom"). Returns false on anything else.
bool parse_field_order(const std::string& text, FieldOrder& out);

/// What the container and the first frame say about a video stream.
struct VideoInfo {
    std::string codec;               ///< FFmpeg codec name, e.g. "ffv1", "dvvideo", "mpeg2video", "h264"
    std::string pixel_format;        ///< FFmpeg pixel format name of the decoded frames, e.g. "yuv422p"
    std::string chroma;              ///< "4:2:2", "4:2:0", "4:1:1", "4:4:4", "4:0:0" or "RGB"
    std::string chroma_location;     ///< FFmpeg's chroma location name ("left", "topleft", "unspecified", ...)
    int width = 0;                   ///< frame width, pixels
    int height = 0;                  ///< frame height, lines
    double frame_rate_hz = 0;        ///< frames per second (container, else codec; 0 when unknown)
    int64_t frames = 0;              ///< frame count from the container (count, or duration × rate)
    FieldOrder order = FieldOrder::kUnknown;  ///< field order the stream states
    std::string order_source;        ///< "codec", "container" or "none"
};

/// For interlaced 4:2:0 video as VideoReader splits it: the field line (of the field of `parity`, 0 top) at which
/// chroma row 0 of `component` (0 Cb, 1 Cr) is sited; row k lies 2k lines further. VideoReader gives each field
/// line the linear interpolation between the two rows about it. DV's line-alternate 4:2:0: Cr 0, Cb 1; chroma
/// location top / topleft 0, bottom / bottomleft 1; else (MPEG-2, H.264: left, center, unspecified) 0.25 for the
/// top field and 0.75 for the bottom (the frame's rows 2k + ½ split between the fields).
double field_chroma_site(const VideoInfo& info, int parity, int component);

/// The luma column at which chroma sample 0 of subsampled video is sited as VideoReader reads it (sample k lies
/// hsub·k further: 4 for 4:1:1, 2 for 4:2:x): centred chroma locations (center, top, bottom) (hsub − 1) / 2,
/// co-sited ones (left, topleft, bottomleft, unspecified) 0. VideoReader gives each 4:2:2 sample (luma column 2k)
/// the linear interpolation between the two samples about it.
double chroma_column_site(const VideoInfo& info);

/// Outcome of VideoReader::load_frame.
enum class FrameStatus {
    kOk,       ///< the frame is current
    kPastEnd,  ///< the stream ends before it
    kDamaged,  ///< it is missing from the stream, does not decode, or decodes with errors
};

/// Reads a video file frame by frame and splits frames into UYVY fields. Not thread-safe; one per thread.
class VideoReader {
public:
    /// Opens `path` and decodes its first frame. Throws RigError "<path>: <key>: <why>" when the file is no
    /// video, has no decodable frame at its start, or its frames are not 720×576 in a supported pixel format.
    explicit VideoReader(const std::string& path);
    ~VideoReader();
    VideoReader(VideoReader&&) noexcept;
    VideoReader& operator=(VideoReader&&) noexcept;

    /// The stream as opened.
    const VideoInfo& info() const;
    /// Makes frame `n` (0-based, in display order) the current frame: decodes on from the current one, or seeks
    /// (and, if the seek misses, decodes again from the start). When the frame cannot be had, `why` says why and
    /// the current frame is unchanged. Never throws for a damaged stream.
    FrameStatus load_frame(int64_t n, std::string& why);
    /// Index of the current frame (−1 when none).
    int64_t current_frame() const;
    /// Copies the field of parity `parity` (0: frame rows 0, 2, ...) of the current frame into `uyvy_out`
    /// (720×288 UYVY), re-siting the chroma as the file comment says. `interlaced`: the frame's chroma rows
    /// alternate between the fields (false: progressive 4:2:0 chroma). Needs a current frame.
    void extract_field(int parity, bool interlaced, uint8_t* uyvy_out) const;
    /// Frames the decoder has output so far (open included): what reading has cost.
    int64_t decoded_frames() const;

private:
    struct Impl;
    std::unique_ptr<Impl> impl_;
};

/// A codec and container as cameras and recorders write PAL video.
enum class VideoCodec {
    kFfv1,   ///< FFV1 level 3, 4:2:2 8-bit, lossless, Matroska (.mkv)
    kDv,     ///< DV 25 Mbit/s PAL (IEC 61834), 4:2:0 line-alternate chroma, AVI (.avi)
    kDv411,  ///< DVCPRO25 PAL, 4:1:1, AVI (.avi)
    kMpeg2,  ///< MPEG-2 MP@ML 4:2:0 interlaced, ≤ 15 Mbit/s at quantiser scale 2, GOP 12 (IBBP), program stream (.mpg)
    kH264,   ///< H.264 High 4:2:0 interlaced (libx264 MBAFF, CRF 8, GOP 25), MP4 (.mp4)
    kMpeg2_422,  ///< MPEG-2 4:2:2 Profile interlaced, intra only, ≤ 50 Mbit/s at quantiser scale 1: the D-10 / IMX
                 ///< studio recorders' coding, in a program stream (.mpg)
};

/// The codec named "ffv1", "dv", "dv411", "mpeg2", "mpeg2-422" or "h264" ("video": ffv1). Returns false for
/// anything else.
bool parse_video_codec(const std::string& name, VideoCodec& out);
/// The name parse_video_codec takes.
const char* to_string(VideoCodec codec);
/// File extension, with the dot: ".mkv", ".avi", ".mpg", ".mp4".
const char* extension(VideoCodec codec);
/// Whether this FFmpeg build has the encoder (libx264 is optional in FFmpeg builds).
bool encoder_available(VideoCodec codec);

/// Chroma subsampling of a written file: the codec's own, or for FFV1 (lossless) also that of a 4:2:0 or 4:1:1
/// camera, sited as MPEG-2 / DV25 site it (an exact record of such a stream's planes).
enum class VideoChroma { kCodec, k420, k411 };

/// A `synth --format` video name: a codec (parse_video_codec), or "ffv1-420" / "ffv1-411" (FFV1 holding the
/// chroma planes of a 4:2:0 / 4:1:1 camera: what subsampling alone costs, without a lossy codec). False otherwise.
bool parse_video_format(const std::string& name, VideoCodec& codec, VideoChroma& chroma);

/// Writes woven interlaced PAL frames (720×576, 25 frames/s) from field pairs.
class VideoWriter {
public:
    /// Creates `path` for `codec`; `order` kTopFirst or kBottomFirst; `chroma` other than kCodec only with kFfv1;
    /// `options`: FFmpeg encoder options over the codec's settings, "key=value" pairs separated by ':' (e.g.
    /// "crf=6" for H.264). Throws RigError when the encoder is missing (naming it), an option is unknown to it,
    /// or the file cannot be written.
    VideoWriter(const std::string& path, VideoCodec codec, FieldOrder order = FieldOrder::kTopFirst,
                VideoChroma chroma = VideoChroma::kCodec, const std::string& options = {});
    ~VideoWriter();
    VideoWriter(VideoWriter&&) noexcept;
    VideoWriter& operator=(VideoWriter&&) noexcept;

    /// Encodes one frame from its two fields in temporal order (720×288 UYVY each): with kTopFirst `first` is
    /// the top field (frame rows 0, 2, ...). Throws RigError on an encoder or write failure.
    void write(const uint8_t* first_uyvy, const uint8_t* second_uyvy);
    /// Flushes the encoder and writes the container trailer. Throws RigError on failure. Idempotent.
    void close();
    /// Frames written so far.
    int64_t frames() const;

private:
    struct Impl;
    std::unique_ptr<Impl> impl_;
};

}  // namespace eyesim::rig
