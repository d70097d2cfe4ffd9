#pragma once
/// @file deform_service_impl.h
/// The gRPC face of service::DeformationService (callback API). A thin adapter: converts
/// messages (proto_convert), calls the service, maps statuses (status_mapping). Solves never run
/// on gRPC threads: SetHandles / MoveHandles use the service's *_async calls and Finish from the
/// worker; client cancellation (OnCancel) requests the solve's stop and the call's deadline
/// becomes the move's deadline. Watch pulls from the subscription's one-slot mailbox when it is
/// notified, so a slow stream never blocks the editor or a gRPC thread. Every call is counted and
/// timed in the service's MetricsRegistry and logged as one JSON line (never with its token).

#include <chrono>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <string_view>

#include "meshdeform/v1/deformation.grpc.pb.h"
#include "server/service/deformation_service.h"
#include "server/transport/serial_executor.h"

namespace meshdeform::transport {

/// How the adapter names the client of a call for the service's per-client rate limits.
struct ClientIdentityOptions {
  /// Use the first address of the `x-forwarded-for` metadata when a call carries one. Only for a
  /// server reachable solely through a proxy that sets that header itself (nginx:
  /// `grpc_set_header X-Forwarded-For $remote_addr;`): anyone else could pick their own name.
  bool trust_forwarded_for = false;
  /// The client address of a connection the gRPC front door relays (GrpcFrontDoor::client_of),
  /// given the peer gRPC reports; empty, or nullopt from it, keeps the reported peer.
  std::function<std::optional<std::string>(std::string_view grpc_peer)> resolve_peer;
};

/// The rate-limit name of a call's client: with trust_forwarded_for, the first `x-forwarded-for`
/// address when there is one (the gateway passes a proxy's header on); else the peer address
/// without its port ("ipv4:10.0.0.7", "ipv6:[::1]"); for calls forwarded in-process by the
/// gRPC-Web gateway, the browser's address the gateway passes as `x-meshdeform-peer` (trusted
/// only in-process: a network peer cannot set it).
std::string client_identity(const grpc::CallbackServerContext& context,
                            const ClientIdentityOptions& options);

class DeformServiceImpl final : public v1::DeformationService::CallbackService {
 public:
  /// @param[in] service  must outlive the grpc::Server this is registered with.
  explicit DeformServiceImpl(service::DeformationService& service,
                             ClientIdentityOptions identity = {})
      : service_(service), identity_(identity) {}
  ~DeformServiceImpl() override;

  grpc::ServerUnaryReactor* CreateSession(grpc::CallbackServerContext* context,
                                          const v1::CreateSessionRequest* request,
                                          v1::CreateSessionResponse* response) override;
  grpc::ServerUnaryReactor* SetHandles(grpc::CallbackServerContext* context,
                                       const v1::SetHandlesRequest* request,
                                       v1::SetHandlesResponse* response) override;
  /// The same work as CreateSession / SetHandles, streaming the service's ProgressEvents first.
  grpc::ServerWriteReactor<v1::CreateSessionEvent>* CreateSessionWithProgress(
      grpc::CallbackServerContext* context, const v1::CreateSessionRequest* request) override;
  grpc::ServerWriteReactor<v1::SetHandlesEvent>* SetHandlesWithProgress(
      grpc::CallbackServerContext* context, const v1::SetHandlesRequest* request) override;
  grpc::ServerUnaryReactor* MoveHandles(grpc::CallbackServerContext* context,
                                        const v1::MoveHandlesRequest* request,
                                        v1::MoveHandlesResponse* response) override;
  grpc::ServerWriteReactor<v1::DeformUpdate>* Watch(grpc::CallbackServerContext* context,
                                                    const v1::WatchRequest* request) override;
  grpc::ServerUnaryReactor* GetMesh(grpc::CallbackServerContext* context,
                                    const v1::GetMeshRequest* request,
                                    v1::GetMeshResponse* response) override;
  grpc::ServerUnaryReactor* GetSessionInfo(grpc::CallbackServerContext* context,
                                           const v1::GetSessionInfoRequest* request,
                                           v1::GetSessionInfoResponse* response) override;
  grpc::ServerUnaryReactor* CloseSession(grpc::CallbackServerContext* context,
                                         const v1::CloseSessionRequest* request,
                                         v1::CloseSessionResponse* response) override;
  grpc::ServerUnaryReactor* GetServerStats(grpc::CallbackServerContext* context,
                                           const v1::GetServerStatsRequest* request,
                                           v1::GetServerStatsResponse* response) override;

 private:
  double uptime_seconds() const;
  /// The thread that encodes link-sized Watch updates (started with the first such stream).
  SerialExecutor& encode_executor();

  service::DeformationService& service_;
  ClientIdentityOptions identity_;
  std::chrono::steady_clock::time_point started_ = std::chrono::steady_clock::now();
  std::mutex executor_mutex_;
  std::unique_ptr<SerialExecutor> encode_executor_;
};

}  // namespace meshdeform::transport
