// libFuzzer target: JSON edit spec -> parse_edit_spec -> format_edit_spec round trip ->
// resolve_edit against the octahedron.
#include <cstddef>
#include <cstdint>
#include <string_view>

#include "core/io/deform_spec.h"
#include "tests/fuzz/fuzz_support.h"

using namespace meshdeform;

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  std::uint64_t steps = 0;
  io::ReadControl control;
  control.work_steps = &steps;
  auto spec =
      io::parse_edit_spec(std::string_view(reinterpret_cast<const char*>(data), size), control);
  fuzz::check_work_bounded(steps, size);
  if (!spec.ok()) {
    fuzz::check_error(spec.status());
    return 0;
  }
  auto text = io::format_edit_spec(*spec);
  fuzz::fuzz_check(text.ok(), "format_edit_spec refused a parsed spec");
  auto again = io::parse_edit_spec(*text);
  fuzz::fuzz_check(again.ok(), "formatted spec does not parse");
  fuzz::fuzz_check(again->handles.size() == spec->handles.size() && again->fixed == spec->fixed &&
                       again->magnify.size() == spec->magnify.size(),
                   "spec does not round-trip");

  const MeshData mesh = fuzz::octahedron();
  auto setup = io::resolve_edit(*spec, mesh.V);
  if (!setup.ok()) {
    fuzz::check_error(setup.status());
    return 0;
  }
  fuzz::fuzz_check(setup->constrained.size() > 0, "resolve_edit returned no constraint");
  fuzz::fuzz_check(setup->targets.rows() == setup->constrained.size(), "targets/indices mismatch");
  fuzz::fuzz_check(setup->targets.allFinite(), "resolve_edit produced a non-finite target");
  for (Eigen::Index i = 0; i < setup->constrained.size(); ++i) {
    const int v = setup->constrained(i);
    fuzz::fuzz_check(v >= 0 && v < mesh.V.rows(), "constrained index out of range");
    if (i > 0) fuzz::fuzz_check(setup->constrained(i - 1) < v, "constrained not ascending/unique");
  }
  return 0;
}
