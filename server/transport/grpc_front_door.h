#pragma once
/// @file grpc_front_door.h
/// The public gRPC port (issue 40). gRPC 1.51 (Debian 12) cannot cap incoming connections, so
/// 5000 idle connections were all accepted, and at a low descriptor limit they starved the
/// process of the descriptors its state files need. The front door listens on the public
/// address in its place and relays every connection it admits, byte for byte (TLS included:
/// the gRPC server behind it terminates TLS), to the gRPC server on a loopback port of its own:
///  - each connection passes a ConnectionGate (per client address and in total) or is closed at
///    once;
///  - a connection that sends nothing within the first-bytes deadline is closed (a silent or
///    half-open socket does not hold a place for long);
///  - the gRPC server reports the relay's loopback address as the peer; client_of() maps it
///    back to the client's address, so per-client limits still see clients.
/// The cost is one loopback hop per message (two small copies on one thread).

#include <cstddef>
#include <memory>
#include <optional>
#include <string>
#include <string_view>

#include "core/base/status.h"
#include "server/transport/connection_gate.h"

namespace meshdeform::transport {

struct FrontDoorOptions {
  ConnectionLimits limits;
  /// The first bytes of a connection (the HTTP/2 preface or a TLS ClientHello) must arrive
  /// within this; then the connection may idle (a client's channel stays open between calls).
  int first_bytes_timeout_seconds = 10;
};

class GrpcFrontDoor {
 public:
  /// Listens on `address` ("host:port", port 0 picks one) and relays to `upstream`
  /// ("127.0.0.1:PORT", where the gRPC server listens).
  /// @return the running front door; InvalidArgument for a malformed address; Internal when it
  ///         cannot be bound.
  [[nodiscard]] static Result<std::unique_ptr<GrpcFrontDoor>> start(const std::string& address,
                                                                    const std::string& upstream,
                                                                    FrontDoorOptions options = {});
  /// Stops accepting and closes every relayed connection (idempotent).
  void stop();
  ~GrpcFrontDoor();
  GrpcFrontDoor(const GrpcFrontDoor&) = delete;
  GrpcFrontDoor& operator=(const GrpcFrontDoor&) = delete;

  int port() const { return port_; }
  /// The client's address ("ipv4:1.2.3.4", "ipv6:[::1]") of the relayed connection whose
  /// upstream end the gRPC server reports as `grpc_peer` ("ipv4:127.0.0.1:54321"); nullopt for
  /// a peer that is not one of the relay's connections.
  std::optional<std::string> client_of(std::string_view grpc_peer) const;
  ConnectionStats stats() const;

  struct Impl;  ///< implementation detail (Asio types stay out of this header)

 private:
  GrpcFrontDoor(std::shared_ptr<Impl> impl, int port) : impl_(std::move(impl)), port_(port) {}
  std::shared_ptr<Impl> impl_;
  int port_ = 0;
};

}  // namespace meshdeform::transport
