// URI dispatch: tcp://HOST:PORT or usb[://VID:PID].
#include "eyesim/transport/tcp.hpp"
#include "eyesim/transport/transport.hpp"
#include "eyesim/transport/usb.hpp"

namespace eyesim::transport {

namespace {

bool is_tcp(const std::string& uri) { return uri.rfind("tcp://", 0) == 0; }
bool is_usb(const std::string& uri) { return uri == "usb" || uri.rfind("usb://", 0) == 0; }

UsbIds usb_ids(const std::string& uri) {
    try {
        return parse_usb_uri(uri);
    } catch (const UriError&) {
        throw;
    } catch (const TransportError& e) {  // parse_usb_uri names the URI; a malformed one is a usage error
        throw UriError(e.what());
    }
}

[[noreturn]] void unknown_scheme(const std::string& uri) {
    throw UriError(uri + ": unknown transport (expected tcp://HOST:PORT, usb or usb://VID:PID)");
}

}  // namespace

void check_transport_uri(const std::string& uri) {
    if (is_tcp(uri)) {
        std::string host;
        std::uint16_t port = 0;
        parse_tcp_uri(uri, host, port);
    } else if (is_usb(uri)) {
        usb_ids(uri);
    } else {
        unknown_scheme(uri);
    }
}

std::unique_ptr<Transport> open_transport(const std::string& uri, int timeout_ms) {
    if (is_tcp(uri)) {
        std::string host;
        std::uint16_t port = 0;
        parse_tcp_uri(uri, host, port);
        return connect_tcp(host, port, timeout_ms);
    }
    if (is_usb(uri)) {
        UsbOptions options;
        options.ids = usb_ids(uri);
        return connect_usb(options);
    }
    unknown_scheme(uri);
}

}  // namespace eyesim::transport
