#pragma once
/// @file allocator.h
/// Heap settings for programs that run the solvers (the server, the command-line tool, the
/// benchmarks).

namespace meshdeform::core {

/// Keeps freed heap memory in the process for the next allocation instead of handing it back to
/// the kernel. An outer iteration at 10^4-10^5 vertices allocates and frees tens of arrays of
/// 1-10 MB (Eigen temporaries, CHOLMOD's solve results); glibc's defaults give the top of the heap
/// back once twice its adaptive mmap threshold is free, so every iteration faulted those pages in
/// again: a warm 1-iteration solve of Spot 187k on two threads took 510k page faults and
/// 557-589 ms, against 250k and 352-384 ms with these settings (through the server, single-level
/// moves at 187k: solve p50 516-591 -> 406-415 ms); on one thread at 47k the difference is within
/// the noise (per outer iteration) and 5-15% of the precompute. Peak resident memory is the same.
/// Sets glibc's mmap threshold to 32 MiB (larger blocks, e.g. big factors, still go back to the
/// kernel when freed) and its trim threshold to 256 MiB. Call once at the start of main(), before
/// other threads start; no effect with other C libraries.
void keep_freed_heap_for_solver_arrays();

}  // namespace meshdeform::core
