#pragma once
/// \file
/// Streaming model of one camera's colour-marker pipeline: classify → runs → single-pass connected components →
/// moments → completed blobs, fed one field line at a time; line buffers and fixed tables only.
///
/// Usage (no heap after construction, no exceptions, no RTTI):
/// \code
///   eyesim::fpga::RegisterMap regs;                  // reset values: four default colours
///   eyesim::fpga::Pipeline pipe(&regs);              // live map, sampled at each begin_field
///   pipe.begin_field(field_counter, parity);
///   for (int y = 0; y < 288; ++y) {
///       pipe.push_line(field + y * 1440, y);         // 720 px UYVY
///       eyesim::fpga::Blob b;
///       while (pipe.pop_blob(b)) send(b);            // blobs leave as soon as they are complete
///   }
///   pipe.end_field();                                // flushes blobs touching the last line
/// \endcode
/// Instead of draining the ring, a sink callback may be set; it is called from push_line/end_field the moment a
/// blob completes. Connectivity is 8-connected per class (pixels of different classes never join). With
/// EDGE_RING, background pixels within kRingColumns columns and one line of a blob add to its moments (not area).

#include "eyesim/fpga/blob.hpp"
#include "eyesim/fpga/field_stats.hpp"
#include "eyesim/fpga/register_map.hpp"
#include "eyesim/fpga/timing.hpp"

#include <array>
#include <cstddef>
#include <cstdint>

namespace eyesim::fpga {

/// Bytes of one 720-pixel UYVY line.
inline constexpr size_t kLineBytes = 2 * kActivePixelsPerLine;
/// Most lines a field may have (9-bit line counter).
inline constexpr int kMaxFieldLines = 512;
/// Capacity of the blob (label) table: slots for partial blobs alive at once.
inline constexpr int kMaxBlobSlots = 256;
/// Most runs on one line (alternating classes give one run per pixel).
inline constexpr int kMaxRunsPerLine = static_cast<int>(kActivePixelsPerLine);
/// Capacity of the output ring the caller drains.
inline constexpr int kOutputRingCapacity = 64;
/// Chroma LUT: 6 bits of Cb and 6 of Cr index 4096 entries of 3 bits (class 0..4).
inline constexpr int kLutChromaBits = 6;
/// Edge ring: background pixels within this many columns (and one line) of a blob count in its moments.
inline constexpr int kRingColumns = 2;
/// Background tracking (BG_TRACK): the background chroma is kept per cell of this many pixels (4 chroma pairs).
inline constexpr int kBgCellPixels = 8;
/// Cells per line.
inline constexpr int kBgCells = static_cast<int>(kActivePixelsPerLine) / kBgCellPixels;
/// A cell learns only from lines whose pixels within this many columns of it are unclassified on that line and
/// the lines above and below (so a marker's own colour and its ring never reach its background).
inline constexpr int kBgHoldColumns = kRingColumns + 1;
/// BG_OFFSET band: the chroma samples (even pixels) kBandNearColumns..kBandFarColumns columns beside each run.
inline constexpr int kBandNearColumns = kRingColumns + 1;
/// Outer edge of the BG_OFFSET band (columns beside a run).
inline constexpr int kBandFarColumns = 7;
/// Fractional bits of a cell's background chroma (12-bit values: 8.4).
inline constexpr int kBgFracBits = 4;
/// Modelled clocks from a pixel on the wire to its run being labelled (classify 3, run close 1, label 4).
inline constexpr uint32_t kPipelineDepthClocks = 8;
/// Modelled clocks between two blob emissions (serial output through one pipelined divider).
inline constexpr uint32_t kEmitIntervalClocks = 4;
/// Modelled latency of the centroid divider (53-bit ÷ 27-bit, radix-4: 27 stages + 3).
inline constexpr uint32_t kDividerLatencyClocks = 30;

/// Result of a pipeline call.
enum class PipelineStatus : uint8_t {
    kOk = 0,
    kNotInField,       ///< push_line/end_field without begin_field
    kAlreadyInField,   ///< begin_field twice without end_field
    kLineOutOfOrder,   ///< y not greater than the previous line's y
    kLineOutOfRange,   ///< y < 0 or y ≥ kMaxFieldLines
    kNullLine,         ///< null pixel pointer
};

/// Instruction set of the software model's line scan (the fast path's per-cell grey-box test and cell chroma
/// sums). A model option, not hardware: every choice gives identical output.
enum class ScanIsa : uint8_t {
    kAuto = 0,  ///< the best the CPU has (AVX-512, else AVX2, else SSE2, else portable C++)
    kScalar,    ///< portable C++
    kSse2,      ///< 16-byte vectors (x86-64 baseline)
    kAvx2,      ///< 32-byte vectors (selected at run time where the CPU has AVX2)
    kAvx512,    ///< 64-byte vectors (AVX-512 F, BW, VL), with sixteen-pixel weights
};

/// Construction-time options (hardware build parameters, not registers).
struct PipelineConfig {
    uint8_t camera = 0;                     ///< copied into every Blob
    int blob_table_capacity = kMaxBlobSlots;  ///< 1..kMaxBlobSlots usable slots (smaller = cheaper FPGA)
    bool float_reference = false;           ///< also accumulate the floating reference moments (slower)
    ScanIsa scan_isa = ScanIsa::kAuto;      ///< line scan of the software model (falls back where unsupported)
    /// process_field requests each line's bytes this many lines ahead (software prefetch; 0: off). A model option:
    /// the output is the same; docs/bench/fpga-model.md gives its effect.
    int prefetch_lines = 8;
    /// Prefetch into the first-level cache (`prefetcht0`) instead of the second (`prefetcht1`). Into L1, the
    /// 90 requests of a line compete with the line scan's own loads: on a Zen 4 host 20–35 % slower (measured).
    bool prefetch_l1 = false;
};

/// Storage the FPGA needs for this configuration, in bits. Depends on the line width and table sizes only.
struct StorageBits {
    uint64_t chroma_lut = 0;      ///< 4096 × 3-bit class LUT
    uint64_t run_buffers = 0;     ///< previous + current line run buffers
    uint64_t line_buffer = 0;     ///< previous line's pixels (16 bits each) + occupied/claimed bits of two lines
    uint64_t blob_table = 0;      ///< accumulators, bbox, merge table entries
    uint64_t output_fifo = 0;     ///< emitted-blob FIFO
    uint64_t registers = 0;       ///< register file
    uint64_t total() const { return chroma_lut + run_buffers + line_buffer + blob_table + output_fifo + registers; }
};

/// Called once per emitted blob, at the moment it completes.
using BlobSink = void (*)(void* context, const Blob& blob);

/// The streaming pipeline of one camera.
class Pipeline {
public:
    /// A pipeline with its own copy of `snapshot` (later changes to the caller's map do not reach it).
    explicit Pipeline(const RegisterMap& snapshot, const PipelineConfig& config = {});
    /// A pipeline that re-reads `*live` at every begin_field (writes take effect at the next field boundary).
    explicit Pipeline(const RegisterMap* live, const PipelineConfig& config = {});

