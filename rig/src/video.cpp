#include "eyesim/rig/video.hpp"

#include "eyesim/rig/error.hpp"
#include "eyesim/rig/pal.hpp"
#include "eyesim/rig/recording.hpp"

#include <fmt/format.h>

extern "C" {
#include <libavcodec/avcodec.h>
#include <libavformat/avformat.h>
#include <libavutil/avutil.h>
#include <libavutil/intreadwrite.h>
#include <libavutil/opt.h>
#include <libavutil/pixdesc.h>
}

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdarg>
#include <cstdlib>
#include <cstring>
#include <mutex>

namespace eyesim::rig {

namespace {

// ---------------------------------------------------------------------------------------------------------------
// FFmpeg plumbing
// ---------------------------------------------------------------------------------------------------------------

// FFmpeg's own log lines would reach stderr beside the tools' one-line findings; the last error-level line of
// this thread is kept instead and quoted in the finding that it explains.
thread_local std::string t_last_av_error;

void av_log_sink(void* avcl, int level, const char* format, va_list vl) {
    if (level > AV_LOG_ERROR) return;
    char line[512];
    int print_prefix = 0;
    va_list copy;
    va_copy(copy, vl);
    av_log_format_line(avcl, level, format, copy, line, sizeof line, &print_prefix);
    va_end(copy);
    std::string s(line);
    while (!s.empty() && (s.back() == '\n' || s.back() == ' ')) s.pop_back();
    if (!s.empty()) t_last_av_error = s;
}

void init_ffmpeg() {
    static std::once_flag once;
    std::call_once(once, [] { av_log_set_callback(av_log_sink); });
}

std::string av_error(int err) {
    char b[AV_ERROR_MAX_STRING_SIZE] = {};
    av_strerror(err, b, sizeof b);
    return b;
}

/// The last FFmpeg error line of this thread as " (FFmpeg: ...)", then forgotten; empty when there was none.
std::string take_av_log() {
    std::string s = t_last_av_error.empty() ? std::string() : " (FFmpeg: " + t_last_av_error + ")";
    t_last_av_error.clear();
    return s;
}

// FFmpeg 6.1 moved the frame's interlacing and key flags into AVFrame::flags.
bool frame_interlaced(const AVFrame* f) {
#ifdef AV_FRAME_FLAG_INTERLACED
    return (f->flags & AV_FRAME_FLAG_INTERLACED) != 0;
#else
    return f->interlaced_frame != 0;
#endif
}

bool frame_top_first(const AVFrame* f) {
#ifdef AV_FRAME_FLAG_TOP_FIELD_FIRST
    return (f->flags & AV_FRAME_FLAG_TOP_FIELD_FIRST) != 0;
#else
    return f->top_field_first != 0;
#endif
}

bool frame_key(const AVFrame* f) {
#ifdef AV_FRAME_FLAG_KEY
    return (f->flags & AV_FRAME_FLAG_KEY) != 0;
#else
    return f->key_frame != 0;
#endif
}

void set_frame_fields(AVFrame* f, bool top_first) {
#ifdef AV_FRAME_FLAG_INTERLACED
    f->flags |= AV_FRAME_FLAG_INTERLACED;
    if (top_first) f->flags |= AV_FRAME_FLAG_TOP_FIELD_FIRST;
    else f->flags &= ~AV_FRAME_FLAG_TOP_FIELD_FIRST;
#else
    f->interlaced_frame = 1;
    f->top_field_first = top_first ? 1 : 0;
#endif
}

bool frame_corrupt(const AVFrame* f) { return f->decode_error_flags != 0 || (f->flags & AV_FRAME_FLAG_CORRUPT) != 0; }

// ---------------------------------------------------------------------------------------------------------------
// Pixel layout of decoded frames and the re-siting of their chroma to the raw fields' convention
// ---------------------------------------------------------------------------------------------------------------

enum class PixelKind { kYuv, kGray, kRgb };

struct PixelLayout {
    PixelKind kind = PixelKind::kYuv;
    const AVPixFmtDescriptor* desc = nullptr;
    int hsub = 1;            // chroma sample k covers luma pixels hsub·k ...
    int vsub = 1;            // 1 or 2
    bool full_range = false; // JPEG range: scaled to studio swing
    bool dv_line_alternate = false;  // DV 625/50 4:2:0: Cr on even, Cb on odd field lines
    AVChromaLocation loc = AVCHROMA_LOC_UNSPECIFIED;
};

/// Reads component `c` of pixel (x, y) as an integer of its own depth.
inline int sample(const AVFrame* f, const AVComponentDescriptor& c, int x, int y) {
    const uint8_t* p = f->data[c.plane] + static_cast<ptrdiff_t>(y) * f->linesize[c.plane] +
                       static_cast<ptrdiff_t>(x) * c.step + c.offset;
    const int v = c.depth > 8 ? AV_RL16(p) : *p;
    return (v >> c.shift) & ((1 << c.depth) - 1);
}

/// Whether `fmt` is a frame layout extract_field handles; fills `out`.
bool pixel_layout(AVPixelFormat fmt, AVColorRange range, AVChromaLocation loc, AVCodecID codec, PixelLayout& out) {
    const AVPixFmtDescriptor* d = av_pix_fmt_desc_get(fmt);
    if (!d) return false;
    if (d->flags & (AV_PIX_FMT_FLAG_PAL | AV_PIX_FMT_FLAG_BITSTREAM | AV_PIX_FMT_FLAG_HWACCEL |
                    AV_PIX_FMT_FLAG_BAYER | AV_PIX_FMT_FLAG_BE | AV_PIX_FMT_FLAG_FLOAT))
        return false;
    for (int i = 0; i < d->nb_components; ++i) {
        const AVComponentDescriptor& c = d->comp[i];
        // Whole bytes only: 8-bit samples in bytes, 9..16-bit samples in little-endian 16-bit words.
        if (c.depth < 8 || c.depth > 16) return false;
        if (c.depth > 8 && c.step < 2) return false;
    }
    out = PixelLayout{};
    out.desc = d;
    out.loc = loc;
    if (d->flags & AV_PIX_FMT_FLAG_RGB) {
        if (d->nb_components < 3) return false;
        out.kind = PixelKind::kRgb;
        return true;
    }
    out.kind = d->nb_components < 3 ? PixelKind::kGray : PixelKind::kYuv;
    out.hsub = 1 << d->log2_chroma_w;
    out.vsub = 1 << d->log2_chroma_h;
    if (out.hsub > 4 || out.vsub > 2) return false;
    const std::string name = d->name;
    out.full_range = range == AVCOL_RANGE_JPEG || name.rfind("yuvj", 0) == 0;
    out.dv_line_alternate = codec == AV_CODEC_ID_DVVIDEO && out.vsub == 2;
    return true;
}

std::string chroma_name(const PixelLayout& l) {
    if (l.kind == PixelKind::kRgb) return "RGB";
    if (l.kind == PixelKind::kGray) return "4:0:0";
    if (l.hsub == 1) return l.vsub == 1 ? "4:4:4" : "4:4:0";
    if (l.hsub == 2) return l.vsub == 1 ? "4:2:2" : "4:2:0";
    return l.vsub == 1 ? "4:1:1" : "4:1:0";
}

/// Sited chroma locations of FFmpeg's AVChromaLocation: horizontally centred between luma samples?
bool loc_centred_h(AVChromaLocation loc) {
    return loc == AVCHROMA_LOC_CENTER || loc == AVCHROMA_LOC_TOP || loc == AVCHROMA_LOC_BOTTOM;
}
/// Vertical position of chroma row j in luma rows, as 2j + this (progressive 4:2:0).
double loc_v_offset(AVChromaLocation loc) {
    if (loc == AVCHROMA_LOC_TOPLEFT || loc == AVCHROMA_LOC_TOP) return 0.0;
    if (loc == AVCHROMA_LOC_BOTTOMLEFT || loc == AVCHROMA_LOC_BOTTOM) return 1.0;
    return 0.5;  // left, center, unspecified: MPEG-2 / H.264 default
}

/// Field line (of field `parity`) at which chroma row 0 of component `comp` (1 Cb, 2 Cr) of interlaced 4:2:0 lies;
/// row k lies 2k lines further.
double field_chroma_phase(bool dv_line_alternate, AVChromaLocation loc, int parity, int comp) {
    if (dv_line_alternate) return comp == 2 ? 0.0 : 1.0;
    if (loc == AVCHROMA_LOC_TOPLEFT || loc == AVCHROMA_LOC_TOP) return 0.0;
    if (loc == AVCHROMA_LOC_BOTTOMLEFT || loc == AVCHROMA_LOC_BOTTOM) return 1.0;
    return parity == 0 ? 0.25 : 0.75;
}

/// Luma column at which chroma sample 0 lies for horizontal subsampling `hsub` (sample k lies hsub·k further).
double chroma_column_offset(int hsub, AVChromaLocation loc) { return loc_centred_h(loc) ? (hsub - 1) / 2.0 : 0.0; }

/// FFmpeg's chroma location named in VideoInfo::chroma_location (unspecified when it names none).
AVChromaLocation chroma_location(const VideoInfo& info) {
    const int loc = av_chroma_location_from_name(info.chroma_location.c_str());
    return loc < 0 ? AVCHROMA_LOC_UNSPECIFIED : static_cast<AVChromaLocation>(loc);
}

/// Up to three taps with weights summing to 256.
struct Taps {
    std::array<int, 3> at{0, 0, 0};
    std::array<int, 3> w{256, 0, 0};
};

/// Linear interpolation between samples at integer positions of `t` (in sample units), clamped to [0, n-1].
Taps linear_taps(double t, int n) {
    Taps k;
    const double f = std::floor(t);
    const int i0 = static_cast<int>(f);
    const int w1 = static_cast<int>(std::lround((t - f) * 256.0));
    k.at = {std::clamp(i0, 0, n - 1), std::clamp(i0 + 1, 0, n - 1), 0};
    k.w = {256 - w1, w1, 0};
    return k;
}

/// Studio-swing byte of an 8-bit (or rounded down from deeper) sample.
struct RangeLut {
    std::array<uint8_t, 256> y{}, c{};
    explicit RangeLut(bool full) {
        for (int v = 0; v < 256; ++v) {
            if (full) {
                y[v] = static_cast<uint8_t>(std::lround(16.0 + v * 219.0 / 255.0));
                c[v] = static_cast<uint8_t>(std::clamp(std::lround(128.0 + (v - 128) * 224.0 / 255.0), 16l, 240l));
            } else {
                y[v] = c[v] = static_cast<uint8_t>(v);
            }
        }
    }
};

/// Rounds a sum of samples of `depth` bits weighted by 2^`frac_bits` in all to 8 bits.
inline int to8(int64_t acc, int depth, int frac_bits) {
    const int sh = frac_bits + depth - 8;
    return static_cast<int>(std::min<int64_t>(255, (acc + (int64_t{1} << (sh - 1))) >> sh));
}

void extract_field_impl(const AVFrame* f, const PixelLayout& l, int parity, bool interlaced, uint8_t* out) {
    const AVPixFmtDescriptor* d = l.desc;
    const int W = kFieldWidth;
    if (l.kind == PixelKind::kRgb) {
        std::vector<uint8_t> bgr(static_cast<size_t>(W) * 3);
        for (int y = 0; y < kFieldHeight; ++y) {
            const int v = 2 * y + parity;
            for (int x = 0; x < W; ++x) {
                // FFmpeg describes RGB formats as components R, G, B.
                for (int ch = 0; ch < 3; ++ch) {
                    const AVComponentDescriptor& c = d->comp[2 - ch];
                    bgr[x * 3 + ch] = static_cast<uint8_t>(to8(int64_t{sample(f, c, x, v)} << 8, c.depth, 8));
                }
            }
            bgr_to_uyvy(bgr.data(), 0, W, 1, out + static_cast<size_t>(y) * W * 2, 0);
        }
        return;
    }
    const RangeLut lut(l.full_range);
    const AVComponentDescriptor& cy = d->comp[0];
    // Horizontal taps per chroma pair (output sample at luma x = 2k).
    const int cw = (W + l.hsub - 1) / l.hsub;
    std::vector<Taps> hx(W / 2);
    for (int k = 0; k < W / 2; ++k) {
        if (l.hsub == 1) {  // 4:4:4: the renderer's [1 2 1]/4 at the even pixel (left edge replicated)
            hx[k].at = {std::max(2 * k - 1, 0), 2 * k, 2 * k + 1};
            hx[k].w = {64, 128, 64};
        } else {
            hx[k] = linear_taps((2.0 * k - chroma_column_offset(l.hsub, l.loc)) / l.hsub, cw);
        }
    }
    for (int y = 0; y < kFieldHeight; ++y) {
        const int v = 2 * y + parity;
        uint8_t* o = out + static_cast<size_t>(y) * W * 2;
        for (int x = 0; x < W; ++x) o[2 * x + 1] = lut.y[to8(int64_t{sample(f, cy, x, v)} << 8, cy.depth, 8)];
        if (l.kind == PixelKind::kGray) {
            for (int k = 0; k < W / 2; ++k) o[4 * k] = o[4 * k + 2] = 128;
            continue;
        }
        for (int comp = 1; comp <= 2; ++comp) {  // 1: Cb, 2: Cr
            const AVComponentDescriptor& cc = d->comp[comp];
            Taps vt;
            if (l.vsub == 1) {
                vt.at = {v, 0, 0};
            } else if (interlaced) {
                // Field p's chroma rows are plane rows 2j + p, at field line 2j + phase.
                const double phase = field_chroma_phase(l.dv_line_alternate, l.loc, parity, comp);
                vt = linear_taps((y - phase) / 2.0, kFieldHeight / 2);
                for (int t = 0; t < 2; ++t) vt.at[t] = 2 * vt.at[t] + parity;
            } else {
                vt = linear_taps((v - loc_v_offset(l.loc)) / 2.0, kFrameHeight / 2);
            }
            const int nv = l.vsub == 1 ? 1 : 2;
            for (int k = 0; k < W / 2; ++k) {
                const Taps& h = hx[k];
                int64_t acc = 0;
                for (int a = 0; a < nv; ++a) {
                    if (vt.w[a] == 0) continue;
                    int64_t row = 0;
                    for (int b = 0; b < 3; ++b)
                        if (h.w[b]) row += int64_t{h.w[b]} * sample(f, cc, h.at[b], vt.at[a]);
                    acc += row * vt.w[a];
                }
                o[4 * k + (comp == 1 ? 0 : 2)] = lut.c[to8(acc, cc.depth, 16)];
            }
        }
    }
}

/// A RigError "<path>: <key>: <why>".
[[noreturn]] void fail(const std::string& path, const std::string& key, const std::string& why) {
    throw RigError(fmt::format("{}: {}: {}", path, key, why));
}

}  // namespace

double field_chroma_site(const VideoInfo& info, int parity, int component) {
    return field_chroma_phase(info.codec == "dvvideo" && info.chroma == "4:2:0", chroma_location(info), parity & 1,
                              component == 0 ? 1 : 2);
}

double chroma_column_site(const VideoInfo& info) {
    const int hsub = info.chroma == "4:1:1" || info.chroma == "4:1:0" ? 4 : info.chroma == "4:4:4" ? 1 : 2;
    return chroma_column_offset(hsub, chroma_location(info));
}

const char* to_string(FieldOrder order) {
    switch (order) {
        case FieldOrder::kTopFirst: return "tff";
        case FieldOrder::kBottomFirst: return "bff";
        case FieldOrder::kProgressive: return "progressive";
        case FieldOrder::kUnknown: break;
    }
    return "unknown";
}

bool parse_field_order(const std::string& text, FieldOrder& out) {
    if (text == "tff" || text == "top") out = FieldOrder::kTopFirst;
    else if (text == "bff" || text == "bottom") out = FieldOrder::kBottomFirst;
    else if (text == "progressive") out = FieldOrder::kProgressive;
    else return false;
    return true;
}

// ---------------------------------------------------------------------------------------------------------------
// VideoReader
// ---------------------------------------------------------------------------------------------------------------

namespace {
/// Packets read at open (and after a restart) before giving up on finding a first frame: random bytes that a
/// demuxer half-accepts must end in an error, not a scan of the whole file.
constexpr int kMaxPacketsToFirstFrame = 300;
/// Frames decoded forward rather than seeking.
constexpr int64_t kMaxDecodeAhead = 25;
}  // namespace

struct VideoReader::Impl {
    std::string path;
    AVFormatContext* fmt = nullptr;
    AVCodecContext* dec = nullptr;
    AVPacket* pkt = nullptr;
    AVFrame* cur = nullptr;    // the current frame
    AVFrame* ahead = nullptr;  // a frame decoded past the one asked for, kept for the next call
    AVFrame* tmp = nullptr;
    int stream = -1;
    VideoInfo info;
    PixelLayout layout;
    AVPixelFormat pix = AV_PIX_FMT_NONE;
    int64_t cur_index = -1, ahead_index = -1;
    int64_t last_out = -1;         // index of the last frame the decoder gave (timestamp-less streams: a count)
    int64_t end_index = -1;        // frames in the stream, once its end has been decoded
    int64_t failed_index = -1;     // the last frame found damaged, and why
    std::string failed_why;
    bool input_done = false, drained = false;
    int64_t ts0 = AV_NOPTS_VALUE;  // timestamp of frame 0
    double frame_ticks = 0;        // one frame in stream time-base ticks
    bool have_ts = false;
    bool after_seek = false;       // no keyframe out of the decoder since the last seek
    int64_t key_index = -1;        // the first keyframe after the last seek: earlier frames out after it are not whole
    std::string pending_error;     // the last packet the decoder refused
    int64_t decoded = 0;

