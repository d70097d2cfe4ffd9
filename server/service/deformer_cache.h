#pragma once
/// @file deformer_cache.h
/// A session's prefactored deformers, one per (method, constrained set), least recently used
/// dropped first. Building one is the costly part of an edit (sparse Cholesky factorizations);
/// solving with a cached one only changes targets.

#include <atomic>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <list>
#include <memory>
#include <stop_token>
#include <vector>

#include <Eigen/Core>

#include "core/methods/deformer.h"
#include "core/base/status.h"

namespace meshdeform::service {

/// The cached deformers of one session. find / get_or_build / evict_lru run on the session's
/// strand only; size() and bytes() may be read from any thread (the store's budget).
class DeformerCache {
 public:
  /// One prefactored deformer and what it was built for.
  struct Entry {
    core::Method method = core::Method::ScaleAware;
    std::vector<int> constrained;  ///< ascending
    std::unique_ptr<core::Deformer> deformer;
    std::uint64_t state_revision = 0;  ///< the session revision the deformer's positions() equal
    std::uint64_t last_used = 0;       ///< the cache's use counter at the last use
  };
  /// What get_or_build found.
  struct Found {
    Entry* entry = nullptr;  ///< stays valid until the entry is evicted
    bool built = false;      ///< true when this call built it
  };

  /// Builds the deformer of `method` for the constrained vertices (core::make_deformer).
  using BuildFn = std::function<Result<std::unique_ptr<core::Deformer>>(
      core::Method method, const Eigen::VectorXi& constrained, std::stop_token stop,
      const core::BuildProgress& progress)>;
  /// Asks for `bytes` more memory budget before a build; an error refuses the build.
  using ReserveFn = std::function<Status(std::size_t bytes)>;

  DeformerCache() = default;
  /// @param[in] capacity            most entries held (at least 1).
  /// @param[in] bytes_per_deformer  what bytes() charges per entry (estimate_session_bytes).
  /// @param[in] build               builds a missing entry.
  /// @param[in] reserve             asked before every build; empty: always granted.
  DeformerCache(int capacity, std::size_t bytes_per_deformer, BuildFn build,
                ReserveFn reserve = {});
  DeformerCache(const DeformerCache&) = delete;
  DeformerCache& operator=(const DeformerCache&) = delete;
  DeformerCache(DeformerCache&&) = delete;
  DeformerCache& operator=(DeformerCache&&) = delete;

  /// The entry of (method, constrained), without counting a use; nullptr when none is cached.
  [[nodiscard]] Entry* find(core::Method method, const std::vector<int>& constrained);
  /// Counts a use of `entry` (it becomes the most recently used).
  void touch(Entry& entry);
  /// The entry of (method, constrained), counting a use; built when missing. When the cache is
  /// full the least recently used entry is dropped first, so that the budget sees the net
  /// growth. A new deformer sits at the rest pose (state_revision 0).
  /// @return the entry; the reserve function's error (e.g. ResourceExhausted) or the build's
  ///         (InvalidArgument, NumericalFailure, Cancelled when `stop` is requested), and then
  ///         nothing is added (an entry dropped to make room stays dropped).
  /// @param[in] progress  handed to the build (its phases); not called when the entry is cached.
  [[nodiscard]] Result<Found> get_or_build(core::Method method, const std::vector<int>& constrained,
                                           std::stop_token stop = {},
                                           const core::BuildProgress& progress = {});
  /// Drops the least recently used entry (none when empty).
  void evict_lru();

  /// Entries held (any thread).
  int size() const { return size_.load(); }
  /// What the entries are charged (any thread): size() * bytes_per_deformer.
  std::size_t bytes() const { return static_cast<std::size_t>(size()) * bytes_per_deformer_; }
  int capacity() const { return capacity_; }

 private:
  int capacity_ = 1;
  std::size_t bytes_per_deformer_ = 0;
  BuildFn build_;
  ReserveFn reserve_;
  std::list<Entry> entries_;  ///< a list: entries keep their address while others come and go
  std::uint64_t tick_ = 0;
  std::atomic<int> size_{0};
};

}  // namespace meshdeform::service
