#include "server/redis/tls_bridge.h"

#include <arpa/inet.h>
#include <fcntl.h>
#include <netdb.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <openssl/err.h>
#include <openssl/x509v3.h>
#include <poll.h>
#include <pthread.h>
#include <signal.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstdint>
#include <cstring>

namespace meshdeform::redis {
namespace {

int remaining_ms(std::chrono::steady_clock::time_point deadline) {
  const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(
      deadline - std::chrono::steady_clock::now());
  return static_cast<int>(std::max<std::int64_t>(0, left.count()));
}

/// OpenSSL's reason for a failed handshake (this thread's error queue) and, when the
/// certificate was refused, the verifier's reason.
std::string tls_failure(SSL* ssl, int ssl_error, int saved_errno) {
  std::string reason;
  if (const unsigned long code = ERR_get_error(); code != 0) {
    const char* text = ERR_reason_error_string(code);
    reason = text != nullptr ? text : "OpenSSL error " + std::to_string(code);
  } else if (ssl_error == SSL_ERROR_SYSCALL || ssl_error == SSL_ERROR_ZERO_RETURN) {
    reason = saved_errno != 0 ? std::strerror(saved_errno)
                              : "the server closed the connection (is it a TLS port?)";
  } else {
    reason = "SSL error " + std::to_string(ssl_error);
  }
  if (const long verify = SSL_get_verify_result(ssl); verify != X509_V_OK) {
    reason += " (";
    reason += X509_verify_cert_error_string(verify);
    reason += ")";
  }
  return reason;
}

/// Shuttles bytes between hiredis's socketpair end (`pair`, non-blocking) and the TLS connection
/// (`ssl` on the non-blocking socket `fd`) until either side closes or fails, or `stop`.
void relay_bytes(std::stop_token stop, SSL* ssl, int fd, int pair) {
  std::string to_ssl, to_pair;
  char buffer[16 * 1024];
  const auto transient = [] { return errno == EAGAIN || errno == EWOULDBLOCK || errno == EINTR; };
  while (!stop.stop_requested()) {
    bool want_in = false, want_out = false;
    for (bool progress = true; progress;) {
      progress = false;
      want_in = want_out = false;
      if (!to_ssl.empty()) {
        const int n = SSL_write(ssl, to_ssl.data(), static_cast<int>(to_ssl.size()));
        if (n > 0) {
          to_ssl.erase(0, static_cast<std::size_t>(n));
          progress = true;
        } else {
          const int e = SSL_get_error(ssl, n);
          if (e == SSL_ERROR_WANT_READ) want_in = true;
          else if (e == SSL_ERROR_WANT_WRITE) want_out = true;
          else return;
        }
      }
      if (to_pair.empty()) {
        const int n = SSL_read(ssl, buffer, static_cast<int>(sizeof buffer));
        if (n > 0) {
          to_pair.assign(buffer, static_cast<std::size_t>(n));
          progress = true;
        } else {
          const int e = SSL_get_error(ssl, n);
          if (e == SSL_ERROR_WANT_READ) want_in = true;
          else if (e == SSL_ERROR_WANT_WRITE) want_out = true;
          else return;  // the server closed (close_notify or EOF) or the connection failed
        }
      }
      if (!to_pair.empty()) {
        const ssize_t n = ::send(pair, to_pair.data(), to_pair.size(), MSG_NOSIGNAL);
        if (n > 0) {
          to_pair.erase(0, static_cast<std::size_t>(n));
          progress = true;
        } else if (n < 0 && !transient()) {
          return;
        }
      }
      if (to_ssl.empty()) {
        const ssize_t n = ::recv(pair, buffer, sizeof buffer, 0);
        if (n > 0) {
          to_ssl.assign(buffer, static_cast<std::size_t>(n));
          progress = true;
        } else if (n == 0 || !transient()) {
          return;  // hiredis closed its end (redisFree)
        }
      }
    }
    pollfd p[2] = {
        {pair, static_cast<short>((to_ssl.empty() ? POLLIN : 0) | (to_pair.empty() ? 0 : POLLOUT)),
         0},
        {fd, static_cast<short>((want_in ? POLLIN : 0) | (want_out ? POLLOUT : 0)), 0}};
    // Bounded: the stop request (store destruction) is seen within 250 ms.
    if (::poll(p, 2, 250) < 0 && errno != EINTR) return;
    if ((p[0].revents | p[1].revents) & (POLLERR | POLLNVAL)) return;
  }
}

}  // namespace

/// A relay thread: connects to host:port, TLS handshake (verified against `context`'s CAs and
/// `host`), reports through `opened`, then relays until either side closes. Every socket write
/// of the connection happens on this thread, with SIGPIPE blocked (a reset gives EPIPE).
void tls_connection(std::stop_token stop, SSL_CTX* context, std::string host, int port,
                    std::chrono::milliseconds timeout, std::promise<TlsOpened> opened,
                    std::shared_ptr<std::atomic<bool>> done) {
  struct MarkDone {
    std::atomic<bool>& done;
    ~MarkDone() { done.store(true); }
  } mark{*done};
  sigset_t pipe_signal;
  sigemptyset(&pipe_signal);
  sigaddset(&pipe_signal, SIGPIPE);
  pthread_sigmask(SIG_BLOCK, &pipe_signal, nullptr);
  const std::string where = "redis at " + host + ":" + std::to_string(port);
  const auto fail = [&](std::string why) { opened.set_value({-1, where + why}); };
  const auto deadline = std::chrono::steady_clock::now() + timeout;

  addrinfo hints{};
  hints.ai_family = AF_UNSPEC;
  hints.ai_socktype = SOCK_STREAM;
  addrinfo* found = nullptr;
  if (const int rc = ::getaddrinfo(host.c_str(), std::to_string(port).c_str(), &hints, &found);
      rc != 0) {
    return fail(std::string(" is unreachable: ") + ::gai_strerror(rc));
  }
  int fd = -1;
  std::string last = "no address";
  for (const addrinfo* a = found; a != nullptr; a = a->ai_next) {
    fd = ::socket(a->ai_family, a->ai_socktype | SOCK_NONBLOCK | SOCK_CLOEXEC, a->ai_protocol);
    if (fd < 0) {
      last = std::strerror(errno);
      continue;
    }
    if (::connect(fd, a->ai_addr, a->ai_addrlen) == 0) break;
    if (errno == EINPROGRESS) {
      pollfd p{fd, POLLOUT, 0};
      if (::poll(&p, 1, remaining_ms(deadline)) == 1) {
        int error = 0;
        socklen_t length = sizeof error;
        ::getsockopt(fd, SOL_SOCKET, SO_ERROR, &error, &length);
        if (error == 0) break;
        last = std::strerror(error);
      } else {
        last = "Connection timed out";
      }
    } else {
      last = std::strerror(errno);
    }
    ::close(fd);
    fd = -1;
  }
  ::freeaddrinfo(found);
  if (fd < 0) return fail(" is unreachable: " + last);
  const int one = 1;
  ::setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);

