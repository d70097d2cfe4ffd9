#include "server/transport/http_server.h"
#include "server/transport/tcp_address.h"

#include "server/service/guard.h"
#include "server/service/log.h"

#include <boost/asio/dispatch.hpp>
#include <boost/asio/io_context.hpp>
#include <boost/asio/ip/tcp.hpp>
#include <boost/asio/post.hpp>
#include <boost/asio/ssl.hpp>
#include <boost/asio/steady_timer.hpp>
#include <boost/asio/strand.hpp>
#include <boost/asio/write.hpp>
#include <boost/beast/core.hpp>
#include <boost/beast/http.hpp>
#include <boost/beast/ssl.hpp>

#include <algorithm>
#include <array>
#include <atomic>
#include <charconv>
#include <chrono>
#include <cstring>
#include <deque>
#include <limits>
#include <mutex>
#include <optional>
#include <set>
#include <thread>
#include <type_traits>
#include <utility>

namespace meshdeform::transport {
namespace {

namespace asio = boost::asio;
namespace beast = boost::beast;
namespace http = beast::http;
using tcp = asio::ip::tcp;

std::string_view to_std(beast::string_view text) { return {text.data(), text.size()}; }

/// Header values never carry CR or LF (no response splitting, whatever a handler passes).
std::string header_safe(std::string_view value) {
  std::string out;
  out.reserve(value.size());
  for (const char c : value) {
    if (c != '\r' && c != '\n') out.push_back(c);
  }
  return out;
}

std::string status_line_and_headers(unsigned version, int status, std::string_view content_type,
                                    const HttpHeaders& headers, bool keep_alive) {
  std::string out = version >= 11 ? "HTTP/1.1 " : "HTTP/1.0 ";
  out += std::to_string(status);
  out += ' ';
  out += to_std(http::obsolete_reason(static_cast<http::status>(status)));
  out += "\r\nServer: meshdeform\r\n";
  if (!content_type.empty()) out += "Content-Type: " + header_safe(content_type) + "\r\n";
  for (const auto& [name, value] : headers) {
    out += header_safe(name) + ": " + header_safe(value) + "\r\n";
  }
  if (!keep_alive) {
    out += "Connection: close\r\n";
  } else if (version < 11) {
    out += "Connection: keep-alive\r\n";
  }
  return out;
}

/// Lets exchanges post work into the listener's io_context only while it exists and runs:
/// HttpServer::stop() clears `is_alive` (under the mutex) before the io_context can go away.
struct Lifeline {
  std::mutex mutex;
  bool is_alive = true;
};

/// A chunk's completion, run exactly once: with the write's result, or with false when it is
/// dropped unrun (the connection or the server went away first).
class Completion {
 public:
  Completion() = default;
  explicit Completion(std::function<void(bool)> fn) : fn_(std::move(fn)) {}
  Completion(Completion&& other) noexcept : fn_(std::exchange(other.fn_, nullptr)) {}
  Completion& operator=(Completion&& other) noexcept {
    if (this != &other) {
      run(false);
      fn_ = std::exchange(other.fn_, nullptr);
    }
    return *this;
  }
  Completion(const Completion&) = delete;
  Completion& operator=(const Completion&) = delete;
  ~Completion() { run(false); }

  void run(bool ok) {
    if (std::function<void(bool)> fn = std::exchange(fn_, nullptr)) fn(ok);
  }

 private:
  std::function<void(bool)> fn_;
};

class ConnectionBase;

}  // namespace

struct HttpServer::Impl {
  /// Set: HTTPS. First, so that it outlives every connection's stream (and the io_context's
  /// handlers holding them).
  std::unique_ptr<asio::ssl::context> ssl;
  asio::io_context io;
  tcp::acceptor acceptor{io};
  AsyncHttpHandler handler;
  HttpServerOptions options;
  std::vector<std::thread> threads;
  std::mutex mutex;
  std::set<std::shared_ptr<ConnectionBase>> connections;
  bool stopped = false;
  std::shared_ptr<Lifeline> lifeline = std::make_shared<Lifeline>();
  std::shared_ptr<ConnectionGate> gate;

