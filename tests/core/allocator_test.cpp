#include "core/base/allocator.h"

#include <gtest/gtest.h>

#include <sys/resource.h>

#include <cstdlib>
#include <cstring>
#include <vector>

namespace meshdeform::core {
namespace {

long minor_faults() {
  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  return usage.ru_minflt;
}

// What an outer iteration does to the heap: a few multi-megabyte arrays written, then freed.
// Returns the page faults of the last of `rounds` rounds.
long faults_of_last_round(int rounds) {
  constexpr std::size_t kBytes = 8u << 20;
  long last = 0;
  for (int round = 0; round < rounds; ++round) {
    const long before = minor_faults();
    std::vector<void*> blocks;
    for (int b = 0; b < 4; ++b) {
      void* block = std::malloc(kBytes);
      EXPECT_NE(block, nullptr);
      std::memset(block, round + b, kBytes);  // touch every page
      blocks.push_back(block);
    }
    for (void* block : blocks) std::free(block);
    last = minor_faults() - before;
  }
  return last;
}

// AddressSanitizer brings its own allocator, which glibc's settings do not reach.
#if defined(__SANITIZE_ADDRESS__)
constexpr bool kSanitizerAllocator = true;
#elif defined(__has_feature)
#if __has_feature(address_sanitizer)
constexpr bool kSanitizerAllocator = true;
#else
constexpr bool kSanitizerAllocator = false;
#endif
#else
constexpr bool kSanitizerAllocator = false;
#endif

TEST(Allocator, FreedSolverArraysAreReusedWithoutPageFaults) {
  if (kSanitizerAllocator) GTEST_SKIP() << "the sanitizer's allocator replaces glibc's malloc";
#if defined(__GLIBC__)
  keep_freed_heap_for_solver_arrays();
  // 32 MiB written per round (8192 pages of 4 KiB): once the heap holds them, a round reuses
  // them. With glibc's defaults the freed top of the heap goes back to the kernel every round
  // and every page faults again (measured: about 8200 faults per round).
  EXPECT_LT(faults_of_last_round(4), 500);
#else
  GTEST_SKIP() << "the settings are glibc's";
#endif
}

}  // namespace
}  // namespace meshdeform::core