    ~Impl() { close(); }
    void close() {
        av_frame_free(&cur);
        av_frame_free(&ahead);
        av_frame_free(&tmp);
        av_packet_free(&pkt);
        avcodec_free_context(&dec);
        avformat_close_input(&fmt);
    }

    /// Opens the container and the decoder (no frame decoded). First open: fills `info`. Throws RigError.
    void open_input(bool first) {
        close();
        int r = avformat_open_input(&fmt, path.c_str(), nullptr, nullptr);
        if (r < 0) fail(path, "file", "cannot be opened as video: " + av_error(r) + take_av_log());
        // Containers with a full header (Matroska, AVI, MP4, DV) describe the stream without reading packets;
        // the rest (MPEG program and transport streams) need a look at the first packets.
        auto described = [&] {
            for (unsigned i = 0; i < fmt->nb_streams; ++i) {
                const AVStream* s = fmt->streams[i];
                if (s->codecpar->codec_type == AVMEDIA_TYPE_VIDEO && s->codecpar->codec_id != AV_CODEC_ID_NONE &&
                    s->codecpar->width > 0 && (s->avg_frame_rate.num > 0 || s->r_frame_rate.num > 0) &&
                    (s->nb_frames > 0 || s->duration != AV_NOPTS_VALUE || fmt->duration != AV_NOPTS_VALUE))
                    return true;
            }
            return false;
        };
        if (!described()) {
            r = avformat_find_stream_info(fmt, nullptr);
            if (r < 0) fail(path, "file", "no stream information: " + av_error(r) + take_av_log());
        }
        const AVCodec* codec = nullptr;
        stream = av_find_best_stream(fmt, AVMEDIA_TYPE_VIDEO, -1, -1, &codec, 0);
        if (stream == AVERROR_STREAM_NOT_FOUND) fail(path, "file", "no video stream");
        if (stream < 0 || !codec) {
            const AVCodecID id = stream >= 0 ? fmt->streams[stream]->codecpar->codec_id : AV_CODEC_ID_NONE;
            fail(path, "codec", fmt::format("no decoder for '{}' in this FFmpeg", avcodec_get_name(id)));
        }
        AVStream* st = fmt->streams[stream];
        for (unsigned i = 0; i < fmt->nb_streams; ++i)
            if (static_cast<int>(i) != stream) fmt->streams[i]->discard = AVDISCARD_ALL;
        dec = avcodec_alloc_context3(codec);
        pkt = av_packet_alloc();
        cur = av_frame_alloc();
        ahead = av_frame_alloc();
        tmp = av_frame_alloc();
        if (!dec || !pkt || !cur || !ahead || !tmp) throw RigError(path + ": out of memory");
        avcodec_parameters_to_context(dec, st->codecpar);
        dec->thread_count = 1;  // one decoder per camera; the tools run several cameras side by side
        r = avcodec_open2(dec, codec, nullptr);
        if (r < 0) fail(path, "codec", fmt::format("{} decoder cannot be opened: {}", codec->name, av_error(r)));
        input_done = drained = after_seek = false;
        cur_index = ahead_index = last_out = key_index = -1;
        if (first) {
            info.codec = codec->name;
            info.width = st->codecpar->width;
            info.height = st->codecpar->height;
            const AVRational fr = st->avg_frame_rate.num > 0 ? st->avg_frame_rate : st->r_frame_rate;
            if (fr.num > 0 && fr.den > 0) info.frame_rate_hz = av_q2d(fr);
        }
    }

