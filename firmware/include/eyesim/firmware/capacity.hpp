#pragma once
/// \file
/// Every capacity of the firmware core as a named constant: the core's memory is fixed by these at build time.

#include "eyesim/protocol/messages.hpp"

#include <cstddef>
#include <cstdint>

namespace eyesim::firmware {

/// Cameras driven by one device (genlocked PAL cameras, one pipeline each).
inline constexpr std::size_t kCameras = protocol::kCameraCount;
/// Largest frame the core encodes or receives (one USB high-speed bulk packet).
inline constexpr std::size_t kMaxFrameBytes = protocol::kMaxFrameBytes;
/// Transmit queue: bytes of queued frames. 32 KiB hold ~1.6 fields of all three cameras at 10 markers each.
inline constexpr std::size_t kTxQueueBytes = 32 * 1024;
/// Transmit queue: most frames queued at once.
inline constexpr std::size_t kTxQueuePackets = 256;
/// Markers kept per camera and field in per-field mode; more are dropped and flagged (kFieldFlagBlobsDropped).
inline constexpr std::size_t kMaxMarkersPerField = 128;
/// FieldMarkers messages of one camera field at most (kMaxMarkersPerField / 14, rounded up).
inline constexpr std::size_t kMaxPartsPerField =
    (kMaxMarkersPerField + protocol::kMaxMarkersPerMessage - 1) / protocol::kMaxMarkersPerMessage;
/// Precision mode: BlobPatch bytes on the wire (frames of all fragments) per camera field at most; patches past
/// it are dropped and counted (CoreCounters::patches_dropped). 8 KiB × 3 cameras × 50 fields/s = 1.2 MB/s, 3 % of
/// USB 2.0 high-speed bulk; 12 patches of 16-px markers take 7104 bytes (docs/protocol.md section 4.7).
inline constexpr std::size_t kPatchBudgetBytesPerField = 8 * 1024;
/// Patches kept per camera field (their samples share a pool of kPatchBudgetBytesPerField bytes).
inline constexpr std::size_t kMaxPatchesPerField = 32;
/// Transmit-queue bytes a patch never takes: kept for the markers, pedal, status and replies that follow it.
inline constexpr std::size_t kTxQueueReserveBytes = 8 * 1024;
/// Transmit-queue packets a patch never takes.
inline constexpr std::size_t kTxQueueReservePackets = 64;
/// Bytes read from the host per service call (commands are 33-byte frames).
inline constexpr std::size_t kRxChunkBytes = 256;
/// Commands executed per service call at most (bounds the time one call can take).
inline constexpr std::size_t kMaxCommandsPerService = 16;
/// The pedal is sampled at most this often (1 kHz, an ADC's rate): a change is seen within 1 ms.
inline constexpr std::uint64_t kPedalSampleUs = 1000;
/// A PedalState is sent on a change of a button, or of an axis by at least this many counts (0.1 % of travel,
/// above an ADC's noise); otherwise every PEDAL_PERIOD_MS as a keep-alive.
inline constexpr std::uint16_t kPedalDeadbandCounts = 64;

}  // namespace eyesim::firmware