    Pipeline(const Pipeline&) = delete;
    Pipeline& operator=(const Pipeline&) = delete;

    /// Replaces the private register snapshot (used when constructed from a snapshot); applies at begin_field.
    void set_registers(const RegisterMap& snapshot);

    /// Sets a sink called for each completed blob; nullptr delivers into the output ring instead.
    void set_sink(BlobSink sink, void* context);

    /// Starts a field: samples the register map, recompiles the LUT if it changed, clears per-field state.
    PipelineStatus begin_field(uint32_t field_counter, uint8_t parity);

    /// Feeds active line y (strictly increasing; skipped lines are treated as background) of 720 UYVY pixels.
    /// The caller may overwrite the buffer after the call: the model keeps its own copy of the previous line
    /// (the hardware's line buffer for the edge ring). Blobs completed by this line are delivered before it returns.
    PipelineStatus push_line(const uint8_t* uyvy_line, int y);

    /// Ends the field: completes every open blob (after the last pushed line) and finalises the stats.
    PipelineStatus end_field();

    /// Convenience: begin_field, push `lines` lines spaced `stride_bytes` apart, end_field.
    PipelineStatus process_field(const uint8_t* uyvy_field, int lines, uint32_t field_counter, uint8_t parity,
                                 size_t stride_bytes = kLineBytes);

    /// Takes the oldest queued blob; false when the ring is empty.
    bool pop_blob(Blob& out);