    /// Next frame out of the decoder into `out`: 1, 0 at the end of the stream, −1 on a read error (`why`).
    /// `max_packets` ≥ 0: give up (−1) after reading that many packets without a frame.
    int next_frame(AVFrame* out, std::string& why, int max_packets = -1) {
        for (int packets = 0;; ++packets) {
            if (max_packets >= 0 && packets > max_packets) {
                why = fmt::format("no frame in the first {} packets{}", max_packets,
                                  pending_error.empty() ? std::string() : ": " + pending_error);
                return -1;
            }
            int r = avcodec_receive_frame(dec, out);
            if (r == 0) {
                ++decoded;
                return 1;
            }
            if (r == AVERROR_EOF) {
                drained = true;
                return 0;
            }
            if (r != AVERROR(EAGAIN)) {
                why = "decoder error: " + av_error(r) + take_av_log();
                return -1;
            }
            if (input_done) {  // flushed and nothing more: the end
                drained = true;
                return 0;
            }
            r = av_read_frame(fmt, pkt);
            if (r < 0) {
                if (r != AVERROR_EOF) pending_error = "read error: " + av_error(r) + take_av_log();
                input_done = true;
                avcodec_send_packet(dec, nullptr);
                continue;
            }
            if (pkt->stream_index != stream) {
                av_packet_unref(pkt);
                continue;
            }
            r = avcodec_send_packet(dec, pkt);
            av_packet_unref(pkt);
            if (r < 0 && r != AVERROR(EAGAIN)) pending_error = "does not decode: " + av_error(r) + take_av_log();
        }
    }

