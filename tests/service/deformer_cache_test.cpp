#include "server/service/deformer_cache.h"

#include <gtest/gtest.h>

#include <memory>
#include <stop_token>
#include <vector>

namespace meshdeform::service {
namespace {

/// A deformer that records what it was built for and never solves.
class FakeDeformer final : public core::Deformer {
 public:
  FakeDeformer(core::Method method, Eigen::VectorXi constrained)
      : method_(method), constrained_(std::move(constrained)) {}
  core::Method method() const override { return method_; }
  Result<core::SolveReport> solve(const Positions&, const core::SolveOptions&,
                                  const core::ProgressCallback&, std::stop_token) override {
    return Error(ErrorCode::Internal, "not solved in these tests");
  }
  const Positions& positions() const override { return positions_; }
  const Eigen::VectorXi& constrained() const override { return constrained_; }
  void reset() override {}

 private:
  core::Method method_;
  Eigen::VectorXi constrained_;
  Positions positions_;
};

constexpr std::size_t kBytesPerDeformer = 1000;

/// A cache of `capacity` fake deformers that counts its builds and reserves.
struct Fixture {
  int builds = 0;
  std::vector<std::size_t> reserved;
  Status reserve_answer = Status::success();
  Status build_answer = Status::success();
  std::unique_ptr<DeformerCache> cache;

