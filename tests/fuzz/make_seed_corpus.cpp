// Writes the seed corpus of the fuzz targets: a few small valid and invalid inputs per target,
// the meshes through the project's own writers. Run once from the fuzz build and commit the
// output (tests/fuzz/corpus/<target>/); the fuzzers never write into that directory.
//
//   build-fuzz/tests/fuzz/meshdeform_fuzz_seeds tests/fuzz/corpus
#include <Eigen/Core>
#include <algorithm>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "core/io/mesh_io.h"
#include "core/mesh/mesh_data.h"

using namespace meshdeform;
namespace fs = std::filesystem;

namespace {

MeshData tetrahedron() {
  MeshData mesh;
  mesh.V.resize(4, 3);
  mesh.V << 0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 1;
  mesh.F.resize(4, 3);
  mesh.F << 0, 2, 1, 0, 1, 3, 0, 3, 2, 1, 2, 3;
  return mesh;
}

MeshData octahedron() {
  MeshData mesh;
  mesh.V.resize(6, 3);
  mesh.V << 1, 0, 0, -1, 0, 0, 0, 1, 0, 0, -1, 0, 0, 0, 1, 0, 0, -1;
  mesh.F.resize(8, 3);
  mesh.F << 0, 2, 4, 2, 1, 4, 1, 3, 4, 3, 0, 4, 2, 0, 5, 1, 2, 5, 3, 1, 5, 0, 3, 5;
  return mesh;
}

bool failed = false;

void put(const fs::path& dir, const std::string& name, const std::string& bytes) {
  fs::create_directories(dir);
  if (bytes.size() >= 4096) {
    std::fprintf(stderr, "seed %s is %zu bytes (limit 4 KiB)\n", name.c_str(), bytes.size());
    failed = true;
  }
  std::ofstream out(dir / name, std::ios::binary);
  out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
}

std::string written(const MeshData& mesh, io::MeshFormat format) {
  auto bytes = io::write_mesh_to_memory(mesh, format);
  if (!bytes.ok()) {
    std::fprintf(stderr, "writer failed: %s\n", bytes.status().to_string().c_str());
    failed = true;
    return {};
  }
  return *bytes;
}

template <typename T>
void append_raw(std::string& out, T value, bool big_endian = false) {
  char bytes[sizeof(T)];
  std::memcpy(bytes, &value, sizeof(T));
  if (big_endian) std::reverse(bytes, bytes + sizeof(T));
  out.append(bytes, sizeof(T));
}

// Binary PLY of the tetrahedron: float vertices, uchar/int face lists.
std::string binary_ply(bool big_endian) {
  const MeshData mesh = tetrahedron();
  std::string out = std::string("ply\nformat ") +
                    (big_endian ? "binary_big_endian" : "binary_little_endian") +
                    " 1.0\ncomment seed\nelement vertex 4\nproperty float x\nproperty float y\n"
                    "property float z\nelement face 4\nproperty list uchar int vertex_indices\n"
                    "end_header\n";
  for (int i = 0; i < 4; ++i) {
    for (int c = 0; c < 3; ++c) append_raw(out, static_cast<float>(mesh.V(i, c)), big_endian);
  }
  for (int f = 0; f < 4; ++f) {
    out.push_back(3);
    for (int k = 0; k < 3; ++k)
      append_raw(out, static_cast<std::int32_t>(mesh.F(f, k)), big_endian);
  }
  return out;
}

}  // namespace

