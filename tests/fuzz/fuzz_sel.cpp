// libFuzzer target: .sel text -> parse_sel (any count and the octahedron's 6) -> format_sel round
// trip -> constraints on the octahedron.
#include <Eigen/Core>
#include <cstddef>
#include <cstdint>
#include <string_view>

#include "core/io/deform_spec.h"
#include "core/samples/samples.h"
#include "tests/fuzz/fuzz_support.h"

using namespace meshdeform;

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string_view text(reinterpret_cast<const char*>(data), size);
  std::uint64_t steps = 0;
  io::ReadControl control;
  control.work_steps = &steps;
  auto any = io::parse_sel(text, -1, control);
  fuzz::check_work_bounded(steps, size);
  if (!any.ok()) {
    fuzz::check_error(any.status());
  } else {
    for (Eigen::Index i = 0; i < any->size(); ++i) {
      fuzz::fuzz_check((*any)(i) >= 0 && (*any)(i) <= 2, "parse_sel accepted a role outside 0..2");
    }
    auto text_again = io::format_sel(*any);
    fuzz::fuzz_check(text_again.ok(), "format_sel refused a parsed selection");
    auto again = io::parse_sel(*text_again, static_cast<int>(any->size()));
    fuzz::fuzz_check(again.ok() && *again == *any, "selection does not round-trip");
  }
  const MeshData mesh = fuzz::octahedron();
  auto sel = io::parse_sel(text, static_cast<int>(mesh.V.rows()));
  if (!sel.ok()) {
    fuzz::check_error(sel.status());
    return 0;
  }
  fuzz::fuzz_check(sel->size() == mesh.V.rows(), "parse_sel ignored the expected count");
  auto setup = core::constraints_from_selection(mesh.V, *sel, Eigen::Matrix4d::Identity());
  if (!setup.ok()) fuzz::check_error(setup.status());
  return 0;
}
