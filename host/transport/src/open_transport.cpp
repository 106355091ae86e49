// URI dispatch: tcp://HOST:PORT or usb[://VID:PID].
#include "eyesim/transport/tcp.hpp"
#include "eyesim/transport/transport.hpp"
#include "eyesim/transport/usb.hpp"

namespace eyesim::transport {

std::unique_ptr<Transport> open_transport(const std::string& uri, int timeout_ms) {
    if (uri.rfind("tcp://", 0) == 0) {
        std::string host;
        std::uint16_t port = 0;
        parse_tcp_uri(uri, host, port);
        return connect_tcp(host, port, timeout_ms);
    }
    if (uri == "usb" || uri.rfind("usb://", 0) == 0) {
        UsbOptions options;
        options.ids = parse_usb_uri(uri);
        return connect_usb(options);
    }
    throw TransportError(uri + ": unknown transport (expected tcp://HOST:PORT, usb or usb://VID:PID)");
}

}  // namespace eyesim::transport
