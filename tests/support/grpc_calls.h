#pragma once
/// @file grpc_calls.h
/// Header-only helpers for the tests that drive a real meshdeform-server over gRPC (recovery,
/// Redis, nginx, bad input): a bounded deadline for every call, the sample session with its
/// handles set that they start from, and the one "drag" move those tests send.
/// Header-only so that the test support library does not link gRPC (core-only builds use it).

#include <chrono>
#include <memory>
#include <string>

#include <grpcpp/grpcpp.h>

#include "meshdeform/v1/deformation.grpc.pb.h"

namespace meshdeform::test {

/// Every call a test makes ends by this deadline, whatever the server does.
inline void bound(grpc::ClientContext& context,
                  std::chrono::seconds timeout = std::chrono::seconds(30)) {
  context.set_deadline(std::chrono::system_clock::now() + timeout);
}

/// Creates a session from the built-in `sample` and sets its suggested groups as handles.
/// @return OK and the created session; the first failing call's status otherwise.
inline grpc::Status create_sample_with_handles(::meshdeform::v1::DeformationService::Stub& stub,
                                               const std::string& sample,
                                               ::meshdeform::v1::CreateSessionResponse* created) {
  ::meshdeform::v1::CreateSessionRequest create;
  create.set_sample(sample);
  {
    grpc::ClientContext context;
    bound(context);
    if (grpc::Status status = stub.CreateSession(&context, create, created); !status.ok()) {
      return status;
    }
  }
  ::meshdeform::v1::SetHandlesRequest handles;
  handles.set_session_id(created->session_id());
  handles.set_token(created->edit_token());
  *handles.mutable_groups() = created->suggested_groups();
  ::meshdeform::v1::SetHandlesResponse response;
  grpc::ClientContext context;
  bound(context);
  return stub.SetHandles(&context, handles, &response);
}

/// Step `step` of a drag: handle group 1 lifted to z = 0.002 * step, one outer iteration, the
/// full positions in the answer (to compare with what a restarted or other replica serves).
inline ::meshdeform::v1::MoveHandlesRequest lift_move(const std::string& session_id,
                                                      const std::string& edit_token, int step) {
  ::meshdeform::v1::MoveHandlesRequest move;
  move.set_session_id(session_id);
  move.set_token(edit_token);
  move.set_full_positions(true);
  move.set_max_iterations(1);
  ::meshdeform::v1::GroupMove* group = move.add_moves();
  group->set_group(1);
  group->mutable_translation()->set_z(0.002 * step);
  return move;
}

}  // namespace meshdeform::test
