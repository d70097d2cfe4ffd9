#pragma once
/// @file fuzz_support.h
/// Shared checks of the libFuzzer targets in tests/fuzz/: what must hold for ANY input.
///
/// Beyond "no crash, no sanitizer report" (ASan + UBSan + libFuzzer), every target checks the
/// documented contract: errors carry a message, a successful read has well-formed shapes, a mesh
/// that clean_mesh accepts is valid, and what a writer/formatter produces reads back to the same
/// value. A broken property aborts through fuzz_check, so libFuzzer reports it like a crash.

#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string_view>

#include "core/io/mesh_io.h"
#include "core/mesh/mesh_data.h"
#include "core/base/status.h"
#include "core/mesh/validate.h"

namespace meshdeform::fuzz {

/// Aborts with a message when a property of the parsers does not hold.
inline void fuzz_check(bool condition, const char* what) {
  if (!condition) {
    std::fprintf(stderr, "fuzz property violated: %s\n", what);
    std::abort();
  }
}

/// Work allowed per input byte by the io rule "work bounded by bytes" (core/io/mesh_io.h): a
/// reader that loops over a declared count its bytes do not back exceeds it on some input.
inline constexpr std::uint64_t kStepsPerByte = 4;
inline constexpr std::uint64_t kStepsConstant = 64;

/// The work a reader did must be bounded by its input (what the hostile-input tests check on
/// crafted headers, here on every input the fuzzer makes).
inline void check_work_bounded(std::uint64_t steps, std::size_t bytes) {
  fuzz_check(steps <= kStepsPerByte * bytes + kStepsConstant,
             "reader work not bounded by its input size");
}

/// Bitwise equality of two meshes (NaN coordinates compare equal to themselves).
inline bool same_mesh(const MeshData& a, const MeshData& b) {
  return a.V.rows() == b.V.rows() && a.F.rows() == b.F.rows() && a.F == b.F &&
         (a.V.size() == 0 ||
          std::memcmp(a.V.data(), b.V.data(),
                      sizeof(double) * static_cast<std::size_t>(a.V.size())) == 0);
}

/// An error must be a real error with a message naming the problem.
inline void check_error(const Status& status) {
  fuzz_check(!status.ok(), "error status is ok");
  fuzz_check(!status.message().empty(), "error without a message");
}

/// A small closed mesh (octahedron, 6 vertices, 8 faces) that edit specs are resolved against.
inline MeshData octahedron() {
  MeshData mesh;
  mesh.V.resize(6, 3);
  mesh.V << 1, 0, 0, -1, 0, 0, 0, 1, 0, 0, -1, 0, 0, 0, 1, 0, 0, -1;
  mesh.F.resize(8, 3);
  mesh.F << 0, 2, 4, 2, 1, 4, 1, 3, 4, 3, 0, 4, 2, 0, 5, 1, 2, 5, 3, 1, 5, 0, 3, 5;
  return mesh;
}

/// Validation and cleaning of an arbitrary (raw) mesh: clean_mesh either fails with a message
/// and leaves the mesh untouched, or returns a mesh that validates and a consistent report.
inline void check_clean(const MeshData& raw, bool weld) {
  MeshData mesh = raw;
  const Status valid = core::validate_triangle_mesh(raw.V, raw.F);
  if (!valid.ok()) check_error(valid);
  auto report = core::clean_mesh(mesh, weld);
  if (!report.ok()) {
    check_error(report.status());
    fuzz_check(same_mesh(mesh, raw), "failed clean_mesh modified the mesh");
    return;
  }
  fuzz_check(core::validate_triangle_mesh(mesh.V, mesh.F).ok(), "cleaned mesh does not validate");
  fuzz_check(report->old_to_new.size() == raw.V.rows(), "old_to_new has the wrong length");
  fuzz_check(mesh.F.rows() == raw.F.rows(), "clean_mesh changed the face count");
  for (Eigen::Index i = 0; i < report->old_to_new.size(); ++i) {
    const int j = report->old_to_new(i);
    fuzz_check(j >= -1 && j < mesh.V.rows(), "old_to_new out of range");
    if (j >= 0) fuzz_check(mesh.V.row(j) == raw.V.row(i), "cleaning moved a vertex");
  }
  if (valid.ok() && !weld) fuzz_check(same_mesh(mesh, raw), "clean_mesh changed a valid mesh");
}

/// The whole path of a mesh from request bytes: read, then validate and clean (with and without
/// welding); a mesh that cleans is written back in the same format and must read back equal
/// (exactly for the double formats, OBJ/OFF/PLY; same shape for float32 STL/glTF).
inline void check_mesh_bytes(std::string_view bytes, io::MeshFormat format) {
  std::uint64_t steps = 0;
  io::ReadControl control;
  control.work_steps = &steps;
  auto raw = io::read_mesh_from_memory(bytes, format, control);
  check_work_bounded(steps, bytes.size());
  if (!raw.ok()) {
    check_error(raw.status());
    return;
  }
  fuzz_check(raw->V.rows() > 0 && raw->F.rows() > 0, "reader returned an empty mesh");
  check_clean(*raw, /*weld=*/false);
  check_clean(*raw, /*weld=*/true);

  MeshData mesh = *raw;
  if (!core::clean_mesh(mesh, /*weld=*/false).ok()) return;
  auto written = io::write_mesh_to_memory(mesh, format);
  if (!written.ok()) {
    // Only float32 formats may refuse a valid mesh (a coordinate outside float range).
    fuzz_check(format == io::MeshFormat::Stl || format == io::MeshFormat::Glb ||
                   format == io::MeshFormat::Gltf,
               "writer refused a valid mesh in a double format");
    check_error(written.status());
    return;
  }
  auto again = io::read_mesh_from_memory(*written, format);
  fuzz_check(again.ok(), "written mesh does not read back");
  if (format == io::MeshFormat::Stl) return;  // soup: vertices are repeated per face
  fuzz_check(again->V.rows() == mesh.V.rows() && again->F == mesh.F,
             "written mesh reads back with other shape or faces");
  if (format == io::MeshFormat::Obj || format == io::MeshFormat::Off ||
      format == io::MeshFormat::Ply) {
    fuzz_check(again->V == mesh.V, "double coordinates changed in a round trip");
  }
}

}  // namespace meshdeform::fuzz
