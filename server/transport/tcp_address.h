#pragma once
/// @file tcp_address.h
/// Addresses of the transport's own TCP listeners (the HTTP listener, the gRPC front door):
/// "host:port" parsing and the client-address form shared with gRPC's peer().

#include <string>

#include <boost/asio/ip/tcp.hpp>

#include "core/base/status.h"

namespace meshdeform::transport {

/// Parses "host:port" or "[v6]:port" with a numeric host ("localhost" is 127.0.0.1).
/// @return the endpoint; InvalidArgument naming what is wrong.
Result<boost::asio::ip::tcp::endpoint> parse_endpoint(const std::string& address);

/// A remote address in gRPC's peer() form without the port ("ipv4:1.2.3.4", "ipv6:[::1]"), so
/// that per-client policies can key HTTP and gRPC clients alike; IPv4-mapped IPv6 addresses are
/// reported as IPv4 (as gRPC does).
std::string client_address(const boost::asio::ip::tcp::endpoint& remote);

}  // namespace meshdeform::transport
