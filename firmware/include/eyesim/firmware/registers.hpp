#pragma once
/// \file
/// The device's register address space as seen by host commands (Command.address), and its validation.
///
///   0x0000–0x0FFF  FPGA pipeline registers (eyesim/fpga/register_map.hpp), written to all three cameras at once;
///                  reads return camera 0's value
///   0x1000–0x1FFF  the same registers of camera 0 only; 0x2000–0x2FFF camera 1; 0x3000–0x3FFF camera 2
///   0x8000–0x80FF  firmware registers (below)
/// Every register is a 32-bit word at a 4-byte aligned address; any other address gets NackReason::BadAddress.

#include "eyesim/protocol/messages.hpp"

#include <cstdint>

namespace eyesim::firmware {

/// Address bits selecting the target (broadcast, camera 0..2, firmware).
inline constexpr std::uint32_t kRegTargetMask = 0xF000;
/// FPGA register offset bits.
inline constexpr std::uint32_t kRegOffsetMask = 0x0FFF;
/// Target value of the per-camera windows: camera c is at (c + 1) << 12.
inline constexpr std::uint32_t kRegCameraBase = 0x1000;
/// Base of the firmware registers.
inline constexpr std::uint32_t kFwRegBase = 0x8000;

/// Firmware register addresses.
namespace fwreg {
inline constexpr std::uint32_t kId = 0x8000;             ///< RO 32: 0x45594657 ("EYFW")
inline constexpr std::uint32_t kVersion = 0x8004;        ///< RO 16: firmware version 0x0100
inline constexpr std::uint32_t kStatusPeriodMs = 0x8008; ///< RW 16: DeviceStatus period, 10..10000 ms
inline constexpr std::uint32_t kPedalPeriodMs = 0x800C;  ///< RW 16: PedalState keep-alive period, 1..1000 ms
inline constexpr std::uint32_t kLowLatency = 0x8010;     ///< RW 1: 1 per-blob messages, 0 per-field (= SetLowLatency)
inline constexpr std::uint32_t kStreaming = 0x8014;      ///< RO 1: 1 while streaming
}  // namespace fwreg

/// Value of fwreg::kId.
inline constexpr std::uint32_t kFirmwareId = 0x45594657;
/// Value of fwreg::kVersion.
inline constexpr std::uint32_t kFirmwareVersion = 0x0100;

}  // namespace eyesim::firmware