    int64_t index_of(const AVFrame* f) const {
        const int64_t ts = f->best_effort_timestamp;
        if (!have_ts || ts == AV_NOPTS_VALUE) return last_out + 1;
        return std::llround(static_cast<double>(ts - ts0) / frame_ticks);
    }

    /// Decodes the first frame after open_input(): it fixes frame 0's timestamp and the pixel layout.
    void first_frame() {
        std::string why;
        const int r = next_frame(cur, why, kMaxPacketsToFirstFrame);
        if (r != 1) {
            const std::string reason = !why.empty()             ? why
                                       : !pending_error.empty() ? pending_error
                                                                : "the stream is empty";
            fail(path, "frames", "no decodable frame: " + reason);
        }
        const AVStream* st = fmt->streams[stream];
        if (cur->width != kFrameWidth || cur->height != kFrameHeight)
            fail(path, "frame size", fmt::format("{}x{}, expected 720x576", cur->width, cur->height));
        pix = static_cast<AVPixelFormat>(cur->format);
        const AVChromaLocation loc =
            cur->chroma_location != AVCHROMA_LOC_UNSPECIFIED ? cur->chroma_location : st->codecpar->chroma_location;
        if (!pixel_layout(pix, cur->color_range, loc, st->codecpar->codec_id, layout))
            fail(path, "pixel format",
                 fmt::format("{} is not supported (planar or packed YUV of 8 to 16 bits, or RGB)",
                             av_get_pix_fmt_name(pix) ? av_get_pix_fmt_name(pix) : "unknown"));
        ts0 = cur->best_effort_timestamp;
        if (info.frame_rate_hz <= 0 && dec->framerate.num > 0) info.frame_rate_hz = av_q2d(dec->framerate);
        have_ts = ts0 != AV_NOPTS_VALUE && info.frame_rate_hz > 0;
        frame_ticks = have_ts ? 1.0 / (info.frame_rate_hz * av_q2d(st->time_base)) : 0.0;
        cur_index = last_out = 0;
        info.pixel_format = av_get_pix_fmt_name(pix);
        info.chroma = chroma_name(layout);
        info.chroma_location = av_chroma_location_name(loc) ? av_chroma_location_name(loc) : "unspecified";
        // Field order: the codec's flags, else the container's (first letter: the field coded first, which is
        // how FFmpeg labels the woven top-first video it writes, "tb").
        if (frame_interlaced(cur)) {
            info.order = frame_top_first(cur) ? FieldOrder::kTopFirst : FieldOrder::kBottomFirst;
            info.order_source = "codec";
        } else {
            switch (st->codecpar->field_order) {
                case AV_FIELD_TT:
                case AV_FIELD_TB: info.order = FieldOrder::kTopFirst; break;
                case AV_FIELD_BB:
                case AV_FIELD_BT: info.order = FieldOrder::kBottomFirst; break;
                case AV_FIELD_PROGRESSIVE: info.order = FieldOrder::kProgressive; break;
                default: info.order = FieldOrder::kUnknown; break;
            }
            info.order_source = info.order == FieldOrder::kUnknown ? "none" : "container";
        }
        // Frame count from the container: a count, else the duration at the frame rate.
        int64_t n = st->nb_frames;
        if (n <= 0 && info.frame_rate_hz > 0) {
            double dur_s = -1;
            if (st->duration != AV_NOPTS_VALUE && st->duration > 0) dur_s = st->duration * av_q2d(st->time_base);
            else if (fmt->duration != AV_NOPTS_VALUE && fmt->duration > 0) dur_s = fmt->duration / double(AV_TIME_BASE);
            if (dur_s > 0) n = std::llround(dur_s * info.frame_rate_hz);
        }
        // An MPEG program or transport stream states no length. FFmpeg estimates it from the last timestamps of
        // the few hundred KB it reads at the end, and without the last frame when that frame's packet is not among
        // them (large intra frames): a stream one frame short, whose last frame would never be read. The count
        // from the largest timestamp of the stream's tail instead.
        const std::string demuxer = fmt->iformat ? fmt->iformat->name : "";
        if (st->nb_frames <= 0 && info.frame_rate_hz > 0 && (demuxer == "mpeg" || demuxer == "mpegts")) {
            const int64_t t = tail_frames(st->start_time, st->time_base);
            if (t > 0) n = t;
        }
        if (n <= 0) n = count_packets();
        info.frames = std::max<int64_t>(1, n);
    }

