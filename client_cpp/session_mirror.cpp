#include "client_cpp/client.h"

#include <string>
#include <utility>

namespace meshdeform::client {
namespace {

Status invalid(std::string message) {
  return Error(ErrorCode::InvalidArgument, std::move(message));
}

}  // namespace

Status SessionMirror::apply_snapshot(const DeformResult& result) {
  if (!result.positions) {
    return invalid("snapshot of revision " + std::to_string(result.revision) + " has no positions");
  }
  if (has_snapshot_ && result.positions->rows() != positions_.rows()) {
    return invalid("snapshot of revision " + std::to_string(result.revision) + " has " +
                   std::to_string(result.positions->rows()) + " vertices, the mirror " +
                   std::to_string(positions_.rows()));
  }
  positions_ = *result.positions;
  revision_ = result.revision;
  has_snapshot_ = true;
  return Status::success();
}

Status SessionMirror::apply_delta(const DeformResult& result) {
  if (!has_snapshot_) {
    return Error(ErrorCode::FailedPrecondition,
                 "delta for revision " + std::to_string(result.revision) + " before any snapshot");
  }
  if (result.revision != revision_ + 1) {
    return Error(ErrorCode::FailedPrecondition,
                 "delta for revision " + std::to_string(result.revision) +
                     " does not follow the mirrored revision " + std::to_string(revision_));
  }
  if (result.changed_positions.rows() != static_cast<Eigen::Index>(result.changed_indices.size())) {
    return invalid("delta for revision " + std::to_string(result.revision) + " has " +
                   std::to_string(result.changed_indices.size()) + " indices but " +
                   std::to_string(result.changed_positions.rows()) + " positions");
  }
  // Check everything before writing, so a bad delta leaves the mirror unchanged.
  for (const int v : result.changed_indices) {
    if (v < 0 || v >= positions_.rows()) {
      return invalid("delta for revision " + std::to_string(result.revision) + " changes vertex " +
                     std::to_string(v) + " (#V=" + std::to_string(positions_.rows()) + ")");
    }
  }
  for (std::size_t j = 0; j < result.changed_indices.size(); ++j) {
    positions_.row(result.changed_indices[j]) =
        result.changed_positions.row(static_cast<Eigen::Index>(j));
  }
  revision_ = result.revision;
  return Status::success();
}

Status SessionMirror::apply(const WatchUpdate& update) {
  // A link-sized update carries the positions the client reconstructed: all of them.
  return update.is_snapshot || update.delta ? apply_snapshot(update.result)
                                            : apply_delta(update.result);
}

Status SessionMirror::apply(const DeformResult& result) {
  return result.positions ? apply_snapshot(result) : apply_delta(result);
}

}  // namespace meshdeform::client
