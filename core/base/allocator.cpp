#include "core/base/allocator.h"

#include <cstdlib>  // defines __GLIBC__ with glibc (tested below)

#if defined(__GLIBC__)
#include <malloc.h>
#endif

namespace meshdeform::core {

void keep_freed_heap_for_solver_arrays() {
#if defined(__GLIBC__)
  // Setting either threshold turns off glibc's adaptation of both, so both are set.
  mallopt(M_MMAP_THRESHOLD, 32 << 20);
  mallopt(M_TRIM_THRESHOLD, 256 << 20);
#endif
}

}  // namespace meshdeform::core
