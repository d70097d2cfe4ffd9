#include "server/transport/grpc_front_door.h"

#include <boost/asio/connect.hpp>
#include <boost/asio/io_context.hpp>
#include <boost/asio/ip/tcp.hpp>
#include <boost/asio/steady_timer.hpp>
#include <boost/asio/strand.hpp>
#include <boost/asio/write.hpp>

#include <array>
#include <chrono>
#include <map>
#include <mutex>
#include <set>
#include <thread>
#include <vector>

#include "server/service/log.h"
#include "server/transport/tcp_address.h"

namespace meshdeform::transport {
namespace {

namespace asio = boost::asio;
using tcp = asio::ip::tcp;
using error_code = boost::system::error_code;

class Relay;

}  // namespace

struct GrpcFrontDoor::Impl {
  asio::io_context io;
  tcp::acceptor acceptor{io};
  tcp::endpoint upstream;
  FrontDoorOptions options;
  ConnectionGate gate;
  std::thread thread;
  mutable std::mutex mutex;
  std::set<std::shared_ptr<Relay>> relays;               ///< guarded by mutex
  std::map<unsigned short, std::string> client_by_port;  ///< upstream local port -> client
  bool stopped = false;

  explicit Impl(FrontDoorOptions o) : options(o), gate(o.limits) {}
  void accept();
  void forget(const std::shared_ptr<Relay>& relay, unsigned short port);
};

namespace {

/// One admitted connection and its upstream twin; everything runs on one strand. Each direction
/// reads into its buffer and writes it on before reading again; an end of stream is passed on as
/// a half close, an error closes both sides.
class Relay : public std::enable_shared_from_this<Relay> {
 public:
  Relay(GrpcFrontDoor::Impl& door, tcp::socket client, std::string address,
        ConnectionGate::Ticket ticket)
      : door_(door),
        strand_(client.get_executor()),
        client_(std::move(client)),
        upstream_(strand_),
        first_bytes_(strand_),
        address_(std::move(address)),
        ticket_(std::move(ticket)) {}

  void start() {
    auto self = shared_from_this();
    first_bytes_.expires_after(std::chrono::seconds(door_.options.first_bytes_timeout_seconds));
    first_bytes_.async_wait([self](const error_code& error) {
      if (error || self->has_first_bytes_) return;
      self->door_.gate.note_header_timeout();
      self->close();
    });
    upstream_.async_connect(door_.upstream, [self](const error_code& error) {
      if (error) {
        service::log_event(service::LogLevel::Warn, "front_door_upstream_failed",
                           service::LogFields().add("message", error.message()));
        self->close();
        return;
      }
      if (self->closed_) return;
      error_code ignored;
      self->upstream_.set_option(tcp::no_delay(true), ignored);
      self->port_ = self->upstream_.local_endpoint(ignored).port();
      {
        const std::lock_guard lock(self->door_.mutex);
        self->door_.client_by_port[self->port_] = self->address_;
      }
      self->pump(self->client_, self->upstream_, self->to_upstream_, true);
      self->pump(self->upstream_, self->client_, self->to_client_, false);
    });
  }

  /// Closes both sides (on the strand, or from the thread stopping the door once its io thread
  /// is joined).
  void close() {
    if (closed_) return;
    closed_ = true;
    error_code ignored;
    first_bytes_.cancel();
    client_.shutdown(tcp::socket::shutdown_both, ignored);
    client_.close(ignored);
    upstream_.shutdown(tcp::socket::shutdown_both, ignored);
    upstream_.close(ignored);
    ticket_.release();
    door_.forget(shared_from_this(), port_);
  }

 private:
  void pump(tcp::socket& from, tcp::socket& to, std::array<char, 65536>& buffer,
            bool from_client) {
    auto self = shared_from_this();
    from.async_read_some(
        asio::buffer(buffer), [self, &from, &to, &buffer, from_client](const error_code& error,
                                                                       std::size_t n) {
          if (self->closed_) return;
          if (error) {
            if (error == asio::error::eof) {
              // A half close travels on; the other direction may still be talking.
              error_code ignored;
              to.shutdown(tcp::socket::shutdown_send, ignored);
              if (++self->ended_ == 2) self->close();
            } else {
              self->close();
            }
            return;
          }
          if (from_client) self->has_first_bytes_ = true;
          asio::async_write(to, asio::buffer(buffer.data(), n),
                            [self, &from, &to, &buffer, from_client](const error_code& e,
                                                                     std::size_t) {
                              if (self->closed_) return;
                              if (e) {
                                self->close();
                                return;
                              }
                              self->pump(from, to, buffer, from_client);
                            });
        });
  }

