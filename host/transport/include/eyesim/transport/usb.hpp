#pragma once
/// \file
/// USB transport: the device's vendor-specific interface with one bulk IN and one bulk OUT endpoint, reached
/// through libusb. The libusb calls sit behind UsbBackend/BulkDevice so the framing and reconnect logic are
/// tested over a fake bulk endpoint. See docs/protocol.md, "USB transport", for the descriptors.
///
/// Framing: the byte stream of protocol packets is carried unchanged. The device ends every protocol packet
/// with a short packet (or a zero-length packet when its size is a multiple of wMaxPacketSize), so a host read
/// completes as soon as a packet is whole; the host does the same for its command packets.

#include "eyesim/transport/transport.hpp"

#include <array>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

namespace eyesim::transport {

/// Vendor id: pid.codes, the open-source hardware vendor id.
inline constexpr std::uint16_t kUsbVendorId = 0x1209;
/// Product id: pid.codes' test PID (0x0001), for development units; a shipped device needs its own PID.
inline constexpr std::uint16_t kUsbProductId = 0x0001;
/// Interface number of the eyesim function.
inline constexpr std::uint8_t kUsbInterface = 0;
/// Interface class: vendor specific (no OS class driver binds to it).
inline constexpr std::uint8_t kUsbInterfaceClass = 0xFF;
/// Interface subclass: 0x45 ('E'), so tools can tell the eyesim function from other vendor interfaces.
inline constexpr std::uint8_t kUsbInterfaceSubclass = 0x45;
/// Interface protocol: 1 = eyesim wire protocol version 1.
inline constexpr std::uint8_t kUsbInterfaceProtocol = 0x01;
/// Bulk IN endpoint (device → host: markers, pedal, status, replies).
inline constexpr std::uint8_t kUsbEndpointIn = 0x81;
/// Bulk OUT endpoint (host → device: commands).
inline constexpr std::uint8_t kUsbEndpointOut = 0x01;
/// wMaxPacketSize of both bulk endpoints at high speed (USB 2.0).
inline constexpr std::uint16_t kUsbMaxPacketHighSpeed = 512;
/// wMaxPacketSize of both bulk endpoints at full speed (USB 1.1 fallback).
inline constexpr std::uint16_t kUsbMaxPacketFullSpeed = 64;
/// Size of one host IN request: a multiple of every wMaxPacketSize, so it can never overflow.
inline constexpr std::size_t kUsbInTransferBytes = 16384;

/// Which device to look for.
struct UsbIds {
    std::uint16_t vendor_id = kUsbVendorId;    ///< idVendor
    std::uint16_t product_id = kUsbProductId;  ///< idProduct
};

/// Result of a backend call, mapped from libusb's error codes.
enum class UsbStatus : std::uint8_t {
    ok,          ///< transfer completed
    timeout,     ///< nothing (or only part) moved before the timeout
    no_device,   ///< the device was unplugged
    not_found,   ///< no matching device on the bus
    access,      ///< permission denied (udev rule missing)
    busy,        ///< interface claimed by another program or driver
    overflow,    ///< device sent more than the request could hold
    pipe,        ///< endpoint halted
    io           ///< any other failure
};

/// Short name of a UsbStatus ("no_device").
const char* to_string(UsbStatus s);

/// One opened device with its interface claimed: the bulk endpoints as blocking calls with a timeout.
class BulkDevice {
public:
    virtual ~BulkDevice() = default;
    /// One bulk IN transfer of at most `len` bytes (a multiple of max_packet_in()); completes on a short packet,
    /// a zero-length packet or a full buffer. `transferred` is set even on timeout.
    virtual UsbStatus bulk_in(std::uint8_t* buf, std::size_t len, std::size_t& transferred, unsigned timeout_ms) = 0;
    /// One bulk OUT transfer of `len` bytes (0 sends a zero-length packet).
    virtual UsbStatus bulk_out(const std::uint8_t* buf, std::size_t len, std::size_t& transferred,
                               unsigned timeout_ms) = 0;
    /// wMaxPacketSize of the bulk IN endpoint.
    virtual std::uint16_t max_packet_in() const = 0;
    /// wMaxPacketSize of the bulk OUT endpoint.
    virtual std::uint16_t max_packet_out() const = 0;
};

/// Finds and opens devices; libusb in production, a fake in tests.
class UsbBackend {
public:
    virtual ~UsbBackend() = default;
    /// Opens the first device with `ids`, claims kUsbInterface and finds its bulk endpoints. On failure returns
    /// the status and a one-line reason in `why`.
    virtual UsbStatus open(const UsbIds& ids, std::unique_ptr<BulkDevice>& out, std::string& why) = 0;
    /// True when the backend reports device arrivals (libusb hotplug); otherwise reconnecting polls.
    virtual bool hotplug_supported() const = 0;
    /// Waits up to `timeout_ms` for a matching device to arrive; returns true when one did (always false
    /// without hotplug, after sleeping).
    virtual bool wait_for_arrival(int timeout_ms) = 0;
};

/// Creates the libusb backend (one libusb context, hotplug registered when the platform supports it).
/// Throws TransportError when libusb cannot be initialised.
std::unique_ptr<UsbBackend> make_libusb_backend(const UsbIds& ids = {});

/// Options of the USB transport.
struct UsbOptions {
    UsbIds ids;                        ///< device to find
    int reconnect_initial_ms = 50;     ///< first wait between reconnect attempts
    int reconnect_max_ms = 1000;       ///< backoff doubles up to this
};

/// Counters of a UsbTransport.
struct UsbStats {
    std::uint64_t in_transfers = 0;     ///< completed IN transfers (zero-length ones included)
    std::uint64_t out_transfers = 0;    ///< OUT transfers, zero-length packets included
    std::uint64_t zero_length_out = 0;  ///< zero-length packets sent to end a transfer
    std::uint64_t disconnects = 0;      ///< times the device went away
    std::uint64_t reconnects = 0;       ///< times it was opened again
    std::uint64_t open_attempts = 0;    ///< open() calls, the first included
};

/// The host's USB link: bulk IN/OUT framing as described above, reconnect with exponential backoff (woken early
/// by hotplug arrivals) after an unplug. While the device is away, read() and write() return IoStatus::error
/// with last_error() saying so, and keep trying to reconnect; no data sent during the gap is recovered.
class UsbTransport final : public Transport {
public:
    /// Takes the backend; does not open yet (see open_first()).
    UsbTransport(std::unique_ptr<UsbBackend> backend, UsbOptions options);
    ~UsbTransport() override;
    UsbTransport(const UsbTransport&) = delete;
    UsbTransport& operator=(const UsbTransport&) = delete;