  SSL* ssl = SSL_new(context);
  const auto close_all = [&] {
    if (ssl != nullptr) SSL_free(ssl);
    ::close(fd);
  };
  if (ssl == nullptr || SSL_set_fd(ssl, fd) != 1) {
    close_all();
    return fail(": TLS setup failed (out of memory?)");
  }
  SSL_set_mode(ssl, SSL_MODE_ACCEPT_MOVING_WRITE_BUFFER);
  // The certificate must name the URL's host: an IP address is checked against its IP
  // subjectAltNames, a name against its DNS names (and sent as SNI).
  in6_addr ip6{};
  in_addr ip4{};
  const bool is_ip = ::inet_pton(AF_INET, host.c_str(), &ip4) == 1 ||
                     ::inet_pton(AF_INET6, host.c_str(), &ip6) == 1;
  bool named = false;
  if (is_ip) {
    named = X509_VERIFY_PARAM_set1_ip_asc(SSL_get0_param(ssl), host.c_str()) == 1;
  } else {
    SSL_set_hostflags(ssl, X509_CHECK_FLAG_NO_PARTIAL_WILDCARDS);
    named = SSL_set_tlsext_host_name(ssl, host.c_str()) == 1 && SSL_set1_host(ssl, host.c_str()) == 1;
  }
  if (!named) {
    close_all();
    return fail(": cannot verify the host name '" + host + "' (not a valid name or address)");
  }
  ERR_clear_error();
  for (;;) {
    errno = 0;
    const int rc = SSL_connect(ssl);
    if (rc == 1) break;
    const int saved_errno = errno;
    const int e = SSL_get_error(ssl, rc);
    if (e == SSL_ERROR_WANT_READ || e == SSL_ERROR_WANT_WRITE) {
      pollfd p{fd, static_cast<short>(e == SSL_ERROR_WANT_READ ? POLLIN : POLLOUT), 0};
      if (::poll(&p, 1, remaining_ms(deadline)) == 1) continue;
      close_all();
      return fail(": TLS handshake timed out");
    }
    std::string reason = tls_failure(ssl, e, saved_errno);
    close_all();
    return fail(": TLS handshake failed: " + reason);
  }
  int pair[2] = {-1, -1};
  if (::socketpair(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0, pair) != 0) {
    const std::string reason = std::strerror(errno);
    SSL_shutdown(ssl);
    close_all();
    return fail(": socketpair: " + reason);
  }
  const int flags = ::fcntl(pair[1], F_GETFL);
  ::fcntl(pair[1], F_SETFL, flags | O_NONBLOCK);
  opened.set_value({pair[0], {}});  // hiredis owns pair[0] from here (redisFree closes it)
  relay_bytes(stop, ssl, fd, pair[1]);
  SSL_shutdown(ssl);  // best effort close_notify (non-blocking socket: never waits)
  close_all();
  ::close(pair[1]);
}


}  // namespace meshdeform::redis
