#pragma once
/// \file
/// The firmware core: three fpga-model pipelines, the packetiser, command handling and the bounded transmit
/// queue, behind the HAL (hal.hpp). Embedded rules: construct once at start-up (static storage or one start-up
/// allocation); afterwards no heap, no exceptions, no RTTI, every call bounded and non-blocking.
///
/// A board (or eyesim-device) runs it as
/// \code
///   DeviceCore core(hal, config);                 // at start-up
///   for (;;) {
///       core.step_cameras();                      // one line (or field end) from each camera
///       core.service();                           // commands in, pedal, status, bytes out
///   }
/// \endcode

#include "eyesim/firmware/capacity.hpp"
#include "eyesim/firmware/fixed_vector.hpp"
#include "eyesim/firmware/hal.hpp"
#include "eyesim/firmware/latency.hpp"
#include "eyesim/firmware/packet_queue.hpp"

#include "eyesim/fpga/patch_capture.hpp"
#include "eyesim/fpga/pipeline.hpp"
#include "eyesim/fpga/register_map.hpp"
#include "eyesim/fpga/wire.hpp"
#include "eyesim/protocol/messages.hpp"
#include "eyesim/protocol/stream_parser.hpp"

#include <array>
#include <cstddef>
#include <cstdint>

namespace eyesim::firmware {

/// Start-up settings (the host can change the run-time ones by command).
struct CoreConfig {
    bool low_latency = false;          ///< start in per-blob mode
    bool stream_on_start = false;      ///< stream without waiting for StreamStart
    std::uint32_t status_period_ms = 100;  ///< DeviceStatus period while streaming
    std::uint32_t pedal_period_ms = 20;    ///< PedalState keep-alive period (also sent on every change, see capacity.hpp)
};

/// Everything the core is connected to. Cameras, sink, source and clock are required; pedal and latency optional.
struct DeviceHal {
    std::array<CameraSource*, kCameras> cameras{};  ///< one field source per camera
    ByteSink* sink = nullptr;                       ///< towards the host
    ByteSource* source = nullptr;                   ///< from the host
    Clock* clock = nullptr;                         ///< device time
    const PedalInput* pedal = nullptr;              ///< foot pedal, or nullptr (no PedalState then)
    LatencyObserver* latency = nullptr;             ///< per-blob latency records, or nullptr
};

/// What step_cameras() found.
enum class StepStatus : std::uint8_t {
    active,    ///< at least one camera delivered a line or a field end
    idle,      ///< no camera had anything (real-time sources between lines)
    finished   ///< every camera reached the end of its stream
};

/// Counters beyond DeviceStatus, for tests, tools and benchmarks.
struct CoreCounters {
    std::uint64_t commands = 0;        ///< commands executed
    std::uint64_t nacks = 0;           ///< of which refused
    std::uint64_t frames_queued = 0;   ///< frames put into the transmit queue
    std::uint64_t frames_written = 0;  ///< frames whose last byte the sink took
    std::uint64_t blobs_sent = 0;      ///< blobs put into queued frames
    std::uint64_t patches_sent = 0;    ///< precision mode: patches whose BlobPatch fragments were all queued
    std::uint64_t patch_frames = 0;    ///< BlobPatch frames queued
    std::uint64_t patch_bytes = 0;     ///< bytes of those frames
    std::uint64_t patches_dropped = 0; ///< patches captured but not sent: over the field's budget, or no room in
                                       ///< the transmit queue beside the markers
    std::uint64_t patches_too_large = 0;  ///< blobs of an enabled class too large for a patch (no patch)
};

/// The device firmware core.
class DeviceCore {
public:
    /// Sets up the pipelines (register reset values), the queue and the parser. `hal` pointers must outlive it.
    DeviceCore(const DeviceHal& hal, const CoreConfig& config = {}) noexcept;
    DeviceCore(const DeviceCore&) = delete;
    DeviceCore& operator=(const DeviceCore&) = delete;

    /// Runs up to one item (line or field end) per camera through that camera's pipeline, in device-time order
    /// across the cameras: each camera's next item waits until no other camera has an earlier one, as on a board
    /// where unsynchronised cameras' lines arrive when they are read out. Blobs are packetised as they complete
    /// (low-latency mode) or at the field end.
    StepStatus step_cameras() noexcept;

    /// Reads and executes host commands, sends pedal and periodic status messages, writes queued bytes.
    void service() noexcept;

    /// The host went away (TCP disconnect, USB reset): stop streaming, drop queued and partial data, reset the
    /// command parser.
    void host_disconnected() noexcept;

    /// True while FieldMarkers, PedalState and DeviceStatus are being sent.
    bool streaming() const noexcept { return streaming_; }
    /// True in per-blob (low-latency) mode (applies from the next field on).
    bool low_latency() const noexcept { return low_latency_; }
    /// True when nothing is queued or half written.
    bool tx_idle() const noexcept { return queue_.empty() && tx_len_ == tx_off_; }
    /// Bytes waiting in the transmit queue.
    std::size_t tx_queued_bytes() const noexcept { return queue_.bytes(); }
    /// Current DeviceStatus values.
    protocol::DeviceStatus status() const noexcept;
    /// Transmit queue counters (drops, high-water marks).
    const PacketQueueStats& queue_stats() const noexcept { return queue_.stats(); }
    /// Other counters.
    const CoreCounters& counters() const noexcept { return counters_; }
    /// Camera c's live register map (c < kCameras); pipelines sample it at each field start.
    const fpga::RegisterMap& registers(std::size_t camera) const noexcept { return cams_[camera].regs; }
    /// Executes one command and returns its reply (also used by service(); exposed for tests).
    protocol::Reply execute(const protocol::Command& command) noexcept;