    /// Number of blobs waiting in the ring.
    int pending_blobs() const { return ring_count_; }

    /// Stats of the field in progress, or of the last field after end_field.
    const FieldStats& field_stats() const { return stats_; }

    /// Decoded registers in effect for the current field.
    const PipelineParams& params() const { return params_; }

    /// True between begin_field and end_field.
    bool in_field() const { return in_field_; }

    /// Storage in bits the hardware needs for this configuration.
    StorageBits storage_bits() const;

    /// Class (0..4) the compiled LUT gives a Cb/Cr pair (before the luma band); for tests and tools.
    uint8_t lut_class(uint8_t cb, uint8_t cr) const;

    /// Classifies one pixel exactly as the datapath does: class 0..4 after luma band and class enables.
    uint8_t classify(uint8_t y, uint8_t cb, uint8_t cr) const;

    /// Weight of a pixel of class `cls` (1..4) with luma y, as the datapath computes it. Chroma is given doubled,
    /// as the datapath keeps it: 2·Cb for an even pixel, Cb_k + Cb_k+1 (the sum of its neighbours) for an odd one.
    uint16_t weight2(uint8_t cls, int y, int cb2, int cr2) const;

    /// Weight of the same pixel against an explicit background chroma given ×128 (`bg_cb_q7`, `bg_cr_q7`; 128·128
    /// is neutral grey, which gives weight2). This is the datapath's arithmetic with BG_TRACK on; the background
    /// at pixel x is the linear interpolation of the two nearest cells' values (see docs/fpga-pipeline.md).
    uint16_t weight2_bg(uint8_t cls, int y, int cb2, int cr2, int bg_cb_q7, int bg_cr_q7) const;

    /// Background residual of a chroma sample for class `cls` (BG_OFFSET): the projection of weight2_bg, signed,
    /// without level, clamp or WEIGHT_BITS.
    int band_residual(uint8_t cls, int cb2, int cr2, int bg_cb_q7, int bg_cr_q7) const;

    /// Floating reference weight for the same pixel (no quantisation of direction, weight or width).
    double weight_reference(uint8_t cls, double y, double cb, double cr) const;

    /// Half-width of the grey chroma box the fast path treats as background (0: fast path off).
    int fast_path_half_width() const { return fast_half_width_; }

    /// Line scan in use (PipelineConfig::scan_isa resolved against the CPU; never kAuto).
    ScanIsa scan_isa() const { return scan_isa_; }

    /// Per-line scan of the software model's fast path: the 8-px cell chroma sums (Cb in the low, Cr in the high
    /// 16 bits) and one bit per cell (bit j of word j / 64) set where a chroma sample lies outside the grey box
    /// |C − 128| ≤ half_width.
    using LineScan = void (*)(const uint8_t* uyvy_line, int half_width, uint32_t* cell_sums, uint64_t* out_cells);
    /// Background step of every cell from a line's cell sums with gain 2^-shift (BG_TRACK), cells interleaved Cb, Cr.
    using BgStep = void (*)(int16_t* bg_q4, const uint32_t* cell_sums, int shift);

private:
    struct Run {
        uint16_t x0, x1;      // inclusive
        uint16_t label;       // blob-table slot (kNoLabel: dropped)
        uint8_t cls;
        uint32_t sum_w;       // Σw over the run (18 bits)
        uint32_t sum_wx;      // Σw·x (28 bits)
        uint64_t sum_wxx;     // Σw·x² (38 bits)
        uint32_t pos_n, pos_sx;  // pixels with w > 0 and their Σx
        double ref_w, ref_wx, ref_wxx;  // floating reference sums
    };
    struct OpenRun {          // the run being extracted on the current line
        uint8_t cls = 0;      // 0: none open
        int x0 = 0;
        uint32_t sw = 0, swx = 0;
        uint64_t swxx = 0;
        uint32_t pn = 0, psx = 0;
        double rw = 0, rwx = 0, rwxx = 0;
    };
    struct Slot {
        uint16_t parent;      // merge table: == own index for a root
        uint8_t cls;
        uint8_t flags;
        bool live;
        bool seen_this_line;  // got a run on the current line
        uint16_t x_min, x_max, y_min, y_max;
        uint16_t last_y;          // last line with a run
        uint16_t last_line_x_max; // rightmost pixel on last_y
        uint32_t area;
        uint64_t sw, swx, swy, swxx, swyy, swxy;
        uint32_t pn;          // pixels with w > 0 (runs and ring), their Σx
        uint64_t psx;
        int64_t band_r;       // BG_OFFSET: Σ residual and count of the beside-band samples
        uint32_t band_n;
        double rw, rwx, rwy;
    };
    static constexpr uint16_t kNoLabel = 0xFFFF;