    /// Frames of a timestamped stream from its first timestamp to the largest one in the file's last 4 MB (more
    /// than a GOP at any MPEG-2 rate a camera records), demuxed, not decoded; 0 when it cannot tell. Packets
    /// without a timestamp after the one with the largest (a program stream's last packet may have none: sweep seed
    /// 97's MPEG-2, a P frame after the last I frame and its B frames) are frames after it in display order too.
    int64_t tail_frames(int64_t start, AVRational time_base) {
        if (start == AV_NOPTS_VALUE) return 0;
        AVFormatContext* f = nullptr;
        if (avformat_open_input(&f, path.c_str(), nullptr, nullptr) < 0) return 0;
        constexpr int64_t kTailBytes = 4 << 20;
        int64_t last = AV_NOPTS_VALUE, untimed_after = 0;
        AVPacket* p = av_packet_alloc();
        const int64_t size = f->pb ? avio_size(f->pb) : -1;
        // (A program stream's streams appear as its packets are read: the index is the first open's.)
        if (p && (size <= kTailBytes ||
             avformat_seek_file(f, -1, INT64_MIN, size - kTailBytes, size - kTailBytes, AVSEEK_FLAG_BYTE) >= 0))
            while (av_read_frame(f, p) >= 0) {
                if (p->stream_index == stream) {
                    if (p->pts == AV_NOPTS_VALUE) {
                        ++untimed_after;
                    } else if (last == AV_NOPTS_VALUE || p->pts > last) {
                        last = p->pts;
                        untimed_after = 0;
                    }
                }
                av_packet_unref(p);
            }
        av_packet_free(&p);
        avformat_close_input(&f);
        if (last == AV_NOPTS_VALUE || last < start) return 0;
        return std::llround(static_cast<double>(last - start) * av_q2d(time_base) * info.frame_rate_hz) + 1 +
               untimed_after;
    }

    /// Frame count of a container that states neither count nor duration: its packets, demuxed (not decoded).
    int64_t count_packets() {
        AVFormatContext* f = nullptr;
        if (avformat_open_input(&f, path.c_str(), nullptr, nullptr) < 0) return 0;
        int64_t n = 0;
        AVPacket* p = av_packet_alloc();
        if (avformat_find_stream_info(f, nullptr) >= 0)
            while (p && av_read_frame(f, p) >= 0) {
                n += p->stream_index == stream;
                av_packet_unref(p);
            }
        av_packet_free(&p);
        avformat_close_input(&f);
        return n;
    }

    /// Starts decoding again at the beginning of the file.
    void restart() {
        open_input(false);
        std::string why;
        if (next_frame(cur, why, kMaxPacketsToFirstFrame) != 1) fail(path, "frames", "frame 0 no longer decodes: " + why);
        cur_index = last_out = 0;
    }

    /// Seeks so that decoding resumes at or before frame n. False when the container cannot seek.
    bool seek_before(int64_t n) {
        if (!have_ts) return false;
        const int64_t ts = ts0 + static_cast<int64_t>(std::llround(n * frame_ticks));
        if (av_seek_frame(fmt, stream, ts, AVSEEK_FLAG_BACKWARD) < 0) return false;
        avcodec_flush_buffers(dec);
        input_done = drained = false;
        cur_index = ahead_index = last_out = -1;
        after_seek = true;
        return true;
    }

    /// Decodes forward until frame n. After a seek, frames count from the first keyframe out of the decoder;
    /// `overshoot` is set when that is already past n, or when nothing whole came out before the end.
    FrameStatus decode_to(int64_t n, std::string& why, bool& overshoot) {
        overshoot = false;
        for (;;) {
            if (ahead_index >= 0) {  // a frame decoded earlier, past the one then asked for
                if (ahead_index <= n) {
                    std::swap(cur, ahead);
                    cur_index = ahead_index;
                    ahead_index = -1;
                    if (cur_index == n) return FrameStatus::kOk;
                    continue;
                }
                why = pending_error.empty() ? fmt::format("missing from the stream (frame {} follows frame {})",
                                                          ahead_index, std::max<int64_t>(cur_index, -1))
                                            : pending_error;
                return FrameStatus::kDamaged;
            }
            std::string err;
            const int r = next_frame(tmp, err);
            if (r == 0) {
                if (after_seek) {
                    overshoot = true;
                    return FrameStatus::kPastEnd;
                }
                end_index = std::max(end_index, last_out + 1);
                why = fmt::format("the stream ends after {} frames (the container says {})", end_index, info.frames);
                return FrameStatus::kPastEnd;
            }
            if (r < 0) {
                why = err;
                return FrameStatus::kDamaged;
            }
            const int64_t idx = index_of(tmp);
            if (after_seek) {
                if (!frame_key(tmp)) continue;  // predicted from references decoded before the seek point
                after_seek = false;
                key_index = idx;
                if (idx > n) {
                    overshoot = true;
                    return FrameStatus::kDamaged;
                }
            } else if (idx < key_index) {
                continue;  // an open GOP's leading frames: they refer to the GOP before the keyframe
            }
            last_out = idx;
            if (tmp->width != kFrameWidth || tmp->height != kFrameHeight || tmp->format != pix) {
                if (idx == n) {
                    why = fmt::format("frame is {}x{} {}, the stream began 720x576 {}", tmp->width, tmp->height,
                                      av_get_pix_fmt_name(static_cast<AVPixelFormat>(tmp->format))
                                          ? av_get_pix_fmt_name(static_cast<AVPixelFormat>(tmp->format))
                                          : "?",
                                      info.pixel_format);
                    return FrameStatus::kDamaged;
                }
                continue;
            }
            if (idx < n) continue;
            if (idx == n && frame_corrupt(tmp)) {
                why = "decodes with errors" + (pending_error.empty() ? std::string() : ": " + pending_error) +
                      take_av_log();
                pending_error.clear();
                return FrameStatus::kDamaged;
            }
            if (idx == n) {
                std::swap(cur, tmp);
                cur_index = n;
                pending_error.clear();
                return FrameStatus::kOk;
            }
            std::swap(ahead, tmp);  // frame n never came out
            ahead_index = idx;
        }
    }