  GrpcFrontDoor::Impl& door_;
  asio::any_io_executor strand_;  ///< the accepted socket's strand
  tcp::socket client_;
  tcp::socket upstream_;
  asio::steady_timer first_bytes_;
  std::string address_;
  ConnectionGate::Ticket ticket_;
  std::array<char, 65536> to_upstream_{};
  std::array<char, 65536> to_client_{};
  unsigned short port_ = 0;
  int ended_ = 0;
  bool has_first_bytes_ = false;
  bool closed_ = false;
};

}  // namespace

void GrpcFrontDoor::Impl::accept() {
  acceptor.async_accept(asio::make_strand(io), [this](const error_code& error, tcp::socket socket) {
    if (error) {
      if (error == asio::error::operation_aborted) return;  // stopping
      // Out of descriptors (EMFILE) and the like: the kernel keeps the connection queued; try
      // again shortly instead of spinning.
      auto timer = std::make_shared<asio::steady_timer>(io, std::chrono::milliseconds(100));
      timer->async_wait([this, timer](const error_code&) { accept(); });
      return;
    }
    error_code ignored;
    const tcp::endpoint remote = socket.remote_endpoint(ignored);
    std::string address = ignored ? std::string("unknown") : client_address(remote);
    std::optional<ConnectionGate::Ticket> ticket = gate.admit(address);
    if (!ticket) {
      socket.close(ignored);  // over a cap: closed before a byte is read
    } else {
      socket.set_option(tcp::no_delay(true), ignored);
      auto relay = std::make_shared<Relay>(*this, std::move(socket), std::move(address),
                                           std::move(*ticket));
      bool started = false;
      {
        const std::lock_guard lock(mutex);
        if (!stopped) {
          relays.insert(relay);
          started = true;
        }
      }
      if (started) relay->start();
    }
    accept();
  });
}

void GrpcFrontDoor::Impl::forget(const std::shared_ptr<Relay>& relay, unsigned short port) {
  const std::lock_guard lock(mutex);
  relays.erase(relay);
  if (port != 0) client_by_port.erase(port);
}

Result<std::unique_ptr<GrpcFrontDoor>> GrpcFrontDoor::start(const std::string& address,
                                                            const std::string& upstream,
                                                            FrontDoorOptions options) {
  MD_ASSIGN_OR_RETURN(tcp::endpoint endpoint, parse_endpoint(address));
  MD_ASSIGN_OR_RETURN(tcp::endpoint upstream_endpoint, parse_endpoint(upstream));
  auto impl = std::make_shared<Impl>(options);
  impl->upstream = upstream_endpoint;
  error_code error;
  impl->acceptor.open(endpoint.protocol(), error);
  if (!error) impl->acceptor.set_option(asio::socket_base::reuse_address(true), error);
  if (!error) impl->acceptor.bind(endpoint, error);
  if (!error) impl->acceptor.listen(asio::socket_base::max_listen_connections, error);
  if (error) {
    return Error(ErrorCode::Internal, "cannot listen on " + address + ": " + error.message());
  }
  const int port = impl->acceptor.local_endpoint().port();
  impl->accept();
  impl->thread = std::thread([raw = impl.get()] { raw->io.run(); });
  return std::unique_ptr<GrpcFrontDoor>(new GrpcFrontDoor(std::move(impl), port));
}

void GrpcFrontDoor::stop() {
  if (!impl_->thread.joinable()) return;
  {
    const std::lock_guard lock(impl_->mutex);
    impl_->stopped = true;
  }
  impl_->io.stop();
  impl_->thread.join();
  error_code ignored;
  impl_->acceptor.close(ignored);
  // The io thread is gone: nothing else touches the relays now.
  std::set<std::shared_ptr<Relay>> relays;
  {
    const std::lock_guard lock(impl_->mutex);
    relays = impl_->relays;
  }
  for (const std::shared_ptr<Relay>& relay : relays) relay->close();
}

GrpcFrontDoor::~GrpcFrontDoor() { stop(); }

std::optional<std::string> GrpcFrontDoor::client_of(std::string_view grpc_peer) const {
  // "ipv4:127.0.0.1:54321" or "ipv6:[::1]:54321": the port is after the last colon.
  const std::size_t colon = grpc_peer.rfind(':');
  if (colon == std::string_view::npos) return std::nullopt;
  const std::string_view host = grpc_peer.substr(0, colon);
  if (host != "ipv4:127.0.0.1" && host != "ipv6:[::1]") return std::nullopt;
  unsigned port = 0;
  for (const char c : grpc_peer.substr(colon + 1)) {
    if (c < '0' || c > '9' || port > 65535) return std::nullopt;
    port = port * 10 + static_cast<unsigned>(c - '0');
  }
  const std::lock_guard lock(impl_->mutex);
  const auto it = impl_->client_by_port.find(static_cast<unsigned short>(port));
  if (it == impl_->client_by_port.end()) return std::nullopt;
  return it->second;
}

ConnectionStats GrpcFrontDoor::stats() const { return impl_->gate.stats(); }

}  // namespace meshdeform::transport
