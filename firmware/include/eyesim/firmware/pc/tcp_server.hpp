#pragma once
/// \file
/// Device side of the TCP transport (PC build): a non-blocking listening socket serving one host at a time, as
/// the core's ByteSink and ByteSource. Loopback only unless the caller explicitly allows another address.

#include "eyesim/firmware/hal.hpp"

#include <cstdint>
#include <stdexcept>
#include <string>

namespace eyesim::firmware::pc {

/// Thrown when the server cannot be set up; what() is one line naming the address.
class ServerError : public std::runtime_error {
public:
    using std::runtime_error::runtime_error;
};

/// True for 127.0.0.0/8, ::1 and "localhost".
bool is_loopback_address(const std::string& address);

/// One-client TCP server.
class TcpServer final : public ByteSink, public ByteSource {
public:
    /// Listens on `address:port` (port 0 picks a free port, see port()). A non-loopback address is refused
    /// unless `allow_non_loopback`. Throws ServerError.
    TcpServer(const std::string& address, std::uint16_t port, bool allow_non_loopback);
    ~TcpServer() override;
    TcpServer(const TcpServer&) = delete;
    TcpServer& operator=(const TcpServer&) = delete;

    /// The port actually bound.
    std::uint16_t port() const noexcept { return port_; }
    /// Accepts a waiting host when none is attached; true when one was just accepted. A second host trying to
    /// connect while one is attached is accepted and closed at once.
    bool poll_accept() noexcept;
    /// Waits up to `timeout_ms` until a host connects, sends bytes or can take more bytes.
    void wait(int timeout_ms, bool want_write) noexcept;
    /// True once after the attached host went away (then the core should be told).
    bool take_disconnect() noexcept;
    /// Sets the kernel send buffer of the attached host's socket (small values show back-pressure early).
    void set_send_buffer(int bytes) noexcept { send_buffer_ = bytes; }

    /// Non-blocking send to the attached host; 0 when its socket buffer is full or no host is attached.
    std::size_t write_some(const std::uint8_t* data, std::size_t len) noexcept override;
    /// True while a host is attached.
    bool connected() const noexcept override { return client_ >= 0; }
    /// Non-blocking receive from the attached host; 0 when nothing is waiting (EOF detaches the host).
    std::size_t read_some(std::uint8_t* out, std::size_t cap) noexcept override;

private:
    void drop_client() noexcept;

    int listen_fd_ = -1;
    int client_ = -1;
    std::uint16_t port_ = 0;
    bool disconnected_ = false;
    int send_buffer_ = 0;
};

}  // namespace eyesim::firmware::pc
