// TCP client transport over POSIX sockets (poll-based timeouts, TCP_NODELAY).
#include "eyesim/transport/tcp.hpp"

#include <arpa/inet.h>
#include <fcntl.h>
#include <netdb.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <cctype>
#include <cerrno>
#include <cstring>
#include <string>

namespace eyesim::transport {
namespace {

class TcpTransport final : public Transport {
public:
    TcpTransport(int fd, std::string address) : fd_(fd), address_(std::move(address)) {}
    ~TcpTransport() override { close(); }
    TcpTransport(const TcpTransport&) = delete;
    TcpTransport& operator=(const TcpTransport&) = delete;

    IoResult read(std::span<std::uint8_t> out, int timeout_ms) override {
        if (fd_ < 0) return {0, IoStatus::closed};
        if (out.empty()) return {0, IoStatus::ok};
        pollfd p{fd_, POLLIN, 0};
        const int r = ::poll(&p, 1, timeout_ms);
        if (r == 0) return {0, IoStatus::timeout};
        if (r < 0) return fail(errno == EINTR ? "interrupted" : std::strerror(errno));
        const ssize_t n = ::recv(fd_, out.data(), out.size(), 0);
        if (n > 0) return {static_cast<std::size_t>(n), IoStatus::ok};
        if (n == 0) {
            close();
            return {0, IoStatus::closed};
        }
        if (errno == EAGAIN || errno == EWOULDBLOCK || errno == EINTR) return {0, IoStatus::timeout};
        if (errno == ECONNRESET) {  // the peer aborted (a killed device): the bytes before it were delivered
            error_ = "connection reset by peer";
            close();
            return {0, IoStatus::closed};
        }
        return fail(std::strerror(errno));
    }

    IoResult write(std::span<const std::uint8_t> data, int timeout_ms) override {
        if (fd_ < 0) return {0, IoStatus::closed};
        std::size_t done = 0;
        while (done < data.size()) {
            pollfd p{fd_, POLLOUT, 0};
            const int r = ::poll(&p, 1, timeout_ms);
            if (r == 0) return {done, IoStatus::timeout};
            if (r < 0 && errno != EINTR) return {done, fail(std::strerror(errno)).status};
            const ssize_t n = ::send(fd_, data.data() + done, data.size() - done, MSG_NOSIGNAL);
            if (n > 0) {
                done += static_cast<std::size_t>(n);
            } else if (n < 0 && errno != EAGAIN && errno != EWOULDBLOCK && errno != EINTR) {
                if (errno == EPIPE || errno == ECONNRESET) {
                    close();
                    return {done, IoStatus::closed};
                }
                return {done, fail(std::strerror(errno)).status};
            }
        }
        return {done, IoStatus::ok};
    }

    bool connected() const override { return fd_ >= 0; }
    void close() override {
        if (fd_ >= 0) ::close(fd_);
        fd_ = -1;
    }
    std::string describe() const override { return address_; }
    std::string last_error() const override { return error_; }

private:
    IoResult fail(const char* why) {
        error_ = why;  // callers prefix the address (describe())
        return {0, IoStatus::error};
    }

    int fd_;
    std::string address_;
    std::string error_;
};

}  // namespace

void parse_tcp_uri(const std::string& uri, std::string& host, std::uint16_t& port) {
    std::string rest = uri;
    if (rest.rfind("tcp://", 0) == 0) rest = rest.substr(6);
    const auto colon = rest.rfind(':');
    if (colon == std::string::npos || colon == 0 || colon + 1 >= rest.size())
        throw UriError(uri + ": expected tcp://HOST:PORT");
    host = rest.substr(0, colon);
    if (host.size() > 2 && host.front() == '[' && host.back() == ']') host = host.substr(1, host.size() - 2);
    const std::string p = rest.substr(colon + 1);
    unsigned long v = 0;
    for (char c : p) {
        if (c < '0' || c > '9') throw UriError(uri + ": port '" + p + "' is not a number");
        v = v * 10 + static_cast<unsigned long>(c - '0');
        if (v > 65535) throw UriError(uri + ": port " + p + " is out of range 1..65535");
    }
    if (v == 0) throw UriError(uri + ": port 0 is not a valid destination");
    port = static_cast<std::uint16_t>(v);
}

std::unique_ptr<Transport> connect_tcp(const std::string& host, std::uint16_t port, int timeout_ms) {
    const std::string address = "tcp://" + host + ":" + std::to_string(port);
    addrinfo hints{};
    hints.ai_family = AF_UNSPEC;
    hints.ai_socktype = SOCK_STREAM;
    addrinfo* found = nullptr;
    const std::string service = std::to_string(port);
    if (const int rc = ::getaddrinfo(host.c_str(), service.c_str(), &hints, &found); rc != 0)
        throw TransportError(address + ": cannot resolve host: " + ::gai_strerror(rc));
    std::string why = "no address";
    for (addrinfo* ai = found; ai; ai = ai->ai_next) {
        const int fd = ::socket(ai->ai_family, ai->ai_socktype | SOCK_CLOEXEC, ai->ai_protocol);
        if (fd < 0) {
            why = std::strerror(errno);
            continue;
        }
        // Non-blocking connect so the timeout is ours, then back to blocking I/O guarded by poll().
        const int flags = ::fcntl(fd, F_GETFL, 0);
        ::fcntl(fd, F_SETFL, flags | O_NONBLOCK);
        int rc = ::connect(fd, ai->ai_addr, ai->ai_addrlen);
        if (rc < 0 && errno == EINPROGRESS) {
            pollfd p{fd, POLLOUT, 0};
            rc = ::poll(&p, 1, timeout_ms);
            if (rc == 0) {
                why = "connection timed out after " + std::to_string(timeout_ms) + " ms";
                ::close(fd);
                continue;
            }
            int err = 0;
            socklen_t len = sizeof err;
            ::getsockopt(fd, SOL_SOCKET, SO_ERROR, &err, &len);
            if (err != 0) {
                why = std::strerror(err);
                ::close(fd);
                continue;
            }
            rc = 0;
        }
        if (rc != 0) {
            why = std::strerror(errno);
            ::close(fd);
            continue;
        }
        ::fcntl(fd, F_SETFL, flags);
        const int one = 1;
        ::setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
        ::freeaddrinfo(found);
        return std::make_unique<TcpTransport>(fd, address);
    }
    ::freeaddrinfo(found);
    for (auto& c : why) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
    throw TransportError(address + ": " + why);
}

}  // namespace eyesim::transport
