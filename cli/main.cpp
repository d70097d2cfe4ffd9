// meshdeform-cli entry point: no logic here beyond turning escaped exceptions into exit codes,
// so that bad input can never crash the tool.
#include <cstdio>
#include <exception>
#include <new>
#include <string>
#include <vector>

#include "cli/commands.h"
#include "core/base/allocator.h"

int main(int argc, char** argv) {
  meshdeform::core::keep_freed_heap_for_solver_arrays();
  try {
    std::vector<std::string> args(argv + 1, argv + argc);
    return meshdeform::cli::run_cli(args);
  } catch (const std::bad_alloc&) {
    std::fprintf(stderr, "meshdeform-cli: error: ResourceExhausted: out of memory\n");
  } catch (const std::exception& e) {
    std::fprintf(stderr, "meshdeform-cli: error: Internal: %s\n", e.what());
  } catch (...) {
    std::fprintf(stderr, "meshdeform-cli: error: Internal: unknown exception\n");
  }
  return meshdeform::cli::kExitRuntimeError;
}