  void accept();
};

namespace {

/// What the server's connection set and the exchanges need of a connection, whatever its stream
/// (plain TCP or TLS over TCP). The do_* operations run on the connection's strand (executor()).
class ConnectionBase : public std::enable_shared_from_this<ConnectionBase> {
 public:
  virtual ~ConnectionBase() = default;
  virtual void start() = 0;
  virtual asio::any_io_executor executor() = 0;
  /// Closes at once; only from the thread stopping the server, once the listener threads are
  /// joined.
  virtual void abort() = 0;
  virtual void do_respond(std::uint64_t seq, HttpResponse response) = 0;
  virtual void do_start_stream(std::uint64_t seq, int status, std::string content_type,
                               HttpHeaders headers) = 0;
  virtual void do_write_chunk(std::uint64_t seq, std::string data, Completion done) = 0;
  virtual void do_end_stream(std::uint64_t seq) = 0;
  virtual void do_on_close(std::uint64_t seq, std::function<void()> callback) = 0;
};

/// The remote address in gRPC's peer() form without the port; empty when unknown.
std::string peer_of(const tcp::socket& socket) {
  beast::error_code error;
  const tcp::endpoint remote = socket.remote_endpoint(error);
  return error ? std::string() : client_address(remote);
}

/// One keep-alive connection; everything runs on its strand. Per request: read the header (with
/// the read timeout), pick the route's body limit, read the body, hand the request to the handler
/// with an exchange tagged by the request's sequence number, and meanwhile keep one read open
/// ("monitor") so that a client closing its socket is seen at once. Responses are a queue of
/// byte strings written one at a time, each with the write timeout.
///
/// `Stream` is beast::tcp_stream (HTTP) or beast::ssl_stream<beast::tcp_stream> (HTTPS, which
/// first handshakes); timeouts and closing act on the TCP layer below either.
template <typename Stream>
class Connection final : public ConnectionBase {
 public:
  static constexpr bool kIsTls = !std::is_same_v<Stream, beast::tcp_stream>;

  /// @param[in] stream_args  what constructs `Stream`: the accepted socket (and the SSL context).
  template <typename... StreamArgs>
  Connection(HttpServer::Impl& server, std::string peer, ConnectionGate::Ticket ticket,
             StreamArgs&&... stream_args)
      : stream_(std::forward<StreamArgs>(stream_args)...),
        linger_timer_(stream_.get_executor()),
        server_(server),
        peer_(std::move(peer)),
        ticket_(std::move(ticket)) {}

  void start() override {
    if constexpr (kIsTls) {
      asio::dispatch(stream_.get_executor(),
                     beast::bind_front_handler(&Connection::handshake, self()));
    } else {
      asio::dispatch(stream_.get_executor(), beast::bind_front_handler(&Connection::read, self()));
    }
  }

  asio::any_io_executor executor() override { return stream_.get_executor(); }

  /// Closes at once, from the thread stopping the server once the listener threads are joined
  /// (nothing else touches this object then).
  void abort() override { drop(); }

  // The exchange's operations, on the strand. A stale sequence number (an exchange of an earlier
  // request on this connection) is ignored.
  void do_respond(std::uint64_t seq, HttpResponse response) override {
    if (seq != seq_ || is_closed_ || is_answered_) return;
    is_answered_ = true;
    is_complete_ = true;
    std::string bytes =
        status_line_and_headers(version_, response.status, response.content_type, response.headers,
                                keep_alive_);
    if (response.status == 204 || response.status == 304 || response.status < 200) {
      bytes += "\r\n";  // no body, and no Content-Length (RFC 9110 8.6)
      enqueue(std::move(bytes), Completion());
      return;
    }
    bytes += "Content-Length: " + std::to_string(response.body.size()) + "\r\n\r\n";
    if (response.body.size() < 64 * 1024) {
      bytes += response.body;
      enqueue(std::move(bytes), Completion());
    } else {
      enqueue(std::move(bytes), Completion());  // a big body (a mesh) is not copied again
      enqueue(std::move(response.body), Completion());
    }
  }