    void init(const PipelineConfig& config);
    void compile();
    template <bool kRef>
    void classify_line(const uint8_t* line, int y);
    template <bool kRef>
    void classify_pixel(const uint8_t* line, int px, OpenRun& o, Run* runs, int& n);
    void close_run(OpenRun& o, int x_end, Run* runs, int& n);
    void run_pixel(OpenRun& o, uint8_t c, uint32_t w, int px, Run* runs, int& n);
    void classify_line_cells(const uint8_t* line);
    void classify_cells(const uint8_t* line, const uint64_t* out);
    void finish_line(const uint8_t* uyvy_line, int y, bool stable);
    void push_quiet_line(const uint8_t* uyvy_line, int y);
    void background_hold_mask(std::array<uint64_t, (kActivePixelsPerLine + 63) / 64 + 1>& near, uint64_t& any) const;
    void update_background_cells();
    void label_line(int y, bool end_of_field, const uint8_t* line);
    PipelineStatus push_line_impl(const uint8_t* uyvy_line, int y, bool stable);
    void add_ring_pixel(uint16_t root, const uint8_t* line, int x, int y);
    void add_ring_span(uint16_t root, const uint8_t* line, int xa, int xb, int y);
    void add_band_span(uint16_t root, const uint8_t* line, int xa, int xb, int y);
    int processed_spans(int y, uint16_t* x0, uint16_t* x1) const;
    void update_background(const uint8_t* line, int y);
    void background_at(int x, int& cb_q7, int& cr_q7) const;
    void background_reference_at(int x, double& cb, double& cr) const;
    uint16_t weight_at(uint8_t cls, int luma, int cb2, int cr2, int x) const;
    int background_residual_at(uint8_t cls, int cb2, int cr2, int x) const;
    uint16_t weight_from_value(uint8_t cls, int v) const;
    double weight_reference_at(uint8_t cls, double luma, double cb, double cr, int x) const;
    bool in_roi(int x, int y) const;
    uint16_t find_root(uint16_t s);
    uint16_t alloc_slot();
    void merge_into(uint16_t dst, uint16_t src);
    void emit(uint16_t slot, uint32_t decision_cycle, bool end_of_field);
    void deliver(const Blob& b);

    // Registers.
    const RegisterMap* live_ = nullptr;
    RegisterMap own_;
    uint32_t compiled_generation_ = 0xFFFFFFFFu;
    bool compiled_once_ = false;
    bool snapshot_dirty_ = true;
    PipelineParams params_{};
    PipelineConfig config_{};

    // Compiled datapath tables.
    std::array<uint8_t, 1u << (2 * kLutChromaBits)> lut_{};
    std::array<int16_t, kNumClasses + 1> dir_cb_q9_{}, dir_cr_q9_{};
    int fast_half_width_ = 0;

