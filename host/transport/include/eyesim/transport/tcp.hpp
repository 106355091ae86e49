#pragma once
/// \file
/// TCP client transport (`tcp://HOST:PORT`), the link to `eyesim-device`.

#include "eyesim/transport/transport.hpp"

#include <cstdint>
#include <memory>
#include <string>

namespace eyesim::transport {

/// Connects to `host:port` (numeric address or name), waiting at most `timeout_ms`. TCP_NODELAY is set so
/// small command packets leave at once. Throws TransportError ("tcp://127.0.0.1:5100: connection refused").
std::unique_ptr<Transport> connect_tcp(const std::string& host, std::uint16_t port, int timeout_ms = 2000);

/// Splits `tcp://HOST:PORT` (or `HOST:PORT`, port 1..65535); throws UriError naming the URI when malformed.
void parse_tcp_uri(const std::string& uri, std::string& host, std::uint16_t& port);

}  // namespace eyesim::transport