  void do_start_stream(std::uint64_t seq, int status, std::string content_type,
                       HttpHeaders headers) override {
    if (seq != seq_ || is_closed_ || is_answered_) return;
    is_answered_ = true;
    is_streaming_ = true;
    if (version_ < 11) keep_alive_ = false;  // HTTP/1.0: the body ends when the connection does
    std::string bytes =
        status_line_and_headers(version_, status, content_type, headers, keep_alive_);
    if (version_ >= 11) bytes += "Transfer-Encoding: chunked\r\n";
    bytes += "\r\n";
    enqueue(std::move(bytes), Completion());
  }

  void do_write_chunk(std::uint64_t seq, std::string data, Completion done) override {
    if (seq != seq_ || is_closed_ || !is_streaming_ || is_complete_) {
      done.run(false);
      return;
    }
    if (data.empty()) {
      done.run(true);  // an empty chunk would end the body
      return;
    }
    if (version_ >= 11) {
      char size[32];
      const auto [end, ec] = std::to_chars(size, size + sizeof size, data.size(), 16);
      (void)ec;
      std::string bytes(size, end);
      bytes.reserve(bytes.size() + data.size() + 4);
      bytes += "\r\n";
      bytes += data;
      bytes += "\r\n";
      enqueue(std::move(bytes), std::move(done));
    } else {
      enqueue(std::move(data), std::move(done));
    }
  }

  void do_end_stream(std::uint64_t seq) override {
    if (seq != seq_ || is_closed_ || !is_streaming_ || is_complete_) return;
    is_complete_ = true;
    if (version_ >= 11) {
      enqueue("0\r\n\r\n", Completion());
    } else if (!is_writing_ && queue_.empty()) {
      on_response_written();
    }
  }

  void do_on_close(std::uint64_t seq, std::function<void()> callback) override {
    if (seq != seq_ || is_response_done_) return;
    if (is_closed_) {
      if (callback) callback();
      return;
    }
    close_callback_ = std::move(callback);
  }

 private:
  std::shared_ptr<Connection> self() {
    return std::static_pointer_cast<Connection>(shared_from_this());
  }
  beast::tcp_stream& tcp() { return beast::get_lowest_layer(stream_); }

  /// HTTPS: the TLS handshake, bounded by the read timeout. A client that fails it (speaks
  /// plaintext, distrusts our certificate, lacks a required client certificate) gets no answer:
  /// there is no channel to send one on. Debug level: port scanners and health probes do this.
  void handshake() {
    tcp().expires_after(std::chrono::seconds(server_.options.header_timeout_seconds));
    stream_.async_handshake(asio::ssl::stream_base::server,
                            beast::bind_front_handler(&Connection::on_handshake, self()));
  }

  void on_handshake(beast::error_code error) {
    if (error) {
      if (error == beast::error::timeout) server_.gate->note_header_timeout();
      service::log_event(service::LogLevel::Debug, "tls_handshake_failed",
                         service::LogFields().add("peer", peer_).add("message", error.message()));
      drop();
      return;
    }
    read();
  }

  void read() {
    if (is_closed_) return;
    wants_next_ = false;
    is_answered_ = false;
    is_streaming_ = false;
    is_complete_ = false;
    is_response_done_ = false;
    close_callback_ = nullptr;
    parser_.emplace();
    parser_->header_limit(64 * 1024);
    // Checked per route once the request line is known. (Not boost::none: Beast 1.74 compares
    // Content-Length against the optional, and anything is greater than none.)
    parser_->body_limit(std::numeric_limits<std::uint64_t>::max());
    tcp().expires_after(std::chrono::seconds(server_.options.header_timeout_seconds));
    http::async_read_header(stream_, buffer_, *parser_,
                            beast::bind_front_handler(&Connection::on_header, self()));
  }