    // Line buffers.
    std::array<std::array<Run, kMaxRunsPerLine>, 2> runs_{};  // [cur_buf_] current line, other: previous
    std::array<int, 2> n_runs_{};
    int cur_buf_ = 0;
    // One word more than the line needs, always zero: a span's two-word window never reads past the end.
    static constexpr int kMaskWords = (kActivePixelsPerLine + 63) / 64 + 1;
    std::array<std::array<uint64_t, kMaskWords>, 2> occupied_{};  // pixels of any class, per line buffer
    std::array<std::array<uint64_t, kMaskWords>, 2> claimed_{};   // ring pixels already given to a blob
    std::array<uint8_t, kLineBytes + 4> prev_line_copy_{};        // previous line's pixels (edge ring)
    const uint8_t* prev_line_ = nullptr;                          // previous pushed line, or null
    std::array<int16_t, kNumClasses + 1> luma_min_{}, luma_max_{};
    std::array<double, kNumClasses + 1> dir_cb_ref_{}, dir_cr_ref_{};
    // Background tracking (BG_TRACK): per chroma pair, Cb and Cr ×16 interleaved, the seeded bit, and the
    // occupied mask of the line before the previous one (pixels near a blob do not update the background).
    std::array<int16_t, 2 * kBgCells + 16> bg_q4_{};  // + padding the 8-cell vector loads of the AVX2 weights read
    std::array<double, 2 * kBgCells> bg_ref_{};
    std::array<uint64_t, (kBgCells + 63) / 64> bg_seeded_{};
    bool bg_all_seeded_ = false;
    std::array<uint64_t, kMaskWords> occupied_older_{};
    int n_runs_older_ = 0;  // runs of that line (0: its occupied mask is empty and not copied)
    // Per line buffer the cells the background holds for that line's runs (kBgHoldColumns around each run; set
    // with the occupied bits), the line before the previous one's, and which claimed masks have bits to clear.
    static constexpr int kCellWords = (kBgCells + 63) / 64;
    std::array<std::array<uint64_t, kCellWords + 1>, 2> hold_cells_{};  // + a spare word (two-word windows)
    std::array<uint64_t, kCellWords + 1> hold_cells_older_{};
    std::array<bool, 2> claimed_dirty_{};
    // Fast line path (whole-field fields, fast path on, no floating reference): per line buffer the cells' chroma
    // sums from the line scan, which the background tracker learns from one line later.
    bool cells_path_ = false;
    ScanIsa scan_isa_ = ScanIsa::kScalar;
    LineScan scan_ = nullptr;
    BgStep bg_step_ = nullptr;
    std::array<std::array<uint32_t, kBgCells>, 2> cell_sums_{};
    // AVX2 chunk weights (fast line path, chroma weights, CPU with AVX2): eight pixels at a time. Per chroma LUT
    // cell the class with its luma band (class | min << 8 | max << 16); per class the Q9 direction (Cb low, Cr
    // high 16 bits) and the level.
    bool simd_weights_ = false;
    std::array<uint32_t, 1u << (2 * kLutChromaBits)> lut_band_{};
    std::array<int32_t, 8> dir_pair_{}, level_{};
    struct ChunkOut {
        alignas(64) int32_t cls[16];  // 8 (chunk_weights) or 16 (chunk_weights16) used
        alignas(64) int32_t w[16];
        bool any;  // some pixel of a class
    };
    void chunk_weights(const uint8_t* line, int x0, ChunkOut& out) const;
    void chunk_weights16(const uint8_t* line, int x0, ChunkOut& out) const;
    // Sums of a ring span's weights (add_ring_span's, the same integers).
    struct RingSums {
        uint64_t sw = 0, swx = 0, swxx = 0, psx = 0;
        uint32_t count = 0, pn = 0;
    };
    void ring_weights_simd(const uint8_t* line, uint8_t cls, int xa, uint64_t free, RingSums& r) const;
    void ring_weights_avx2(const uint8_t* line, uint8_t cls, int xa, uint64_t free, RingSums& r) const;
    static void add_offset_sums(RingSums& r, int xe, uint32_t sum_p, uint64_t swo, uint64_t swoo, uint32_t pn, uint64_t free);
    bool simd16_ = false;     // sixteen-lane ring weights and classification (AVX-512 line scan)
    void classify_span_simd(const uint8_t* line, int x0, int x1, Run* runs, int& n);

    // Blob table.
    std::array<Slot, kMaxBlobSlots> slots_{};
    std::array<uint16_t, kMaxBlobSlots> free_list_{};
    int n_free_ = 0;
    int n_live_ = 0;
    std::array<uint16_t, kMaxBlobSlots> to_free_{};
    int n_to_free_ = 0;

    // Emission.
    std::array<uint16_t, kMaxBlobSlots> done_{};
    std::array<uint32_t, kMaxBlobSlots> done_cycle_{};
    uint32_t next_emit_free_cycle_ = 0;
    BlobSink sink_ = nullptr;
    void* sink_ctx_ = nullptr;
    std::array<Blob, kOutputRingCapacity> ring_{};
    int ring_head_ = 0, ring_count_ = 0;

    // Field state.
    bool in_field_ = false;
    uint32_t field_counter_ = 0;
    uint8_t parity_ = 0;
    int last_line_ = -1;
    uint16_t next_index_ = 0;
    FieldStats stats_{};
};

}  // namespace eyesim::fpga