    /// Opens the device once; returns false with a one-line reason (e.g. no device present).
    bool open_first(std::string& why);

    /// Bytes of the IN stream (one bulk transfer staged at a time); reconnects first when the device is away.
    IoResult read(std::span<std::uint8_t> out, int timeout_ms) override;
    /// One OUT transfer (+ zero-length packet when the length is a multiple of wMaxPacketSize).
    IoResult write(std::span<const std::uint8_t> data, int timeout_ms) override;
    /// True while the device is open.
    bool connected() const override { return device_ != nullptr; }
    /// Releases the device; later calls return `closed`.
    void close() override;
    /// `usb://VID:PID`.
    std::string describe() const override;
    /// Why the last call failed (device lost, not found, permission), one line.
    std::string last_error() const override { return error_; }
    /// Reconnects after an unplug (see the class comment).
    bool reconnects() const override { return true; }
    /// Counters so far.
    const UsbStats& stats() const { return stats_; }

private:
    bool ensure_connected(int timeout_ms);
    void lost(UsbStatus why);

    std::unique_ptr<UsbBackend> backend_;
    UsbOptions options_;
    std::unique_ptr<BulkDevice> device_;
    std::vector<std::uint8_t> staging_;  // one IN transfer, kUsbInTransferBytes
    std::size_t staged_begin_ = 0;
    std::size_t staged_end_ = 0;
    int backoff_ms_ = 0;
    long long next_attempt_ms_ = 0;  // steady-clock ms of the next reconnect attempt
    bool closed_ = false;
    std::string error_;
    std::string lost_why_;  // set by a loss, until the device is back
    UsbStats stats_;
};

/// Opens the USB device with default options through libusb; throws TransportError with a clear one-line
/// message when it is absent ("usb://1209:0001: no device found ...") or cannot be claimed.
std::unique_ptr<Transport> connect_usb(const UsbOptions& options = {});

/// One matching device seen on the bus.
struct UsbDeviceInfo {
    std::uint8_t bus = 0;          ///< bus number
    std::uint8_t address = 0;      ///< device address on the bus
    std::string speed;             ///< "full", "high", "super", ...
};

/// Lists matching devices without opening them; throws TransportError when libusb cannot be initialised.
std::vector<UsbDeviceInfo> list_usb_devices(const UsbIds& ids = {});

/// Parses `usb` or `usb://VID:PID` (hex, e.g. usb://1209:0001); throws TransportError on a malformed URI.
UsbIds parse_usb_uri(const std::string& uri);

}  // namespace eyesim::transport
