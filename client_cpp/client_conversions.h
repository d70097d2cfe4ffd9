#pragma once
/// @file client_conversions.h
/// Internal to meshdeform::client (not installed, not included by client.h): meshdeform.v1
/// messages <-> the client's types, and gRPC statuses -> Status. The value and enum maps are
/// meshdeform::wire's (proto/wire/wire_mapping.h, shared with the server); this file words the
/// client's errors: a bad request names what the caller gave, a bad response reads
/// "<Rpc>: malformed response: ...".

#include <grpcpp/support/status.h>

#include <cstdint>
#include <map>
#include <string>
#include <vector>

#include "client_cpp/client.h"
#include "core/base/status.h"
#include "meshdeform/v1/deformation.pb.h"

namespace meshdeform::client::detail {

namespace v1 = ::meshdeform::v1;

/// InvalidArgument with `message`.
Status invalid(std::string message);

/// A response the server should never send (a protocol mismatch): InvalidArgument
/// "<rpc>: malformed response: <what>".
Status malformed(const char* rpc, const std::string& what);

/// success for OK; otherwise to_error_code's code and "<rpc>: <GRPC_CODE>: <server message>".
Status from_grpc(const char* rpc, const grpc::Status& status);

/// @return success; InvalidArgument naming the group of a negative vertex index.
Status groups_to_proto(const std::vector<HandleGroup>& groups,
                       google::protobuf::RepeatedPtrField<v1::HandleGroup>* out);

/// @return success; InvalidArgument for a negative group or vertex index or max_iterations.
Status move_to_proto(const MoveSpec& spec, v1::MoveHandlesRequest* out);

/// The coarse levels of one Watch stream with coarse_preview (v1::CoarseLevel): the server sends
/// a level's mesh (triangles, to_fine) with the level's first update on the stream and only its
/// positions after that; decode() fills the mesh in on every update.
class CoarseLevelDecoder {
 public:
  /// @return the level with its mesh (remembered when the update carries it); malformed("Watch")
  ///         for positions that are not 12 bytes per vertex, a mesh whose to_fine does not match
  ///         the vertex count or whose triangle index is out of range, or a key whose mesh never
  ///         came on this stream.
  Result<CoarseLevel> decode(const v1::CoarseLevel& in);

 private:
  struct Mesh {
    Triangles triangles;
    std::vector<int> to_fine;
  };
  std::map<std::uint64_t, Mesh> meshes_;  ///< by key (a new handle set makes a new level)
};

/// The responses of `rpc`; malformed() for an unknown enum value, an index above INT_MAX or
/// position lists that do not match.
Result<SessionInfo> info_from_proto(const v1::SessionInfo& in, const char* rpc);
Result<Session> session_from_proto(const v1::CreateSessionResponse& in);
Result<DeformResult> result_from_proto(const v1::DeformResult& in, const char* rpc);
Result<WatchUpdate> update_from_proto(const v1::DeformUpdate& in);
ServerStats stats_from_proto(const v1::GetServerStatsResponse& in);

}  // namespace meshdeform::client::detail