int main(int argc, char** argv) {
  if (argc != 2) {
    std::fprintf(stderr, "usage: %s <corpus dir>\n", argv[0]);
    return 2;
  }
  const fs::path root = argv[1];
  const MeshData tet = tetrahedron();
  const MeshData oct = octahedron();

  // OBJ
  const fs::path obj = root / "fuzz_mesh_obj";
  put(obj, "tetrahedron.obj", written(tet, io::MeshFormat::Obj));
  put(obj, "cube_quads.obj",
      "# unit cube, quads (fan-triangulated), v/vt/vn references, mtllib ignored\n"
      "mtllib cube.mtl\no cube\n"
      "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 0 1\nv 1 0 1\nv 1 1 1\nv 0 1 1\n"
      "vt 0 0\nvn 0 0 1\ns off\n"
      "f 1/1/1 4/1/1 3/1/1 2/1/1\nf 5 6 7 8\nf 1//1 2//1 6//1 5//1\nf 2 3 7 6\nf 3 4 8 7\n"
      "f 4 1 5 8\n");
  put(obj, "relative_indices.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf -3 -2 -1\n");
  put(obj, "bad_index.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n");
  put(obj, "bad_number.obj", "v 0 0 nope\nv 1e999 0 0\nf 1 2 3\n");
  put(obj, "nonmanifold.obj",
      "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 -1 0\nv 0 0 1\nf 1 2 3\nf 2 1 4\nf 1 2 5\n");

  // OFF
  const fs::path off = root / "fuzz_mesh_off";
  put(off, "tetrahedron.off", written(tet, io::MeshFormat::Off));
  put(off, "octahedron.off", written(oct, io::MeshFormat::Off));
  put(off, "coff_quad.off",
      "COFF\n# colour per vertex\n4 1 0\n0 0 0 255 0 0 255\n1 0 0 0 255 0 255\n"
      "1 1 0 0 0 255 255\n0 1 0 9 9 9 255\n4 0 1 2 3\n");
  put(off, "counts_on_next_line.off", "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n");
  put(off, "huge_counts.off", "OFF\n2000000000 2000000000 0\n0 0 0\n");
  put(off, "truncated.off", "OFF\n4 4 6\n0 0 0\n1 0 0\n");

  // PLY
  const fs::path ply = root / "fuzz_mesh_ply";
  put(ply, "tetrahedron_ascii.ply", written(tet, io::MeshFormat::Ply));
  put(ply, "tetrahedron_le.ply", binary_ply(false));
  put(ply, "tetrahedron_be.ply", binary_ply(true));
  put(ply, "extra_properties.ply",
      "ply\nformat ascii 1.0\nelement vertex 3\nproperty double x\nproperty double y\n"
      "property double z\nproperty uchar red\nelement face 1\n"
      "property list uint8 uint32 vertex_indices\nproperty float quality\nelement edge 0\n"
      "property int vertex1\nend_header\n0 0 0 1\n1 0 0 2\n0 1 0 3\n3 0 1 2 0.5\n");
  put(ply, "truncated_binary.ply", binary_ply(false).substr(0, 200));
  put(ply, "bad_header.ply", "ply\nformat ascii 1.0\nelement vertex -1\nend_header\n");

  // STL
  const fs::path stl = root / "fuzz_mesh_stl";
  put(stl, "tetrahedron_binary.stl", written(tet, io::MeshFormat::Stl));
  put(stl, "triangle_ascii.stl",
      "solid seed\n facet normal 0 0 1\n  outer loop\n   vertex 0 0 0\n   vertex 1 0 0\n"
      "   vertex 0 1 0\n  endloop\n endfacet\n facet normal 0 0 -1\n  outer loop\n"
      "   vertex 0 0 0\n   vertex 0 1 0\n   vertex 1 0 0\n  endloop\n endfacet\nendsolid seed\n");
  {
    std::string lying = written(tet, io::MeshFormat::Stl);
    lying.replace(0, 5, "solid");  // binary data whose header starts like ASCII STL
    put(stl, "binary_starting_with_solid.stl", lying);
    put(stl, "truncated_binary.stl", written(tet, io::MeshFormat::Stl).substr(0, 120));
  }
  put(stl, "ascii_missing_vertex.stl",
      "solid x\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\nendloop\nendfacet\n"
      "endsolid x\n");

  // GLB and glTF
  const fs::path glb = root / "fuzz_mesh_glb";
  put(glb, "tetrahedron.glb", written(tet, io::MeshFormat::Glb));
  put(glb, "octahedron.glb", written(oct, io::MeshFormat::Glb));
  put(glb, "truncated.glb", written(tet, io::MeshFormat::Glb).substr(0, 60));
  const fs::path gltf = root / "fuzz_mesh_gltf";
  put(gltf, "tetrahedron.gltf", written(tet, io::MeshFormat::Gltf));
  put(gltf, "external_buffer.gltf",
      R"({"asset":{"version":"2.0"},"buffers":[{"uri":"/etc/passwd","byteLength":48}],)"
      R"("bufferViews":[{"buffer":0,"byteLength":48}],"accessors":[{"bufferView":0,)"
      R"("componentType":5126,"count":4,"type":"VEC3"}],"meshes":[{"primitives":[{"attributes":)"
      R"({"POSITION":0}}]}],"nodes":[{"mesh":0}],"scenes":[{"nodes":[0]}]})");
  put(gltf, "bad_accessor.gltf",
      R"({"asset":{"version":"2.0"},"buffers":[{"uri":"data:application/octet-stream;base64,)"
      R"(AAAAAAAAAAAAAAAAAACAPwAAAAAAAAAAAAAAAAAAgD8AAAAA","byteLength":36}],)"
      R"("bufferViews":[{"buffer":0,"byteLength":36}],"accessors":[{"bufferView":0,)"
      R"("byteOffset":24,"componentType":5126,"count":3,"type":"VEC3"}],"meshes":[{"primitives":)"
      R"([{"attributes":{"POSITION":0},"mode":4}]}]})");
  put(gltf, "not_json.gltf", "{\"asset\": {\"version\": \"2.0\"");

  // .sel / .def
  const fs::path sel = root / "fuzz_sel";
  put(sel, "octahedron.sel", "# 0 fixed, 1 free, 2 handle\n0\n0\n1\n1\n2\n2\n");
  put(sel, "one_line.sel", "0 1 2 1 0 2");
  put(sel, "bad_value.sel", "0\n1\n3\n1\n0\n2\n");
  put(sel, "wrong_count.sel", "#\n0\n1\n");
  const fs::path def = root / "fuzz_def";
  put(def, "identity.def", "# handle transform\n1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n");
  put(def, "rotate_translate.def", "0 -1 0 0.5\n1 0 0 0\n0 0 1 0.25\n0 0 0 1\n");
  put(def, "fifteen.def", "1 0 0 0 0 1 0 0 0 0 1 0 0 0 0\n");
  put(def, "nan.def", "1 0 0 nan\n0 1 0 0\n0 0 1 0\n0 0 0 1\n");
  put(def, "projective.def", "1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 1 1\n");

  // JSON edit specs (vertex indices of the octahedron the target resolves against)
  const fs::path spec = root / "fuzz_edit_spec";
  put(spec, "rigid.json",
      R"({ "fixed": [0, 1],
  "handles": [ { "vertices": [4], "translation": [0, 0, 0.3],
                 "rotation": {"axis": [0, 1, 0], "angle_deg": 30}, "scale": 1.2 } ],
  "magnify": [ { "vertices": [2, 3, 4], "scale": 2.0 } ],
  "options": { "iterations": 15, "method": "scale_aware", "ora": false } })");
  put(spec, "matrix_quaternion.json",
      R"({"fixed":[5],"handles":[{"vertices":[0],"matrix":[1,0,0,1, 0,1,0,0, 0,0,1,0, 0,0,0,1]},)"
      R"({"vertices":[1,2],"quaternion":[1,0,0,0.5],"pivot":[0,0,0]}],)"
      R"("options":{"tolerance":1e-6,"inner_iterations":3,"method":"arap","ora":true}})");
  put(spec, "targets.json",
      R"({"fixed":[0,1],"handles":[{"vertices":[4,5],"targets":[[0,0,2],[0,0,-2]]}]})");
  put(spec, "index_out_of_range.json", R"({"fixed":[0,99],"handles":[{"vertices":[-1]}]})");
  put(spec, "unknown_key.json", R"({"fixd":[0],"handles":[]})");
  put(spec, "two_forms.json",
      R"({"handles":[{"vertices":[0],"translation":[1,2,3],"matrix":[1,0,0,0,0,1,0,0,0,0,1,0,0,0,0,1]}]})");

  // fuzz_clean: byte-encoded raw meshes (nv, nf, weld, 3 coordinate bytes per vertex, 3 signed
  // index bytes per face; coordinate byte b -> b % 8 - 3).
  const fs::path clean = root / "fuzz_clean";
  put(clean, "tetrahedron.bin",
      std::string("\x04\x04\x00"
                  "\x03\x03\x03"
                  "\x04\x03\x03"
                  "\x03\x04\x03"
                  "\x03\x03\x04"
                  "\x00\x02\x01"
                  "\x00\x01\x03"
                  "\x00\x03\x02"
                  "\x01\x02\x03",
                  3 + 12 + 12));
  put(clean, "soup_weld.bin",
      std::string("\x06\x02\x01"
                  "\x03\x03\x03"
                  "\x04\x03\x03"
                  "\x03\x04\x03"
                  "\x03\x03\x03"
                  "\x03\x04\x03"
                  "\x03\x03\x04"
                  "\x00\x01\x02"
                  "\x03\x04\x05",
                  3 + 18 + 6));
  put(clean, "nan_and_range.bin",
      std::string("\x03\x02\x00"
                  "\xff\x03\x03"
                  "\x04\xfe\x03"
                  "\x03\x04\xfd"
                  "\x00\x01\x7f"
                  "\x00\xff\x02",
                  3 + 9 + 6));
  return failed ? 1 : 0;
}
