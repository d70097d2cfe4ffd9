#include "server/service/deformer_cache.h"

#include <algorithm>
#include <utility>

namespace meshdeform::service {

DeformerCache::DeformerCache(int capacity, std::size_t bytes_per_deformer, BuildFn build,
                             ReserveFn reserve)
    : capacity_(std::max(1, capacity)),
      bytes_per_deformer_(bytes_per_deformer),
      build_(std::move(build)),
      reserve_(std::move(reserve)) {}

DeformerCache::Entry* DeformerCache::find(core::Method method,
                                          const std::vector<int>& constrained) {
  for (Entry& entry : entries_) {
    if (entry.method == method && entry.constrained == constrained) return &entry;
  }
  return nullptr;
}

void DeformerCache::touch(Entry& entry) { entry.last_used = ++tick_; }

Result<DeformerCache::Found> DeformerCache::get_or_build(core::Method method,
                                                         const std::vector<int>& constrained,
                                                         std::stop_token stop,
                                                         const core::BuildProgress& progress) {
  if (Entry* cached = find(method, constrained)) {
    touch(*cached);
    return Found{cached, false};
  }
  if (size() >= capacity_) evict_lru();
  if (reserve_) MD_RETURN_IF_ERROR(reserve_(bytes_per_deformer_));
  const Eigen::VectorXi idx = Eigen::Map<const Eigen::VectorXi>(
      constrained.data(), static_cast<Eigen::Index>(constrained.size()));
  MD_ASSIGN_OR_RETURN(std::unique_ptr<core::Deformer> deformer,
                      build_(method, idx, std::move(stop), progress));
  entries_.push_back(Entry{method, constrained, std::move(deformer), 0, ++tick_});
  size_.store(static_cast<int>(entries_.size()));
  return Found{&entries_.back(), true};
}

void DeformerCache::evict_lru() {
  if (entries_.empty()) return;
  const auto oldest = std::min_element(
      entries_.begin(), entries_.end(),
      [](const Entry& a, const Entry& b) { return a.last_used < b.last_used; });
  entries_.erase(oldest);
  size_.store(static_cast<int>(entries_.size()));
}

}  // namespace meshdeform::service
