#include "server/transport/server_setup.h"

#include <grpcpp/ext/proto_server_reflection_plugin.h>
#include <grpcpp/health_check_service_interface.h>

#include <climits>
#include <mutex>

namespace meshdeform::transport {

void enable_health_and_reflection() {
  static std::once_flag once;
  std::call_once(once, [] {
    grpc::EnableDefaultHealthCheckService(true);
    grpc::reflection::InitProtoReflectionServerBuilderPlugin();
  });
}

void configure_builder(grpc::ServerBuilder& builder, grpc::Service& service, int max_message_mib) {
  const long long bytes = static_cast<long long>(max_message_mib) * 1024 * 1024;
  const int limit = bytes > INT_MAX ? INT_MAX : static_cast<int>(bytes);
  builder.SetMaxReceiveMessageSize(limit);
  builder.SetMaxSendMessageSize(limit);
  builder.RegisterService(&service);
}

}  // namespace meshdeform::transport
