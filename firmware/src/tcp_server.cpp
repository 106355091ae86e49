// Non-blocking one-client TCP server for eyesim-device.
#include "eyesim/firmware/pc/tcp_server.hpp"

#include <arpa/inet.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>

namespace eyesim::firmware::pc {

bool is_loopback_address(const std::string& address) {
    if (address == "localhost") return true;
    in_addr v4{};
    if (::inet_pton(AF_INET, address.c_str(), &v4) == 1) return (ntohl(v4.s_addr) >> 24) == 127;
    in6_addr v6{};
    if (::inet_pton(AF_INET6, address.c_str(), &v6) == 1) return IN6_IS_ADDR_LOOPBACK(&v6);
    return false;
}

TcpServer::TcpServer(const std::string& address, std::uint16_t port, bool allow_non_loopback) {
    const std::string where = address + ":" + std::to_string(port);
    if (!allow_non_loopback && !is_loopback_address(address))
        throw ServerError("listen address " + address +
                          " is not loopback; serving the device beyond this machine needs --bind " + address);
    const std::string host = address == "localhost" ? "127.0.0.1" : address;
    sockaddr_storage ss{};
    socklen_t len = 0;
    int family = AF_INET;
    if (in_addr v4{}; ::inet_pton(AF_INET, host.c_str(), &v4) == 1) {
        auto* sa = reinterpret_cast<sockaddr_in*>(&ss);
        sa->sin_family = AF_INET;
        sa->sin_port = htons(port);
        sa->sin_addr = v4;
        len = sizeof(sockaddr_in);
    } else if (in6_addr v6{}; ::inet_pton(AF_INET6, host.c_str(), &v6) == 1) {
        auto* sa = reinterpret_cast<sockaddr_in6*>(&ss);
        sa->sin6_family = AF_INET6;
        sa->sin6_port = htons(port);
        sa->sin6_addr = v6;
        len = sizeof(sockaddr_in6);
        family = AF_INET6;
    } else {
        throw ServerError("listen address '" + address + "' is not a numeric IPv4/IPv6 address or localhost");
    }
    listen_fd_ = ::socket(family, SOCK_STREAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0);
    if (listen_fd_ < 0) throw ServerError(where + ": socket: " + std::strerror(errno));
    const int one = 1;
    ::setsockopt(listen_fd_, SOL_SOCKET, SO_REUSEADDR, &one, sizeof one);
    if (::bind(listen_fd_, reinterpret_cast<sockaddr*>(&ss), len) != 0 || ::listen(listen_fd_, 4) != 0) {
        const std::string why = std::strerror(errno);
        ::close(listen_fd_);
        listen_fd_ = -1;
        throw ServerError(where + ": cannot listen: " + why);
    }
    sockaddr_storage bound{};
    socklen_t blen = sizeof bound;
    ::getsockname(listen_fd_, reinterpret_cast<sockaddr*>(&bound), &blen);
    port_ = family == AF_INET ? ntohs(reinterpret_cast<sockaddr_in*>(&bound)->sin_port)
                              : ntohs(reinterpret_cast<sockaddr_in6*>(&bound)->sin6_port);
}

namespace {
/// Orderly close: FIN first (everything sent stays deliverable), then read and discard what the host still sends
/// (pings) until it closes too or 500 ms pass. Closing with unread bytes would send RST, and a host that gets RST
/// loses the data still in its receive buffer.
void close_gracefully(int fd) noexcept {
    ::shutdown(fd, SHUT_WR);
    std::uint8_t sink[512];
    for (int waited_ms = 0; waited_ms < 500; waited_ms += 20) {
        pollfd p{fd, POLLIN, 0};
        if (::poll(&p, 1, 20) <= 0) continue;
        const ssize_t n = ::recv(fd, sink, sizeof sink, 0);
        if (n <= 0 && !(n < 0 && (errno == EAGAIN || errno == EINTR))) break;  // host closed (or failed)
    }
    ::close(fd);
}
}  // namespace

TcpServer::~TcpServer() {
    if (client_ >= 0) close_gracefully(client_);
    if (listen_fd_ >= 0) ::close(listen_fd_);
}

bool TcpServer::poll_accept() noexcept {
    const int fd = ::accept4(listen_fd_, nullptr, nullptr, SOCK_NONBLOCK | SOCK_CLOEXEC);
    if (fd < 0) return false;
    if (client_ >= 0) {
        ::close(fd);  // one host at a time
        return false;
    }
    const int one = 1;
    ::setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
    if (send_buffer_ > 0) ::setsockopt(fd, SOL_SOCKET, SO_SNDBUF, &send_buffer_, sizeof send_buffer_);
    client_ = fd;
    return true;
}

void TcpServer::wait(int timeout_ms, bool want_write) noexcept {
    pollfd p[2] = {{listen_fd_, POLLIN, 0}, {client_, static_cast<short>(POLLIN | (want_write ? POLLOUT : 0)), 0}};
    ::poll(p, client_ >= 0 ? 2 : 1, timeout_ms);
}

bool TcpServer::take_disconnect() noexcept {
    const bool d = disconnected_;
    disconnected_ = false;
    return d;
}

void TcpServer::drop_client() noexcept {
    if (client_ >= 0) ::close(client_);
    client_ = -1;
    disconnected_ = true;
}

std::size_t TcpServer::write_some(const std::uint8_t* data, std::size_t len) noexcept {
    if (client_ < 0) return 0;
    const ssize_t n = ::send(client_, data, len, MSG_NOSIGNAL | MSG_DONTWAIT);
    if (n > 0) return static_cast<std::size_t>(n);
    if (n < 0 && errno != EAGAIN && errno != EWOULDBLOCK && errno != EINTR) drop_client();
    return 0;
}

std::size_t TcpServer::read_some(std::uint8_t* out, std::size_t cap) noexcept {
    if (client_ < 0) return 0;
    const ssize_t n = ::recv(client_, out, cap, MSG_DONTWAIT);
    if (n > 0) return static_cast<std::size_t>(n);
    if (n == 0 || (errno != EAGAIN && errno != EWOULDBLOCK && errno != EINTR)) drop_client();
    return 0;
}

}  // namespace eyesim::firmware::pc