    FrameStatus load(int64_t n, std::string& why) {
        if (n < 0) {
            why = "negative frame index";
            return FrameStatus::kDamaged;
        }
        if (n == cur_index) return FrameStatus::kOk;
        if (n == failed_index) {
            why = failed_why;
            return FrameStatus::kDamaged;
        }
        if (end_index >= 0 && n >= end_index) {
            why = fmt::format("the stream ends after {} frames (the container says {})", end_index, info.frames);
            return FrameStatus::kPastEnd;
        }
        const int64_t pos = std::max(cur_index, last_out);
        const bool forward = cur_index >= 0 && n > cur_index && n - pos <= kMaxDecodeAhead;
        bool overshoot = false;
        FrameStatus s = FrameStatus::kDamaged;
        if (forward) {
            s = decode_to(n, why, overshoot);
        } else {
            // Seek to at or before the frame; where that lands after it (containers that seek to any packet, GOPs
            // that reach back), further back; in the end decode from the start.
            bool done = false;
            int64_t tried = -1;
            for (const int64_t back : {int64_t{0}, int64_t{12}, int64_t{60}, int64_t{300}}) {
                const int64_t target = std::max<int64_t>(0, n - back);
                if (target == tried) break;
                tried = target;
                if (!seek_before(target)) break;
                s = decode_to(n, why, overshoot);
                if (!overshoot) {
                    done = true;
                    break;
                }
            }
            if (!done) {
                restart();
                s = n == 0 ? FrameStatus::kOk : decode_to(n, why, overshoot);
            }
        }
        if (s == FrameStatus::kDamaged) {
            failed_index = n;
            failed_why = why;
        }
        return s;
    }
};

VideoReader::VideoReader(const std::string& path) : impl_(std::make_unique<Impl>()) {
    init_ffmpeg();
    impl_->path = path;
    impl_->open_input(true);
    impl_->first_frame();
}
VideoReader::~VideoReader() = default;
VideoReader::VideoReader(VideoReader&&) noexcept = default;
VideoReader& VideoReader::operator=(VideoReader&&) noexcept = default;

const VideoInfo& VideoReader::info() const { return impl_->info; }
FrameStatus VideoReader::load_frame(int64_t n, std::string& why) { return impl_->load(n, why); }
int64_t VideoReader::current_frame() const { return impl_->cur_index; }
int64_t VideoReader::decoded_frames() const { return impl_->decoded; }

void VideoReader::extract_field(int parity, bool interlaced, uint8_t* uyvy_out) const {
    if (impl_->cur_index < 0) throw RigError(impl_->path + ": frame: none current");
    extract_field_impl(impl_->cur, impl_->layout, parity & 1, interlaced, uyvy_out);
}

// ---------------------------------------------------------------------------------------------------------------
// VideoWriter
// ---------------------------------------------------------------------------------------------------------------

bool parse_video_codec(const std::string& name, VideoCodec& out) {
    if (name == "ffv1" || name == "video") out = VideoCodec::kFfv1;
    else if (name == "dv") out = VideoCodec::kDv;
    else if (name == "dv411") out = VideoCodec::kDv411;
    else if (name == "mpeg2") out = VideoCodec::kMpeg2;
    else if (name == "mpeg2-422") out = VideoCodec::kMpeg2_422;
    else if (name == "h264") out = VideoCodec::kH264;
    else return false;
    return true;
}

bool parse_video_format(const std::string& name, VideoCodec& codec, VideoChroma& chroma) {
    chroma = VideoChroma::kCodec;
    if (name == "ffv1-420" || name == "ffv1-411") {
        codec = VideoCodec::kFfv1;
        chroma = name == "ffv1-420" ? VideoChroma::k420 : VideoChroma::k411;
        return true;
    }
    return parse_video_codec(name, codec);
}

const char* to_string(VideoCodec codec) {
    switch (codec) {
        case VideoCodec::kFfv1: return "ffv1";
        case VideoCodec::kDv: return "dv";
        case VideoCodec::kDv411: return "dv411";
        case VideoCodec::kMpeg2: return "mpeg2";
        case VideoCodec::kMpeg2_422: return "mpeg2-422";
        case VideoCodec::kH264: return "h264";
    }
    return "?";
}

const char* extension(VideoCodec codec) {
    switch (codec) {
        case VideoCodec::kFfv1: return ".mkv";
        case VideoCodec::kDv:
        case VideoCodec::kDv411: return ".avi";
        case VideoCodec::kMpeg2:
        case VideoCodec::kMpeg2_422: return ".mpg";
        case VideoCodec::kH264: return ".mp4";
    }
    return "";
}

namespace {

const AVCodec* find_encoder(VideoCodec codec) {
    switch (codec) {
        case VideoCodec::kFfv1: return avcodec_find_encoder(AV_CODEC_ID_FFV1);
        case VideoCodec::kDv:
        case VideoCodec::kDv411: return avcodec_find_encoder(AV_CODEC_ID_DVVIDEO);
        case VideoCodec::kMpeg2:
        case VideoCodec::kMpeg2_422: return avcodec_find_encoder(AV_CODEC_ID_MPEG2VIDEO);
        case VideoCodec::kH264: return avcodec_find_encoder_by_name("libx264");
    }
    return nullptr;
}

/// Rounded weighted sum / 2^shift of field rows, clamped to the field.
inline int rows_filter(const uint8_t* field, int byte, const int* rows, const int* w, int n, int shift) {
    int acc = 0;
    for (int i = 0; i < n; ++i) {
        const int r = std::clamp(rows[i], 0, kFieldHeight - 1);
        acc += w[i] * field[static_cast<size_t>(r) * kFieldWidth * 2 + byte];
    }
    return (acc + (1 << (shift - 1))) >> shift;
}

}  // namespace

bool encoder_available(VideoCodec codec) { return find_encoder(codec) != nullptr; }

struct VideoWriter::Impl {
    std::string path;
    VideoCodec codec = VideoCodec::kFfv1;
    VideoCodec layout = VideoCodec::kFfv1;  // whose chroma planes the frame holds
    bool top_first = true;
    AVFormatContext* oc = nullptr;
    AVCodecContext* enc = nullptr;
    AVStream* st = nullptr;
    AVFrame* frame = nullptr;
    AVPacket* pkt = nullptr;
    int64_t n = 0;
    bool header = false, closed = false;

    ~Impl() { release(); }
    void release() {
        av_frame_free(&frame);
        av_packet_free(&pkt);
        avcodec_free_context(&enc);
        if (oc) {
            if (!(oc->oformat->flags & AVFMT_NOFILE)) avio_closep(&oc->pb);
            avformat_free_context(oc);
            oc = nullptr;
        }
    }
    [[noreturn]] void error(const std::string& what, int r) {
        throw RigError(fmt::format("{}: video: {}: {}{}", path, what, av_error(r), take_av_log()));
    }
    void drain() {
        for (;;) {
            int r = avcodec_receive_packet(enc, pkt);
            if (r == AVERROR(EAGAIN) || r == AVERROR_EOF) return;
            if (r < 0) error("encoder", r);
            av_packet_rescale_ts(pkt, enc->time_base, st->time_base);
            pkt->stream_index = st->index;
            r = av_interleaved_write_frame(oc, pkt);
            if (r < 0) error("write", r);
        }
    }

