#pragma once
/// @file tls_bridge.h
/// rediss:// for hiredis 0.14 (Debian 12), which has no TLS of its own: a relay thread opens a
/// TLS connection with OpenSSL (the server's certificate verified against the context's CAs and
/// the host name) and bridges it to hiredis over a socketpair. Sockets and OpenSSL stay here;
/// redis_store.cpp speaks only hiredis.

#include <openssl/ssl.h>

#include <atomic>
#include <chrono>
#include <future>
#include <memory>
#include <stop_token>
#include <string>

namespace meshdeform::redis {

/// What the relay thread reports once the TLS connection is up or has failed.
struct TlsOpened {
  int fd = -1;        ///< hiredis's end of the socketpair (-1: failed)
  std::string error;  ///< why it failed (host, port and reason included)
};

/// The body of a relay thread: connects to host:port within `timeout`, handshakes (verified
/// against `context`'s CAs and `host`: an IP address against the certificate's IP names, a name
/// against its DNS names, sent as SNI), reports through `opened`, then shuttles bytes until
/// either side closes, the connection fails or `stop` is requested (seen within 250 ms). Every
/// socket write happens on this thread, with SIGPIPE blocked. Sets `done` when it returns.
void tls_connection(std::stop_token stop, SSL_CTX* context, std::string host, int port,
                    std::chrono::milliseconds timeout, std::promise<TlsOpened> opened,
                    std::shared_ptr<std::atomic<bool>> done);

}  // namespace meshdeform::redis
