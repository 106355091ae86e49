#pragma once
/// \file
/// Hardware-abstraction layer of the firmware core: the four things the core needs from a board. Each is a
/// small interface with non-blocking, noexcept calls, so the same core runs on a microcontroller or soft core
/// (implementations over DMA line buffers, a USB device stack and a timer) and on a PC (eyesim-device, tests).

#include <cstddef>
#include <cstdint>

namespace eyesim::firmware {

/// One active line of one camera's field as the video decoder delivers it: BT.656 4:2:2 UYVY, 2 bytes a pixel.
struct CameraLine {
    const std::uint8_t* uyvy = nullptr;  ///< width_px * 2 bytes, valid until the next next_line() call
    std::uint16_t width_px = 0;          ///< active pixels on the line (720 for PAL)
    std::uint16_t line = 0;              ///< active line index within the field, 0 = top
    std::uint32_t field = 0;             ///< field counter since the stream began
    std::uint8_t parity = 0;             ///< 0 top field, 1 bottom field
    std::uint64_t field_start_us = 0;    ///< device time of the field's start (first line of vertical blanking),
                                         ///< captured by the video input at VSYNC; pixel times follow from the
                                         ///< PAL timing model (eyesim/fpga/timing.hpp)
};

/// What CameraSource::next_line delivered.
enum class LineStatus : std::uint8_t {
    line,          ///< `out` holds the next active line of the current field
    field_end,     ///< the current field has no more active lines (vertical blanking starts)
    idle,          ///< nothing available yet (real-time sources); call again later
    end_of_stream  ///< the source has finished (recordings without --loop)
};

/// A camera's field stream, delivered line by line (no frame buffer anywhere).
class CameraSource {
public:
    virtual ~CameraSource() = default;
    /// Delivers the next line, or tells that the field ended / nothing is ready / the stream is over.
    virtual LineStatus next_line(CameraLine& out) noexcept = 0;
};

/// Transport towards the host (USB bulk IN endpoint, TCP socket, in-process pipe). Never blocks.
class ByteSink {
public:
    virtual ~ByteSink() = default;
    /// Writes up to `len` bytes and returns how many were taken (0 when the link is busy or down).
    virtual std::size_t write_some(const std::uint8_t* data, std::size_t len) noexcept = 0;
    /// True while a host is attached (bytes written while false are discarded by the core).
    virtual bool connected() const noexcept = 0;
};

/// Transport from the host (USB bulk OUT endpoint, TCP socket, in-process pipe). Never blocks.
class ByteSource {
public:
    virtual ~ByteSource() = default;
    /// Reads up to `cap` bytes into `out` and returns how many were read (0 when none are waiting).
    virtual std::size_t read_some(std::uint8_t* out, std::size_t cap) noexcept = 0;
};

/// Free-running device clock in microseconds since power-up (monotonic).
class Clock {
public:
    virtual ~Clock() = default;
    /// Current device time, µs.
    virtual std::uint64_t now_us() const noexcept = 0;
    /// The core has run a camera line that ended at device time `t_us` (lines of the cameras in time order). A
    /// board's free-running clock ignores it; a modelled clock (PC build) follows it.
    virtual void line_run_us(std::uint64_t t_us) noexcept { (void)t_us; }
};

/// One reading of the foot pedal, in PedalState's units.
struct PedalReading {
    std::uint16_t axes[3] = {0, 0, 0};  ///< 0 = released .. 65535 = full travel (axes 1, 2: the pedal's
                                        ///< joystick, 32768 = centre)
    std::uint16_t buttons = 0;          ///< bit i set = button i pressed
};

/// The foot pedal: three analogue axes (main travel, joystick x/y) and its buttons, read by the core at most
/// once per kPedalSampleUs.
class PedalInput {
public:
    virtual ~PedalInput() = default;
    /// The pedal now.
    virtual PedalReading read() const noexcept = 0;
};

}  // namespace eyesim::firmware