  void on_header(beast::error_code error, std::size_t) {
    if (error) {
      if (error == beast::error::timeout) server_.gate->note_header_timeout();
      drop();
      return;
    }
    tcp().expires_after(std::chrono::seconds(server_.options.read_timeout_seconds));  // the body
    const auto& header = parser_->get();
    const std::size_t limit =
        server_.options.body_limit
            ? server_.options.body_limit(to_std(header.method_string()), to_std(header.target()))
            : server_.options.max_request_bytes;
    limit_ = limit;
    if (const auto length = parser_->content_length(); length && *length > limit) {
      // The body is not read: the handler answers from the header alone, then we close.
      HttpRequest in = make_request();
      in.is_body_over_limit = true;
      in.declared_body_bytes = *length;
      dispatch(std::move(in), /*keep_alive=*/false, header.version());
      return;
    }
    parser_->body_limit(static_cast<std::uint64_t>(limit));
    if (iequals_ascii(to_std(header[http::field::expect]), "100-continue")) {
      auto reply = std::make_shared<std::string>(
          header.version() >= 11 ? "HTTP/1.1 100 Continue\r\n\r\n" : "HTTP/1.0 100 Continue\r\n\r\n");
      asio::async_write(stream_, asio::buffer(*reply),
                        [connection = self(), reply](beast::error_code e, std::size_t) {
                          if (e) {
                            connection->drop();
                            return;
                          }
                          connection->read_body();
                        });
      return;
    }
    read_body();
  }

  void read_body() {
    http::async_read(stream_, buffer_, *parser_,
                     beast::bind_front_handler(&Connection::on_read, self()));
  }

  void on_read(beast::error_code error, std::size_t) {
    if (error == http::error::body_limit) {
      ++seq_;
      version_ = parser_->get().version();
      keep_alive_ = false;
      is_response_done_ = false;
      do_respond(seq_, text_response(413, "request body over " + std::to_string(limit_) + " bytes\n"));
      return;
    }
    if (error) {
      drop();
      return;
    }
    HttpRequest in = make_request();
    in.body = std::move(parser_->get().body());
    dispatch(std::move(in), parser_->get().keep_alive(), parser_->get().version());
  }

  HttpRequest make_request() const {
    const auto& request = parser_->get();
    HttpRequest in;
    in.method = std::string(request.method_string());
    in.target = std::string(request.target());
    in.peer = peer_;
    for (const auto& field : request) {
      in.headers.emplace_back(std::string(field.name_string()), std::string(field.value()));
    }
    return in;
  }

  void dispatch(HttpRequest in, bool keep_alive, unsigned version);

  /// Keeps one read open while a response is pending, to see the client leave.
  void start_monitor() {
    if (is_monitoring_ || is_closed_ || buffer_.size() >= server_.options.max_pipelined_bytes) {
      return;
    }
    is_monitoring_ = true;
    stream_.async_read_some(asio::buffer(monitor_buffer_),
                            beast::bind_front_handler(&Connection::on_monitor, self()));
  }

  void on_monitor(beast::error_code error, std::size_t n) {
    is_monitoring_ = false;
    if (is_lingering_) {
      buffer_.clear();
      if (error) {
        drop();
      } else {
        start_monitor();
      }
      return;
    }
    if (n > 0) {
      // Bytes of a pipelined next request: kept for the next read.
      const auto target = buffer_.prepare(n);
      std::memcpy(target.data(), monitor_buffer_.data(), n);
      buffer_.commit(n);
    }
    if (is_closed_) return;
    if (error == asio::error::operation_aborted && wants_next_) {
      read();  // cancelled by on_response_written to read the next request
      return;
    }
    if (error) {
      // EOF, reset, or the socket was closed by a write timeout (operation_aborted).
      drop();
      return;
    }
    if (wants_next_) {
      read();
    } else {
      start_monitor();
    }
  }