    /// Fills the woven frame from the top and bottom fields (UYVY).
    void weave(const uint8_t* top, const uint8_t* bottom) {
        const uint8_t* fields[2] = {top, bottom};
        const int W = kFieldWidth;
        for (int p = 0; p < 2; ++p) {
            const uint8_t* f = fields[p];
            for (int y = 0; y < kFieldHeight; ++y) {
                uint8_t* Y = frame->data[0] + static_cast<ptrdiff_t>(2 * y + p) * frame->linesize[0];
                const uint8_t* in = f + static_cast<size_t>(y) * W * 2;
                for (int x = 0; x < W; ++x) Y[x] = in[2 * x + 1];
            }
            for (int comp = 1; comp <= 2; ++comp) {
                const int byte = comp == 1 ? 0 : 2;  // Cb at byte 0, Cr at byte 2 of each pixel pair
                uint8_t* plane = frame->data[comp];
                const int ls = frame->linesize[comp];
                switch (layout) {
                    case VideoCodec::kFfv1:  // 4:2:2: the field's own chroma, row for row
                    case VideoCodec::kMpeg2_422:
                        for (int y = 0; y < kFieldHeight; ++y) {
                            uint8_t* o = plane + static_cast<ptrdiff_t>(2 * y + p) * ls;
                            const uint8_t* in = f + static_cast<size_t>(y) * W * 2;
                            for (int k = 0; k < W / 2; ++k) o[k] = in[4 * k + byte];
                        }
                        break;
                    case VideoCodec::kDv411:  // 4:1:1 co-sited with every fourth pixel: [1 2 1]/4 of the 4:2:2 samples
                        for (int y = 0; y < kFieldHeight; ++y) {
                            uint8_t* o = plane + static_cast<ptrdiff_t>(2 * y + p) * ls;
                            const uint8_t* in = f + static_cast<size_t>(y) * W * 2;
                            for (int m = 0; m < W / 4; ++m) {
                                const int a = std::max(2 * m - 1, 0), b = 2 * m, c = 2 * m + 1;
                                o[m] = static_cast<uint8_t>(
                                    (in[4 * a + byte] + 2 * in[4 * b + byte] + in[4 * c + byte] + 2) >> 2);
                            }
                        }
                        break;
                    case VideoCodec::kDv: {  // line-alternate: Cr at field line 2j, Cb at 2j + 1; [1 2 1]/4 vertically
                        const int c0 = comp == 2 ? 0 : 1;
                        const int w[3] = {1, 2, 1};
                        for (int j = 0; j < kFieldHeight / 2; ++j) {
                            uint8_t* o = plane + static_cast<ptrdiff_t>(2 * j + p) * ls;
                            const int rows[3] = {2 * j + c0 - 1, 2 * j + c0, 2 * j + c0 + 1};
                            for (int k = 0; k < W / 2; ++k) o[k] = static_cast<uint8_t>(rows_filter(f, 4 * k + byte, rows, w, 3, 2));
                        }
                        break;
                    }
                    case VideoCodec::kMpeg2:
                    case VideoCodec::kH264: {
                        // Field chroma row j at field line 2j + 1/4 (top) or 2j + 3/4 (bottom): the tent filter of
                        // a 2:1 decimation centred there, over field lines 2j − 1 .. 2j + 2.
                        const int wt[2][4] = {{3, 7, 5, 1}, {1, 5, 7, 3}};
                        for (int j = 0; j < kFieldHeight / 2; ++j) {
                            uint8_t* o = plane + static_cast<ptrdiff_t>(2 * j + p) * ls;
                            const int rows[4] = {2 * j - 1, 2 * j, 2 * j + 1, 2 * j + 2};
                            for (int k = 0; k < W / 2; ++k)
                                o[k] = static_cast<uint8_t>(rows_filter(f, 4 * k + byte, rows, wt[p], 4, 4));
                        }
                        break;
                    }
                }
            }
        }
    }
};

VideoWriter::VideoWriter(const std::string& path, VideoCodec codec, FieldOrder order, VideoChroma chroma,
                         const std::string& options)
    : impl_(std::make_unique<Impl>()) {
    init_ffmpeg();
    Impl& w = *impl_;
    w.path = path;
    w.codec = codec;
    if (order != FieldOrder::kTopFirst && order != FieldOrder::kBottomFirst)
        throw RigError(path + ": video: field order must be top or bottom first");
    w.top_first = order == FieldOrder::kTopFirst;
    if (chroma != VideoChroma::kCodec && codec != VideoCodec::kFfv1)
        throw RigError(path + ": video: only FFV1 takes another chroma subsampling than its codec's");
    w.layout = chroma == VideoChroma::k420 ? VideoCodec::kMpeg2 : chroma == VideoChroma::k411 ? VideoCodec::kDv411 : codec;
    const AVCodec* c = find_encoder(codec);
    if (!c)
        throw RigError(fmt::format("{}: video: this FFmpeg has no {} encoder", path,
                                   codec == VideoCodec::kH264 ? "libx264 (H.264)" : to_string(codec)));
    const char* muxer = codec == VideoCodec::kFfv1    ? "matroska"
                        : codec == VideoCodec::kMpeg2 || codec == VideoCodec::kMpeg2_422 ? "vob"  // MPEG-2 program stream
                        : codec == VideoCodec::kH264  ? "mp4"
                                                      : "avi";
    int r = avformat_alloc_output_context2(&w.oc, nullptr, muxer, path.c_str());
    if (r < 0 || !w.oc) w.error("container", r);
    w.enc = avcodec_alloc_context3(c);
    w.pkt = av_packet_alloc();
    w.frame = av_frame_alloc();
    if (!w.enc || !w.pkt || !w.frame) throw RigError(path + ": out of memory");
    AVCodecContext* e = w.enc;
    e->width = kFrameWidth;
    e->height = kFrameHeight;
    e->time_base = {1, 25};
    e->framerate = {25, 1};
    e->sample_aspect_ratio = {16, 15};  // 4:3 PAL
    e->pix_fmt = w.layout == VideoCodec::kFfv1 || w.layout == VideoCodec::kMpeg2_422 ? AV_PIX_FMT_YUV422P
                 : w.layout == VideoCodec::kDv411 ? AV_PIX_FMT_YUV411P
                                                  : AV_PIX_FMT_YUV420P;
    e->field_order = w.top_first ? AV_FIELD_TT : AV_FIELD_BB;
    e->color_range = AVCOL_RANGE_MPEG;
    e->colorspace = AVCOL_SPC_BT470BG;
    e->color_primaries = AVCOL_PRI_BT470BG;
    e->color_trc = AVCOL_TRC_GAMMA28;
    e->chroma_sample_location = (w.layout == VideoCodec::kDv || w.layout == VideoCodec::kDv411) ? AVCHROMA_LOC_TOPLEFT
                                                                                               : AVCHROMA_LOC_LEFT;
    e->thread_count = 1;  // reproducible files
    AVDictionary* opts = nullptr;
    switch (codec) {
        case VideoCodec::kFfv1:
            e->gop_size = 1;
            av_dict_set(&opts, "level", "3", 0);
            av_dict_set(&opts, "slicecrc", "1", 0);  // damaged slices are found, not shown
            break;
        case VideoCodec::kDv:
        case VideoCodec::kDv411: break;  // DV's rate is fixed (25 Mbit/s)
        case VideoCodec::kMpeg2:
            e->flags |= AV_CODEC_FLAG_INTERLACED_DCT | AV_CODEC_FLAG_INTERLACED_ME;
            // A 15 Mbit/s recorder never reaches its rate on the rig's mostly dark pictures: its quantiser sits at
            // the floor on every picture, which is what a fixed quantiser scale of 2 writes.
            e->bit_rate = 15'000'000;  // MP@ML's ceiling
            e->rc_max_rate = 15'000'000;
            e->rc_buffer_size = 1'835'008;  // MP@ML VBV
            e->qmin = e->qmax = 2;
            e->intra_dc_precision = 2;  // 10-bit intra DC, as broadcast encoders write
            e->gop_size = 12;
            e->max_b_frames = 2;
            av_dict_set(&opts, "intra_vlc", "1", 0);
            break;
        case VideoCodec::kMpeg2_422:
            // D-10 / IMX: 4:2:2 Profile @ Main Level, every picture intra, 50 Mbit/s. At the non-linear
            // quantiser's finest scale (1) the rig's pictures take about 32 Mbit/s per camera, under the rate, so
            // a 50 Mbit/s recorder codes them at its floor: the scale is held there.
            e->profile = 0;  // 4:2:2 Profile
            e->level = 5;    // Main Level
            e->flags |= AV_CODEC_FLAG_INTERLACED_DCT;
            e->bit_rate = 50'000'000;
            e->rc_max_rate = 50'000'000;
            e->rc_buffer_size = 9'437'184;  // 422P@ML VBV
            e->qmin = e->qmax = 1;
            e->intra_dc_precision = 2;
            e->gop_size = 1;
            e->max_b_frames = 0;
            av_dict_set(&opts, "intra_vlc", "1", 0);
            av_dict_set(&opts, "non_linear_quant", "1", 0);
            break;
        case VideoCodec::kH264:
            e->flags |= AV_CODEC_FLAG_INTERLACED_DCT;  // x264 --interlaced (field order per frame)
            e->gop_size = 25;
            av_dict_set(&opts, "crf", "8", 0);  // about DV's 25 Mbit/s on the rig's pictures
            av_dict_set(&opts, "preset", "medium", 0);
            av_dict_set(&opts, "profile", "high", 0);
            break;
    }
    if (!options.empty() && av_dict_parse_string(&opts, options.c_str(), "=", ":", 0) < 0) {
        av_dict_free(&opts);
        throw RigError(fmt::format("{}: video: encoder options '{}': not key=value pairs separated by ':'", path, options));
    }
    // FFmpeg's MPEG-2 encoder calls a null comparison function for most interlaced-DCT metrics (a segmentation
    // fault in the first frame): only the ones it implements for that block shape are let through.
    if (const AVDictionaryEntry* il = av_dict_get(opts, "ildctcmp", nullptr, 0)) {
        const std::string v = il->value;
        if (v != "vsad" && v != "vsse" && v != "satd" && v != "zero") {
            av_dict_free(&opts);
            throw RigError(fmt::format("{}: video: encoder option ildctcmp={}: the MPEG-2 encoder crashes on it; "
                                       "use vsad (its default), vsse, satd or zero",
                                       path, v));
        }
    }
    if (w.oc->oformat->flags & AVFMT_GLOBALHEADER) e->flags |= AV_CODEC_FLAG_GLOBAL_HEADER;
    r = avcodec_open2(e, c, &opts);
    const AVDictionaryEntry* unused = av_dict_get(opts, "", nullptr, AV_DICT_IGNORE_SUFFIX);
    const std::string unknown = unused ? unused->key : "";
    av_dict_free(&opts);
    if (r < 0) w.error(fmt::format("{} encoder cannot be opened", c->name), r);
    if (!unknown.empty()) throw RigError(fmt::format("{}: video: encoder option '{}': {} has no such option", path, unknown, c->name));
    w.st = avformat_new_stream(w.oc, nullptr);
    if (!w.st) throw RigError(path + ": out of memory");
    avcodec_parameters_from_context(w.st->codecpar, e);
    w.st->time_base = e->time_base;
    w.st->avg_frame_rate = e->framerate;
    if (!(w.oc->oformat->flags & AVFMT_NOFILE)) {
        r = avio_open(&w.oc->pb, path.c_str(), AVIO_FLAG_WRITE);
        if (r < 0) throw RigError(fmt::format("{}: file: cannot be created: {}", path, av_error(r)));
    }
    r = avformat_write_header(w.oc, nullptr);
    if (r < 0) w.error("container header", r);
    w.header = true;
    w.frame->format = e->pix_fmt;
    w.frame->width = e->width;
    w.frame->height = e->height;
    r = av_frame_get_buffer(w.frame, 0);
    if (r < 0) w.error("frame buffer", r);
}

VideoWriter::~VideoWriter() = default;
VideoWriter::VideoWriter(VideoWriter&&) noexcept = default;
VideoWriter& VideoWriter::operator=(VideoWriter&&) noexcept = default;

void VideoWriter::write(const uint8_t* first_uyvy, const uint8_t* second_uyvy) {
    Impl& w = *impl_;
    if (w.closed) throw RigError(w.path + ": video: write after close");
    int r = av_frame_make_writable(w.frame);
    if (r < 0) w.error("frame buffer", r);
    if (w.top_first) w.weave(first_uyvy, second_uyvy);
    else w.weave(second_uyvy, first_uyvy);
    set_frame_fields(w.frame, w.top_first);
    w.frame->pts = w.n++;
    r = avcodec_send_frame(w.enc, w.frame);
    if (r < 0) w.error("encoder", r);
    w.drain();
}

void VideoWriter::close() {
    Impl& w = *impl_;
    if (w.closed) return;
    w.closed = true;
    int r = avcodec_send_frame(w.enc, nullptr);
    if (r < 0 && r != AVERROR_EOF) w.error("encoder flush", r);
    w.drain();
    r = av_write_trailer(w.oc);
    if (r < 0) w.error("container trailer", r);
    w.release();
}

int64_t VideoWriter::frames() const { return impl_->n; }

}  // namespace eyesim::rig
