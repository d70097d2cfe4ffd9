#pragma once
/// @file shared_store.h
/// Session state shared by stateless replicas (issue 16): one store that every replica reads and
/// writes, so any replica can serve any session. The service layer talks to it through this
/// interface; redis_store.h implements it on Redis.
///
/// Model: a session's stored state has a *version*, a counter of its writes (every committed
/// revision and every handle change adds one). A write is a compare-and-set on the version and
/// is only accepted from the replica holding the session's *lease* (a short-lived exclusive
/// right to edit, taken before an edit and given back when the replica's edit queue runs dry).
/// Every accepted write is also appended to the session's *log* (version order), which replicas
/// replay to catch their cached copy up and to feed their watchers.

#include <chrono>
#include <cstdint>
#include <memory>
#include <optional>
#include <stop_token>
#include <vector>

#include "core/base/status.h"
#include "server/service/persistence.h"
#include "server/service/types.h"

namespace meshdeform::service {

/// One accepted write as the log holds it.
struct SharedLogEntry {
  std::uint64_t version = 0;   ///< the version this write produced (the first write is 1)
  std::uint64_t revision = 0;  ///< the session's revision after the write
  /// The committed revision (full positions and the solve's figures; the changed lists are left
  /// empty: a reader derives them from its previous revision). Null for a handle change, which a
  /// reader replays by loading the whole state.
  std::shared_ptr<const DeformResult> result;
  Positions targets;  ///< #C x 3 handle targets after the write (with `result` only)
  /// The edit settings and history after the write (with `result` only); unset: unchanged
  /// (background refinement).
  std::optional<EditState> edit;
};

/// A session's stored state and its version.
struct SharedState {
  PersistedSession state;
  std::uint64_t version = 0;
};

/// The store replicas share. Thread-safe; every call may block on the network for at most the
/// implementation's I/O timeout. Store failures are reported as Internal naming the cause;
/// nothing is written then.
class SharedStateStore {
 public:
  virtual ~SharedStateStore() = default;

  /// Stores a new session at version 0.
  /// @return success; Aborted when the id exists; Internal when the store fails.
  [[nodiscard]] virtual Status create(const PersistedSession& state) = 0;
  /// @return the state with its version; NotFound when the session is not stored (never
  ///         created, closed, or expired); InvalidArgument when the stored bytes are corrupt.
  [[nodiscard]] virtual Result<SharedState> load(const SessionId& id) = 0;
  /// @return the version now; nullopt when the session is not stored.
  [[nodiscard]] virtual Result<std::optional<std::uint64_t>> version(const SessionId& id) = 0;
  /// Log entries with a version above `after`, oldest first, at most `max`. The log keeps only
  /// the newest entries: a first entry above after + 1 means the ones between were trimmed (the
  /// reader then loads the whole state).
  [[nodiscard]] virtual Result<std::vector<SharedLogEntry>> read_log(const SessionId& id,
                                                                     std::uint64_t after,
                                                                     int max) = 0;
  /// Takes the session's lease for this replica, or renews it when this replica holds it; while
  /// another replica holds it, retries until `wait` has passed or `stop` is requested.
  /// @return success; Aborted naming when the other replica's lease ends.
  [[nodiscard]] virtual Status acquire_lease(const SessionId& id, std::chrono::milliseconds wait,
                                             std::stop_token stop = {}) = 0;
  /// Gives the lease back if this replica holds it (errors are only logged).
  virtual void release_lease(const SessionId& id) = 0;
  /// Writes `state` as version base_version + 1 (its changing part: the rest mesh, the tokens and
  /// lambda are the ones stored at create and may be left empty here) and appends `entry` (whose version and revision
  /// are filled in here) to the log, atomically, if and only if the stored version is still
  /// `base_version` and this replica holds the lease.
  /// @return success; Aborted naming the stored revision when another write won or the lease
  ///         was lost; NotFound when the session is no longer stored; Internal when the store
  ///         fails (then it is not known whether the write was applied: the caller must treat the
  ///         edit as failed and resynchronise).
  [[nodiscard]] virtual Status commit(const PersistedSession& state, std::uint64_t base_version,
                                      SharedLogEntry entry) = 0;
  /// Deletes the session's state, log and lease (errors are only logged).
  virtual void remove(const SessionId& id) = 0;
  /// How long a replica waits for another's lease before an edit fails with Aborted.
  virtual std::chrono::milliseconds lease_wait() const = 0;
};

}  // namespace meshdeform::service