  void enqueue(std::string bytes, Completion done) {
    queue_.push_back(Pending{std::move(bytes), std::move(done)});
    write_next();
  }

  void write_next() {
    if (is_writing_ || queue_.empty() || is_closed_) return;
    is_writing_ = true;
    // With the monitor read pending this arms the write timer only.
    tcp().expires_after(std::chrono::seconds(server_.options.write_timeout_seconds));
    asio::async_write(stream_, asio::buffer(queue_.front().bytes),
                      beast::bind_front_handler(&Connection::on_write, self()));
  }

  void on_write(beast::error_code error, std::size_t) {
    is_writing_ = false;
    Pending written = std::move(queue_.front());
    queue_.pop_front();
    if (error || is_closed_) {
      written.done.run(false);
      drop();
      return;
    }
    written.done.run(true);
    if (!queue_.empty()) {
      write_next();
    } else if (is_complete_) {
      on_response_written();
    }
  }

  void on_response_written() {
    is_response_done_ = true;
    close_callback_ = nullptr;
    if (!keep_alive_) {
      beast::error_code ignored;
      tcp().socket().shutdown(tcp::socket::shutdown_send, ignored);
      linger();
      return;
    }
    if (is_monitoring_) {
      wants_next_ = true;
      tcp().cancel();  // on_monitor (operation_aborted, or data already read) reads next
    } else {
      read();
    }
  }

  /// After the last response of a connection: the client may still be sending (a body over the
  /// limit that we did not read). Closing now would reset the connection and could destroy the
  /// response in flight, so read and discard until the client closes, for at most 2 s.
  void linger() {
    is_lingering_ = true;
    buffer_.clear();
    linger_timer_.expires_after(std::chrono::seconds(2));
    linger_timer_.async_wait([connection = self()](beast::error_code error) {
      if (!error) connection->drop();
    });
    start_monitor();
  }

  /// Closes the connection: the pending exchange learns it (on_close), queued chunk callbacks
  /// get false, and the server forgets this connection.
  void drop() {
    if (is_closed_) return;
    is_closed_ = true;
    if (std::function<void()> callback = std::move(close_callback_); callback && !is_response_done_) {
      callback();
    }
    close_callback_ = nullptr;
    // The in-flight write (if any) stays queued: it completes with an error and reports itself.
    std::deque<Pending> failed;
    while (queue_.size() > (is_writing_ ? 1U : 0U)) {
      failed.push_back(std::move(queue_.back()));
      queue_.pop_back();
    }
    for (Pending& pending : failed) pending.done.run(false);
    beast::error_code ignored;
    linger_timer_.cancel();
    tcp().socket().shutdown(tcp::socket::shutdown_both, ignored);
    tcp().close();
    ticket_.release();
    const std::lock_guard lock(server_.mutex);
    server_.connections.erase(shared_from_this());
  }

  struct Pending {
    std::string bytes;
    Completion done;
  };

  Stream stream_;
  asio::steady_timer linger_timer_;
  beast::flat_buffer buffer_;
  std::optional<http::request_parser<http::string_body>> parser_;
  HttpServer::Impl& server_;
  const std::string peer_;
  ConnectionGate::Ticket ticket_;  ///< this connection's place under the gate's caps
  std::size_t limit_ = 0;
  std::uint64_t seq_ = 0;          // the current request's number
  unsigned version_ = 11;
  bool keep_alive_ = true;
  bool is_answered_ = false;       // respond() or start_stream() seen
  bool is_streaming_ = false;
  bool is_complete_ = false;       // the whole response is queued
  bool is_response_done_ = false;  // ... and written
  bool is_closed_ = false;
  bool is_monitoring_ = false;
  bool wants_next_ = false;        // read the next request when the monitor read ends
  bool is_writing_ = false;
  bool is_lingering_ = false;      // the last response is written; discarding input
  std::deque<Pending> queue_;
  std::function<void()> close_callback_;
  std::array<char, 4096> monitor_buffer_{};
};

class ConnectionExchange final : public HttpExchange {
 public:
  ConnectionExchange(const std::shared_ptr<ConnectionBase>& connection,
                     std::shared_ptr<Lifeline> lifeline, std::uint64_t seq)
      : connection_(connection), lifeline_(std::move(lifeline)), seq_(seq) {}

