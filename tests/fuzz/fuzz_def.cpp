// libFuzzer target: .def text -> parse_def -> format_def round trip -> constraints on the
// octahedron (vertex 0 fixed, 1 handle).
#include <Eigen/Core>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <string_view>

#include "core/io/deform_spec.h"
#include "core/samples/samples.h"
#include "tests/fuzz/fuzz_support.h"

using namespace meshdeform;

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  std::uint64_t steps = 0;
  io::ReadControl control;
  control.work_steps = &steps;
  auto transform =
      io::parse_def(std::string_view(reinterpret_cast<const char*>(data), size), control);
  fuzz::check_work_bounded(steps, size);
  if (!transform.ok()) {
    fuzz::check_error(transform.status());
    return 0;
  }
  fuzz::fuzz_check(transform->allFinite(), "parse_def accepted a non-finite value");
  auto text = io::format_def(*transform);
  fuzz::fuzz_check(text.ok(), "format_def refused a parsed transform");
  auto again = io::parse_def(*text);
  fuzz::fuzz_check(again.ok() && *again == *transform, "transform does not round-trip");

  const MeshData mesh = fuzz::octahedron();
  Eigen::VectorXi selection = Eigen::VectorXi::Ones(mesh.V.rows());
  selection(0) = 0;
  selection(1) = 2;
  auto setup = core::constraints_from_selection(mesh.V, selection, *transform);
  if (!setup.ok()) {
    fuzz::check_error(setup.status());
    return 0;
  }
  fuzz::fuzz_check(setup->targets.rows() == setup->constrained.size(), "targets/indices mismatch");
  return 0;
}
