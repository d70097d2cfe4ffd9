#pragma once
/// @file server_setup.h
/// ServerBuilder settings shared by meshdeform-server and the transport tests, so that the tests
/// run the configuration that ships.

#include <grpcpp/server_builder.h>

namespace meshdeform::transport {

/// Enables the standard grpc.health.v1 service (reports SERVING) and server reflection. Process
/// wide; call once before constructing the ServerBuilder.
void enable_health_and_reflection();

/// Registers `service` and raises the receive/send message limits to `max_message_mib` MiB
/// (meshes are uploaded in one message; see deformation.proto).
void configure_builder(grpc::ServerBuilder& builder, grpc::Service& service, int max_message_mib);

}  // namespace meshdeform::transport