  ~ConnectionExchange() override {
    if (!is_answered_.exchange(true)) {
      post([seq = seq_](ConnectionBase& c) {
        c.do_respond(seq, text_response(500, "no response\n"));
      });
    }
  }

  void respond(HttpResponse response) override {
    is_answered_.store(true);
    post([seq = seq_, response = std::move(response)](ConnectionBase& c) mutable {
      c.do_respond(seq, std::move(response));
    });
  }

  void start_stream(int status, std::string content_type, HttpHeaders headers) override {
    is_answered_.store(true);
    post([seq = seq_, status, content_type = std::move(content_type),
          headers = std::move(headers)](ConnectionBase& c) mutable {
      c.do_start_stream(seq, status, std::move(content_type), std::move(headers));
    });
  }

  void write_chunk(std::string data, std::function<void(bool)> done) override {
    // Shared so that the posted handler stays copyable; if it is destroyed unrun (the server
    // stopped), the Completion reports false.
    auto completion = std::make_shared<Completion>(std::move(done));
    const bool posted =
        post([seq = seq_, data = std::move(data), completion](ConnectionBase& c) mutable {
          c.do_write_chunk(seq, std::move(data), std::move(*completion));
        });
    if (!posted) completion->run(false);
  }

  void end_stream() override {
    post([seq = seq_](ConnectionBase& c) { c.do_end_stream(seq); });
  }

  void on_close(std::function<void()> callback) override {
    auto shared = std::make_shared<std::function<void()>>(std::move(callback));
    const bool posted = post([seq = seq_, shared](ConnectionBase& c) mutable {
      c.do_on_close(seq, std::move(*shared));
    });
    if (!posted && *shared) (*shared)();  // the connection or the server is already gone
  }

 private:
  /// @return false when the server has stopped or the connection is gone.
  template <typename Fn>
  bool post(Fn&& fn) {
    const std::lock_guard lock(lifeline_->mutex);
    if (!lifeline_->is_alive) return false;
    std::shared_ptr<ConnectionBase> connection = connection_.lock();
    if (!connection) return false;
    auto executor = connection->executor();
    asio::post(executor, [connection = std::move(connection), fn = std::forward<Fn>(fn)]() mutable {
      fn(*connection);
    });
    return true;
  }