    /// The transmit queue type.
    using TxQueue = PacketQueue<kTxQueueBytes, kTxQueuePackets>;

private:
    struct PendingBlob {
        std::uint64_t last_pixel_ns;
        std::uint64_t complete_ns;
        std::uint16_t index;
    };
    struct StoredPatch {             // a captured patch; its samples are in the camera's pool at `offset`
        std::uint8_t class_id = 0, flags = 0;
        std::uint16_t blob_index = 0, origin_x = 0, origin_y = 0, width_px = 0, height_px = 0;
        std::size_t offset = 0;
        std::uint64_t ready_ns = 0;  // its last line is in
    };
    struct Camera {
        Camera() noexcept : pipeline(&regs) {}
        fpga::RegisterMap regs;
        fpga::Pipeline pipeline;
        fpga::PatchCapture capture;      // precision mode: PATCH_ENABLE classes' patches, line buffers only
        FixedVector<StoredPatch, kMaxPatchesPerField> patches;  // this field's, each sent after its marker
        std::size_t patches_next = 0;    // patches[0, patches_next) are sent
        std::array<std::uint8_t, kPatchBudgetBytesPerField> patch_pool{};
        std::size_t patch_pool_used = 0;
        std::size_t patch_wire_bytes = 0;
        bool in_field = false;
        std::uint32_t field = 0;
        std::uint8_t parity = 0;
        std::uint64_t field_start_us = 0;
        std::uint16_t part_index = 0;
        bool blobs_dropped = false;
        bool finished = false;
        bool low_latency = false;        // mode sampled at begin_field (a mode change applies from the next field)
        bool closed = false;             // low-latency: field ended, closing part not yet sent
        bool abandoned = false;          // stream stopped (or host lost) inside this field: send no more of it
        std::uint64_t close_ready_ns = 0;
        std::uint64_t field_end_us = 0;
        std::size_t sent = 0;            // low-latency: blobs of `markers` already sent
        std::uint32_t fields_processed = 0;
        FixedVector<fpga::Blob, kMaxMarkersPerField> blobs;
        FixedVector<PendingBlob, kMaxMarkersPerField> pending;
    };

    static void blob_sink(void* context, const fpga::Blob& blob);
    static void patch_sink(void* context, const fpga::Patch& patch);
    void on_patch(std::size_t camera, const fpga::Patch& patch) noexcept;
    void send_patches(std::size_t camera, std::uint64_t ready_ns, std::size_t below_index) noexcept;
    void on_blob(std::size_t camera, const fpga::Blob& blob) noexcept;
    void begin_field(std::size_t camera, const CameraLine& line) noexcept;
    void end_field(std::size_t camera) noexcept;
    void flush_low_latency() noexcept;
    void close_fields_for_stop() noexcept;
    void send_part(std::size_t camera, protocol::FieldMarkers& part, const PendingBlob* pending,
                   std::uint64_t ready_ns) noexcept;
    std::size_t queue_message(const protocol::Message& m, std::uint32_t blobs) noexcept;
    void handle_rx() noexcept;
    void send_periodic() noexcept;
    void pump_tx() noexcept;
    protocol::Reply write_register(const protocol::Command& c, protocol::Reply r) noexcept;
    protocol::Reply read_register(const protocol::Command& c, protocol::Reply r) noexcept;

    DeviceHal hal_;
    CoreConfig config_;
    std::array<Camera, kCameras> cams_;
    std::size_t sink_camera_ = 0;  // camera whose pipeline is calling blob_sink right now
    // Each camera's next item, taken from its source but not yet run (the time order across cameras).
    struct HeldItem {
        bool valid = false;
        LineStatus status = LineStatus::idle;
        CameraLine line{};
        std::uint64_t t_ns = 0;  // device time: the line's end, or just after the camera's last line
    };
    std::array<HeldItem, kCameras> held_{};
    std::array<std::uint64_t, kCameras> last_line_ns_{};
    void run_item(std::size_t camera, const HeldItem& item, std::size_t& finished) noexcept;

    bool streaming_ = false;
    bool low_latency_ = false;
    std::uint32_t status_period_ms_ = 100;
    std::uint32_t pedal_period_ms_ = 20;
    std::uint64_t last_status_us_ = 0;
    bool status_sent_once_ = false;
    std::uint64_t last_pedal_us_ = 0;
    bool pedal_sent_once_ = false;
    std::uint64_t last_pedal_sample_us_ = 0;
    bool pedal_sampled_once_ = false;
    protocol::PedalState last_pedal_{};

    TxQueue queue_;
    std::array<std::uint8_t, kMaxFrameBytes> frame_{};  // encode scratch
    std::array<protocol::FieldMarkers, kMaxPartsPerField> parts_{};  // one field's messages (per-field mode)
    protocol::BlobPatch patch_msg_{};                    // one BlobPatch fragment being encoded
    std::array<std::uint8_t, kMaxFrameBytes> tx_{};     // frame being written to the sink
    std::size_t tx_len_ = 0;
    std::size_t tx_off_ = 0;
    std::uint16_t tx_sequence_ = 0;

    protocol::StreamParser parser_;
    std::array<std::uint8_t, kRxChunkBytes> rx_{};
    std::uint32_t parse_errors_other_ = 0;  // frames of a type the device does not accept

    LinkModel link_;
    std::uint64_t core_free_ns_ = 0;  // modelled soft core busy until
    std::uint64_t bytes_sent_ = 0;
    std::uint32_t blobs_dropped_ = 0;
    std::uint32_t blob_table_overflows_ = 0;
    CoreCounters counters_{};
};

}  // namespace eyesim::firmware
