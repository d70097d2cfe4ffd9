// libFuzzer target: validate_triangle_mesh / clean_mesh on arbitrary raw meshes. The bytes are
// decoded into a tiny V/F directly (coordinates on a coarse integer grid so that coincident
// vertices, zero-length edges and degenerate faces are common; signed indices so that
// out-of-range ones are too), which reaches the validator's later rules far more often than going
// through a text parser.
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <limits>

#include "tests/fuzz/fuzz_support.h"

using namespace meshdeform;

namespace {

double coordinate(std::uint8_t byte) {
  switch (byte) {
    case 0xff:
      return std::numeric_limits<double>::quiet_NaN();
    case 0xfe:
      return std::numeric_limits<double>::infinity();
    case 0xfd:
      return 1e-300;
    case 0xfc:
      return 1e300;
    default:
      return static_cast<double>(static_cast<int>(byte % 8) - 3);
  }
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  if (size < 3) return 0;
  const int nv = data[0] % 33;
  const int nf = data[1] % 33;
  const bool weld = (data[2] & 1) != 0;
  std::size_t at = 3;
  auto next = [&]() -> std::uint8_t { return at < size ? data[at++] : 0; };
  MeshData mesh;
  mesh.V.resize(nv, 3);
  mesh.F.resize(nf, 3);
  for (int i = 0; i < nv; ++i) {
    for (int c = 0; c < 3; ++c) mesh.V(i, c) = coordinate(next());
  }
  for (int f = 0; f < nf; ++f) {
    for (int k = 0; k < 3; ++k) mesh.F(f, k) = static_cast<std::int8_t>(next());
  }
  fuzz::check_clean(mesh, weld);
  return 0;
}
