#pragma once
/// @file
/// The vocabulary of an edit, shared by the service (server/service/types.h), the C++ client
/// (client_cpp/client.h) and the wire mapping (proto/wire): handle groups and their roles,
/// similarity moves of a group, explicit vertex targets, undo and redo. One definition, so the
/// two sides cannot drift apart; each side re-exports these names in its own namespace.

#include <optional>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

namespace meshdeform::core {

/// Role of a handle group.
enum class HandleRole {
  Fixed,   ///< stays where it was when the handles were set; cannot be moved
  Handle,  ///< moved by GroupMove / VertexTarget
};

/// A set of constrained vertices with one role.
struct HandleGroup {
  HandleRole role = HandleRole::Handle;
  std::vector<int> vertices;  ///< distinct indices into the session's cleaned mesh, >= 0

  bool operator==(const HandleGroup&) const = default;
};

/// A similarity transform of one handle group, relative to the group's anchor positions (its
/// positions when the handles were set: the rest pose on an undeformed session). Transforms are
/// absolute, not incremental: sending the same move twice gives the same targets.
/// target = pivot + scale * rotation * (anchor - pivot) + translation.
struct GroupMove {
  int group = 0;  ///< index into the groups the handles were set with; must be a Handle group
  Eigen::Vector3d translation = Eigen::Vector3d::Zero();
  Eigen::Quaterniond rotation = Eigen::Quaterniond::Identity();  ///< normalised by the service
  double scale = 1.0;                                             ///< > 0
  std::optional<Eigen::Vector3d> pivot;  ///< default: the centroid of the group's anchors
};

/// An explicit target for one constrained vertex of a Handle group (applied after the moves).
struct VertexTarget {
  int vertex = 0;
  Eigen::Vector3d position = Eigen::Vector3d::Zero();
};

/// How a move changes the session's undo history.
enum class HistoryAction {
  Record,  ///< the move's state becomes the newest step (or replaces it: same gesture)
  Undo,    ///< apply the previous step instead of the request's moves and targets (send none)
  Redo,    ///< apply the next step likewise
};

}  // namespace meshdeform::core
