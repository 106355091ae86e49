#pragma once
/// \file
/// Host-side byte transport to the device: the one interface the tracking code reads packets through, whatever
/// carries them (TCP loopback to `eyesim-device`, USB bulk endpoints via libusb, an in-process pipe in tests).
/// The transport moves bytes; packet boundaries are found by the protocol's stream parser.

#include <cstddef>
#include <cstdint>
#include <memory>
#include <span>
#include <stdexcept>
#include <string>

namespace eyesim::transport {

/// Outcome of one read or write.
enum class IoStatus : std::uint8_t {
    ok,        ///< `bytes` were moved (may be fewer than asked)
    timeout,   ///< nothing moved before the timeout; the link is still up
    closed,    ///< the peer closed the link (TCP EOF, in-process peer gone); nothing more will arrive
    error      ///< the link failed (see Transport::last_error()); USB retries by reconnecting
};

/// Result of Transport::read / Transport::write.
struct IoResult {
    std::size_t bytes = 0;            ///< bytes moved
    IoStatus status = IoStatus::ok;   ///< why the call returned
};

/// Thrown by the connect functions when a link cannot be opened; what() is one line naming the address.
class TransportError : public std::runtime_error {
public:
    using std::runtime_error::runtime_error;
};

/// Thrown for a malformed or unsupported device URI (a usage error: nothing was tried); a link that was tried and
/// failed (connection refused, no USB device) is a plain TransportError.
class UriError : public TransportError {
public:
    using TransportError::TransportError;
};

/// A bidirectional byte stream to one device.
class Transport {
public:
    virtual ~Transport() = default;
    /// Reads up to `out.size()` bytes, waiting at most `timeout_ms` (0 = poll) for the first byte.
    virtual IoResult read(std::span<std::uint8_t> out, int timeout_ms) = 0;
    /// Writes all of `data` (one command packet), waiting at most `timeout_ms`; returns the bytes written.
    virtual IoResult write(std::span<const std::uint8_t> data, int timeout_ms) = 0;
    /// True while the link is up.
    virtual bool connected() const = 0;
    /// Closes the link (idempotent); the peer sees `closed`.
    virtual void close() = 0;
    /// Human-readable address, e.g. `tcp://127.0.0.1:5100` or `usb://1209:0001`.
    virtual std::string describe() const = 0;
    /// Last error, one line without the address (empty when none). After `closed` it says how the link ended
    /// when that was not an orderly close ("connection reset by peer").
    virtual std::string last_error() const = 0;
    /// True for a link that comes back by itself after an `error` (USB: reconnect after an unplug): the caller
    /// keeps reading, and the device's stream starts again (commands sent before are lost with it).
    virtual bool reconnects() const { return false; }
};

/// Opens a transport from a URI: `tcp://HOST:PORT`, `usb` (default ids) or `usb://VID:PID` (hex).
/// Throws UriError for a malformed URI, TransportError with a one-line reason otherwise (connection refused, no
/// USB device present).
std::unique_ptr<Transport> open_transport(const std::string& uri, int timeout_ms = 2000);

/// Checks a URI's syntax as open_transport() reads it, without opening anything; throws UriError naming the URI.
void check_transport_uri(const std::string& uri);

}  // namespace eyesim::transport
