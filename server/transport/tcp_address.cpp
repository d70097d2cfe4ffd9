#include "server/transport/tcp_address.h"

#include <charconv>

namespace meshdeform::transport {

namespace asio = boost::asio;
using tcp = asio::ip::tcp;

Result<tcp::endpoint> parse_endpoint(const std::string& address) {
  std::string host, port_text;
  if (!address.empty() && address.front() == '[') {
    const std::size_t close = address.find(']');
    if (close == std::string::npos || close + 1 >= address.size() || address[close + 1] != ':') {
      return Error(ErrorCode::InvalidArgument, "bad address '" + address + "' (want [v6]:port)");
    }
    host = address.substr(1, close - 1);
    port_text = address.substr(close + 2);
  } else {
    const std::size_t colon = address.rfind(':');
    if (colon == std::string::npos) {
      return Error(ErrorCode::InvalidArgument, "bad address '" + address + "' (want host:port)");
    }
    host = address.substr(0, colon);
    port_text = address.substr(colon + 1);
  }
  int port = -1;
  const auto [end, ec] = std::from_chars(port_text.data(), port_text.data() + port_text.size(), port);
  if (ec != std::errc() || end != port_text.data() + port_text.size() || port < 0 || port > 65535) {
    return Error(ErrorCode::InvalidArgument, "bad port in address '" + address + "'");
  }
  if (host == "localhost") host = "127.0.0.1";
  boost::system::error_code error;
  const asio::ip::address ip = asio::ip::make_address(host, error);
  if (error) {
    return Error(ErrorCode::InvalidArgument,
                 "bad host '" + host + "' in address '" + address + "' (want a numeric IP)");
  }
  return tcp::endpoint(ip, static_cast<unsigned short>(port));
}

std::string client_address(const tcp::endpoint& remote) {
  asio::ip::address address = remote.address();
  // A dual-stack listener sees IPv4 clients as ::ffff:a.b.c.d; gRPC reports those as IPv4 too.
  if (address.is_v6() && address.to_v6().is_v4_mapped()) {
    address = asio::ip::make_address_v4(asio::ip::v4_mapped, address.to_v6());
  }
  return address.is_v4() ? "ipv4:" + address.to_string() : "ipv6:[" + address.to_string() + "]";
}

}  // namespace meshdeform::transport