  explicit Fixture(int capacity) {
    cache = std::make_unique<DeformerCache>(
        capacity, kBytesPerDeformer,
        [this](core::Method method, const Eigen::VectorXi& constrained,
               std::stop_token stop, const core::BuildProgress&) -> Result<std::unique_ptr<core::Deformer>> {
          if (stop.stop_requested()) return Error(ErrorCode::Cancelled, "stopped");
          if (!build_answer.ok()) return build_answer;
          ++builds;
          return std::unique_ptr<core::Deformer>(new FakeDeformer(method, constrained));
        },
        [this](std::size_t bytes) {
          reserved.push_back(bytes);
          return reserve_answer;
        });
  }
};

const std::vector<int> kSetA{0, 1, 2};
const std::vector<int> kSetB{3, 4};
const std::vector<int> kSetC{5};

TEST(DeformerCacheTest, BuildsOncePerMethodAndConstrainedSet) {
  Fixture f(4);
  Result<DeformerCache::Found> first = f.cache->get_or_build(core::Method::ScaleAware, kSetA);
  ASSERT_TRUE(first.ok()) << first.status().to_string();
  EXPECT_TRUE(first->built);
  EXPECT_EQ(first->entry->state_revision, 0u);  // a new deformer sits at the rest pose
  EXPECT_EQ(first->entry->deformer->constrained(), (Eigen::VectorXi(3) << 0, 1, 2).finished());

  Result<DeformerCache::Found> again = f.cache->get_or_build(core::Method::ScaleAware, kSetA);
  ASSERT_TRUE(again.ok());
  EXPECT_FALSE(again->built);
  EXPECT_EQ(again->entry, first->entry);
  EXPECT_EQ(f.builds, 1);

  // Another method or another set is another entry.
  ASSERT_TRUE(f.cache->get_or_build(core::Method::Arap, kSetA).ok());
  ASSERT_TRUE(f.cache->get_or_build(core::Method::ScaleAware, kSetB).ok());
  EXPECT_EQ(f.builds, 3);
  EXPECT_EQ(f.cache->size(), 3);
  EXPECT_EQ(f.cache->bytes(), 3 * kBytesPerDeformer);
  EXPECT_EQ(f.reserved, (std::vector<std::size_t>(3, kBytesPerDeformer)));
}

TEST(DeformerCacheTest, FindNeitherBuildsNorCountsAUse) {
  Fixture f(2);
  EXPECT_EQ(f.cache->find(core::Method::ScaleAware, kSetA), nullptr);
  EXPECT_EQ(f.builds, 0);
  ASSERT_TRUE(f.cache->get_or_build(core::Method::ScaleAware, kSetA).ok());
  ASSERT_TRUE(f.cache->get_or_build(core::Method::ScaleAware, kSetB).ok());
  // A find of A is not a use: A stays the least recently used and goes first.
  ASSERT_NE(f.cache->find(core::Method::ScaleAware, kSetA), nullptr);
  ASSERT_TRUE(f.cache->get_or_build(core::Method::ScaleAware, kSetC).ok());
  EXPECT_EQ(f.cache->find(core::Method::ScaleAware, kSetA), nullptr);
  EXPECT_NE(f.cache->find(core::Method::ScaleAware, kSetB), nullptr);
}

TEST(DeformerCacheTest, FullCacheDropsTheLeastRecentlyUsedBeforeReserving) {
  Fixture f(2);
  ASSERT_TRUE(f.cache->get_or_build(core::Method::ScaleAware, kSetA).ok());
  ASSERT_TRUE(f.cache->get_or_build(core::Method::ScaleAware, kSetB).ok());
  // Use A again: B is now the least recently used.
  DeformerCache::Entry* a = f.cache->find(core::Method::ScaleAware, kSetA);
  ASSERT_NE(a, nullptr);
  f.cache->touch(*a);
  ASSERT_TRUE(f.cache->get_or_build(core::Method::ScaleAware, kSetC).ok());
  EXPECT_EQ(f.cache->size(), 2);
  EXPECT_NE(f.cache->find(core::Method::ScaleAware, kSetA), nullptr);
  EXPECT_EQ(f.cache->find(core::Method::ScaleAware, kSetB), nullptr);
  EXPECT_NE(f.cache->find(core::Method::ScaleAware, kSetC), nullptr);
  EXPECT_EQ(f.builds, 3);
}

TEST(DeformerCacheTest, BudgetSeesTheNetGrowth) {
  // The reserve function sees the cache after the eviction (the store sums sessions' bytes).
  std::unique_ptr<DeformerCache> cache;
  std::vector<int> sizes_at_reserve;
  cache = std::make_unique<DeformerCache>(
      1, kBytesPerDeformer,
      [](core::Method method, const Eigen::VectorXi& constrained,
         std::stop_token, const core::BuildProgress&) -> Result<std::unique_ptr<core::Deformer>> {
        return std::unique_ptr<core::Deformer>(new FakeDeformer(method, constrained));
      },
      [&](std::size_t) {
        sizes_at_reserve.push_back(cache->size());
        return Status::success();
      });
  ASSERT_TRUE(cache->get_or_build(core::Method::ScaleAware, kSetA).ok());
  ASSERT_TRUE(cache->get_or_build(core::Method::ScaleAware, kSetB).ok());
  EXPECT_EQ(sizes_at_reserve, (std::vector<int>{0, 0}));
  EXPECT_EQ(cache->size(), 1);
}

TEST(DeformerCacheTest, RefusedReserveOrFailedBuildAddsNothing) {
  Fixture f(4);
  f.reserve_answer = Error(ErrorCode::ResourceExhausted, "over budget");
  Result<DeformerCache::Found> refused = f.cache->get_or_build(core::Method::ScaleAware, kSetA);
  EXPECT_EQ(refused.status().code(), ErrorCode::ResourceExhausted);
  EXPECT_EQ(f.builds, 0);
  EXPECT_EQ(f.cache->size(), 0);

  f.reserve_answer = Status::success();
  f.build_answer = Error(ErrorCode::NumericalFailure, "factorization failed");
  EXPECT_EQ(f.cache->get_or_build(core::Method::ScaleAware, kSetA).status().code(),
            ErrorCode::NumericalFailure);
  EXPECT_EQ(f.cache->size(), 0);
  EXPECT_EQ(f.cache->bytes(), 0u);
}

TEST(DeformerCacheTest, StopReachesTheBuild) {
  Fixture f(4);
  std::stop_source stop;
  stop.request_stop();
  EXPECT_EQ(f.cache->get_or_build(core::Method::ScaleAware, kSetA, stop.get_token())
                .status()
                .code(),
            ErrorCode::Cancelled);
  EXPECT_EQ(f.cache->size(), 0);
}

TEST(DeformerCacheTest, EvictLruAndCapacityFloor) {
  Fixture f(0);  // clamped to 1
  EXPECT_EQ(f.cache->capacity(), 1);
  f.cache->evict_lru();  // empty: nothing happens
  EXPECT_EQ(f.cache->size(), 0);
  ASSERT_TRUE(f.cache->get_or_build(core::Method::ScaleAware, kSetA).ok());
  ASSERT_TRUE(f.cache->get_or_build(core::Method::Laplacian, kSetA).ok());
  EXPECT_EQ(f.cache->size(), 1);
  EXPECT_NE(f.cache->find(core::Method::Laplacian, kSetA), nullptr);
  f.cache->evict_lru();
  EXPECT_EQ(f.cache->size(), 0);
  EXPECT_EQ(f.cache->bytes(), 0u);
}

}  // namespace
}  // namespace meshdeform::service