  std::weak_ptr<ConnectionBase> connection_;
  std::shared_ptr<Lifeline> lifeline_;
  std::uint64_t seq_;
  std::atomic<bool> is_answered_{false};
};

template <typename Stream>
void Connection<Stream>::dispatch(HttpRequest in, bool keep_alive, unsigned version) {
  ++seq_;
  keep_alive_ = keep_alive;
  version_ = version;
  // No read timeout while the handler works (the gateway bounds its calls with deadlines); the
  // monitor read watches for the client leaving.
  tcp().expires_never();
  start_monitor();
  auto exchange = std::make_shared<ConnectionExchange>(self(), server_.lifeline, seq_);
  const Status handled = service::run_guarded("http", [&]() -> Status {
    server_.handler(std::move(in), exchange);
    return Status::success();
  });
  if (!handled.ok()) exchange->respond(text_response(500, "internal error\n"));
}

}  // namespace

void HttpServer::Impl::accept() {
  acceptor.async_accept(asio::make_strand(io), [this](beast::error_code error, tcp::socket socket) {
    if (error) {
      if (error == asio::error::operation_aborted) return;  // stopping
    } else {
      // Chunks of a stream are small and must leave at once (no Nagle delay).
      beast::error_code ignored;
      socket.set_option(tcp::no_delay(true), ignored);
      std::string peer = peer_of(socket);
      // Over a cap: closed at once (the socket's destructor), before any byte is read.
      std::optional<ConnectionGate::Ticket> ticket = gate->admit(peer);
      std::shared_ptr<ConnectionBase> connection;
      if (!ticket) {
        socket.close(ignored);
      } else if (ssl) {
        connection = std::make_shared<Connection<beast::ssl_stream<beast::tcp_stream>>>(
            *this, std::move(peer), std::move(*ticket), std::move(socket), *ssl);
      } else {
        connection = std::make_shared<Connection<beast::tcp_stream>>(
            *this, std::move(peer), std::move(*ticket), std::move(socket));
      }
      if (connection) {
        const std::lock_guard lock(mutex);
        if (stopped) return;
        connections.insert(connection);
      }
      if (connection) connection->start();
    }
    accept();
  });
}

Result<std::unique_ptr<HttpServer>> HttpServer::start(const std::string& address,
                                                      HttpHandler handler,
                                                      HttpServerOptions options) {
  AsyncHttpHandler adapted = [handler = std::move(handler)](
                                 HttpRequest request, std::shared_ptr<HttpExchange> exchange) {
    respond_synchronously(handler, request, *exchange);
  };
  return start_async(address, std::move(adapted), std::move(options));
}

Result<std::unique_ptr<HttpServer>> HttpServer::start_async(const std::string& address,
                                                            AsyncHttpHandler handler,
                                                            HttpServerOptions options) {
  MD_ASSIGN_OR_RETURN(tcp::endpoint endpoint, parse_endpoint(address));
  auto impl = std::make_unique<Impl>();
  if (options.tls) {
    MD_ASSIGN_OR_RETURN(impl->ssl, make_ssl_context(*options.tls));
  }
  impl->handler = std::move(handler);
  impl->options = std::move(options);
  impl->gate = impl->options.gate
                   ? impl->options.gate
                   : std::make_shared<ConnectionGate>(ConnectionLimits{
                         impl->options.max_connections_per_address, impl->options.max_connections});
  beast::error_code error;
  impl->acceptor.open(endpoint.protocol(), error);
  if (!error) impl->acceptor.set_option(asio::socket_base::reuse_address(true), error);
  if (!error) impl->acceptor.bind(endpoint, error);
  if (!error) impl->acceptor.listen(asio::socket_base::max_listen_connections, error);
  if (error) {
    return Error(ErrorCode::Internal, "cannot listen on " + address + ": " + error.message());
  }
  const int port = impl->acceptor.local_endpoint().port();
  impl->accept();
  for (int i = 0; i < std::max(1, impl->options.threads); ++i) {
    impl->threads.emplace_back([raw = impl.get()] { raw->io.run(); });
  }
  return std::unique_ptr<HttpServer>(new HttpServer(std::move(impl), port));
}

HttpServer::HttpServer(std::unique_ptr<Impl> impl, int port) : impl_(std::move(impl)), port_(port) {}

void HttpServer::stop() {
  if (!impl_) return;
  {
    const std::lock_guard lock(impl_->mutex);
    if (impl_->stopped) return;
    impl_->stopped = true;
  }
  // Stop the threads first; then no handler runs concurrently with the closes below, which may
  // run exchanges' on_close callbacks on this thread.
  impl_->io.stop();
  for (std::thread& thread : impl_->threads) thread.join();
  impl_->threads.clear();
  {
    const std::lock_guard lock(impl_->lifeline->mutex);
    impl_->lifeline->is_alive = false;
  }
  beast::error_code ignored;
  impl_->acceptor.close(ignored);
  std::set<std::shared_ptr<ConnectionBase>> connections;
  {
    const std::lock_guard lock(impl_->mutex);
    connections = impl_->connections;
  }
  for (const auto& connection : connections) connection->abort();
  const std::lock_guard lock(impl_->mutex);
  impl_->connections.clear();
}

HttpServer::~HttpServer() { stop(); }

}  // namespace meshdeform::transport
