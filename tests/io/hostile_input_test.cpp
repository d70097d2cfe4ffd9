// Hostile input (issue 11): every reader's work is bounded by its input. Each test crafts a small
// input whose header or structure declares far more work than its bytes back (huge counts,
// zero-width rows, accessors larger than their buffers, instancing, deep JSON nesting), asserts
// the error, and counts the loop steps the reader ran (ReadControl::work_steps) against the input
// size: no wall-clock time is measured.

#include <cstdint>
#include <cstring>
#include <stop_token>
#include <string>

#include <gtest/gtest.h>

#include "core/io/deform_spec.h"
#include "core/io/mesh_io.h"

namespace meshdeform::io {
namespace {

// Work allowed per input byte (plus a constant): the readers step a few times per token.
constexpr std::uint64_t kStepsPerByte = 4;
constexpr std::uint64_t kStepsConstant = 64;

struct Counted {
  Status status;
  std::uint64_t steps = 0;
};

Counted read_counted(const std::string& bytes, MeshFormat format) {
  Counted out;
  ReadControl control;
  control.work_steps = &out.steps;
  Result<MeshData> mesh = read_mesh_from_memory(bytes, format, control);
  out.status = mesh.ok() ? Status::success() : mesh.status();
  return out;
}

void expect_bounded(const Counted& counted, std::size_t bytes) {
  EXPECT_LE(counted.steps, kStepsPerByte * bytes + kStepsConstant)
      << "work not bounded by the " << bytes << "-byte input";
}

void append_u32(std::string& out, std::uint32_t v) {
  for (int i = 0; i < 4; ++i) out += static_cast<char>((v >> (8 * i)) & 0xFFU);
}

// --- PLY: property-less elements (the 85- and 139-byte inputs of the issue) -------------------

TEST(HostileInputTest, PlyAsciiElementWithoutPropertiesAndHugeCountIsSkippedInConstantWork) {
  const std::string bytes =
      "ply\nformat ascii 1.0\nelement vx 2\nelement junk 272222222\nend_header\n";
  const Counted counted = read_counted(bytes, MeshFormat::Ply);
  ASSERT_FALSE(counted.status.ok());
  EXPECT_EQ(counted.status.code(), ErrorCode::InvalidArgument);
  EXPECT_NE(counted.status.message().find("vertex"), std::string::npos) << counted.status.message();
  expect_bounded(counted, bytes.size());
}

TEST(HostileInputTest, PlyBinaryElementOfTwoBillionZeroWidthRowsIsSkipped) {
  std::string bytes =
      "ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty "
      "float y\nproperty float z\nelement padding 2000000000\nelement face 1\nproperty list "
      "uchar int vertex_indices\nend_header\n";
  const std::size_t header = bytes.size();
  const float xyz[9] = {0, 0, 0, 1, 0, 0, 0, 1, 0};
  bytes.append(reinterpret_cast<const char*>(xyz), sizeof xyz);
  bytes += static_cast<char>(3);
  for (std::uint32_t i = 0; i < 3; ++i) append_u32(bytes, i);
  ASSERT_GT(bytes.size(), header);
  const Counted counted = read_counted(bytes, MeshFormat::Ply);
  // The property-less element holds no data, so the mesh around it reads fine.
  EXPECT_TRUE(counted.status.ok()) << counted.status.message();
  expect_bounded(counted, bytes.size());
}

TEST(HostileInputTest, PlyElementCountBeyondTheBodyIsRefusedBeforeLooping) {
  const std::string bytes =
      "ply\nformat ascii 1.0\nelement vertex 2000000000\nproperty float x\nproperty float y\n"
      "property float z\nelement face 0\nproperty list uchar int vertex_indices\nend_header\n"
      "0 0 0\n";
  const Counted counted = read_counted(bytes, MeshFormat::Ply);
  ASSERT_FALSE(counted.status.ok());
  EXPECT_NE(counted.status.message().find("more than the data holds"), std::string::npos);
  expect_bounded(counted, bytes.size());
}

TEST(HostileInputTest, PlyListCountBeyondTheBodyIsRefused) {
  std::string bytes =
      "ply\nformat binary_little_endian 1.0\nelement vertex 0\nproperty float x\nproperty "
      "float y\nproperty float z\nelement face 1\nproperty list uint int vertex_indices\n"
      "end_header\n";
  append_u32(bytes, 4000000000U);  // a list of 4e9 indices in 4 bytes
  const Counted counted = read_counted(bytes, MeshFormat::Ply);
  ASSERT_FALSE(counted.status.ok());
  EXPECT_NE(counted.status.message().find("more than the data holds"), std::string::npos)
      << counted.status.message();
  expect_bounded(counted, bytes.size());
}

// --- OFF, OBJ, STL ------------------------------------------------------------------------------

TEST(HostileInputTest, OffCountsBeyondTheDataAreRefusedBeforeLooping) {
  const std::string bytes = "OFF\n2000000000 2000000000 0\n0 0 0\n";
  const Counted counted = read_counted(bytes, MeshFormat::Off);
  ASSERT_FALSE(counted.status.ok());
  EXPECT_NE(counted.status.message().find("more than the data can hold"), std::string::npos);
  expect_bounded(counted, bytes.size());
}

TEST(HostileInputTest, OffWithManyBlankAndCommentLinesIsLinearInItsBytes) {
  std::string bytes = "OFF\n3 1 0\n";
  for (int i = 0; i < 20000; ++i) bytes += "#\n\n";
  bytes += "0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n";
  const Counted counted = read_counted(bytes, MeshFormat::Off);
  EXPECT_TRUE(counted.status.ok()) << counted.status.message();
  expect_bounded(counted, bytes.size());
}

TEST(HostileInputTest, ObjWithAPolygonOfManyCornersIsLinearInItsBytes) {
  std::string bytes = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf";
  for (int i = 0; i < 50000; ++i) bytes += " 1";
  bytes += "\n";
  const Counted counted = read_counted(bytes, MeshFormat::Obj);
  EXPECT_TRUE(counted.status.ok()) << counted.status.message();  // degenerate: validation's job
  expect_bounded(counted, bytes.size());
}

TEST(HostileInputTest, BinaryStlDeclaringMoreTrianglesThanItsBytesIsRefused) {
  std::string bytes(80, ' ');
  append_u32(bytes, 4000000000U);
  bytes.append(50, '\0');  // one triangle's worth
  const Counted counted = read_counted(bytes, MeshFormat::Stl);
  ASSERT_FALSE(counted.status.ok());
  EXPECT_NE(counted.status.message().find("declares 4000000000 triangles"), std::string::npos)
      << counted.status.message();
  expect_bounded(counted, bytes.size());
}

TEST(HostileInputTest, AsciiStlWithALongSolidNameIsLinearInItsBytes) {
  std::string bytes = "solid";
  for (int i = 0; i < 20000; ++i) bytes += " name";
  bytes += "\nendsolid\n";
  const Counted counted = read_counted(bytes, MeshFormat::Stl);
  ASSERT_FALSE(counted.status.ok());  // no facets: no vertices
  expect_bounded(counted, bytes.size());
}

// --- glTF ---------------------------------------------------------------------------------------

std::string gltf_with(const std::string& extra_json_members, int nodes, int accessor_count) {
  // One triangle (3 float positions, 36 bytes) as a data URI, referenced by `nodes` nodes.
  const std::string buffer_b64 =
      "AAAAAAAAAAAAAAAAAACAPwAAAAAAAAAAAAAAAAAAgD8AAAAA";  // (0,0,0) (1,0,0) (0,1,0)
  std::string node_list;
  std::string node_refs;
  for (int i = 0; i < nodes; ++i) {
    node_list += std::string(i ? "," : "") + "{\"mesh\":0}";
    node_refs += std::string(i ? "," : "") + std::to_string(i);
  }
  return "{\"asset\":{\"version\":\"2.0\"}," + extra_json_members +
         "\"buffers\":[{\"byteLength\":36,\"uri\":\"data:application/octet-stream;base64," +
         buffer_b64 +
         "\"}],\"bufferViews\":[{\"buffer\":0,\"byteLength\":36}],"
         "\"accessors\":[{\"bufferView\":0,\"componentType\":5126,\"count\":" +
         std::to_string(accessor_count) +
         ",\"type\":\"VEC3\"}],\"meshes\":[{\"primitives\":[{\"attributes\":{\"POSITION\":0}}]}],"
         "\"nodes\":[" +
         node_list + "],\"scenes\":[{\"nodes\":[" + node_refs + "]}],\"scene\":0}";
}

TEST(HostileInputTest, GltfAccessorLargerThanItsBufferIsRefused) {
  const std::string bytes = gltf_with("", 1, 1000000000);
  const Counted counted = read_counted(bytes, MeshFormat::Gltf);
  ASSERT_FALSE(counted.status.ok());
  EXPECT_EQ(counted.status.code(), ErrorCode::InvalidArgument);
  expect_bounded(counted, bytes.size());
}

TEST(HostileInputTest, GltfDeepJsonNestingIsRefusedBeforeParsing) {
  const std::string deep = std::string(200000, '[') + std::string(200000, ']');
  const std::string bytes = gltf_with("\"extras\":" + deep + ",", 1, 3);
  const Counted counted = read_counted(bytes, MeshFormat::Gltf);
  ASSERT_FALSE(counted.status.ok());
  EXPECT_NE(counted.status.message().find("deeper than"), std::string::npos)
      << counted.status.message();
  expect_bounded(counted, bytes.size());
}

TEST(HostileInputTest, GltfNestingWithinTheLimitStillReads) {
  const std::string nested = std::string(10, '[') + std::string(10, ']');
  const std::string bytes = gltf_with("\"extras\":" + nested + ",", 1, 3);
  const Counted counted = read_counted(bytes, MeshFormat::Gltf);
  EXPECT_TRUE(counted.status.ok()) << counted.status.message();
}

TEST(HostileInputTest, GltfInstancingPastTheExpansionBudgetIsRefused) {
  // Shared meshes multiply output without input: make the shared primitive large (a 3 MB
  // buffer, 262,143 positions) and reference it from more nodes than the budget allows.
  constexpr int kPositions = 262143;  // a multiple of 3: non-indexed TRIANGLES
  std::string bin(static_cast<std::size_t>(kPositions) * 12, '\0');
  std::string node_list;
  std::string node_refs;
  constexpr int kNodes = 64;  // 64 x 262,143 = 16.8M vertices from ~3 MB
  for (int i = 0; i < kNodes; ++i) {
    node_list += std::string(i ? "," : "") + "{\"mesh\":0}";
    node_refs += std::string(i ? "," : "") + std::to_string(i);
  }
  std::string json = "{\"asset\":{\"version\":\"2.0\"},\"buffers\":[{\"byteLength\":" +
                     std::to_string(bin.size()) +
                     "}],\"bufferViews\":[{\"buffer\":0,\"byteLength\":" +
                     std::to_string(bin.size()) +
                     "}],\"accessors\":[{\"bufferView\":0,\"componentType\":5126,\"count\":" +
                     std::to_string(kPositions) +
                     ",\"type\":\"VEC3\",\"min\":[0,0,0],\"max\":[0,0,0]}],\"meshes\":[{"
                     "\"primitives\":[{\"attributes\":{\"POSITION\":0}}]}],\"nodes\":[" +
                     node_list + "],\"scenes\":[{\"nodes\":[" + node_refs + "]}],\"scene\":0}";
  while (json.size() % 4 != 0) json += ' ';
  std::string glb = "glTF";
  append_u32(glb, 2);
  append_u32(glb, static_cast<std::uint32_t>(12 + 8 + json.size() + 8 + bin.size()));
  append_u32(glb, static_cast<std::uint32_t>(json.size()));
  glb += "JSON";
  glb += json;
  append_u32(glb, static_cast<std::uint32_t>(bin.size()));
  glb += std::string("BIN\0", 4);
  glb += bin;
  const Counted counted = read_counted(glb, MeshFormat::Glb);
  ASSERT_FALSE(counted.status.ok());
  EXPECT_NE(counted.status.message().find("instancing"), std::string::npos)
      << counted.status.message();
  expect_bounded(counted, glb.size());
}

// --- .sel, .def, JSON edit specs -----------------------------------------------------------------

TEST(HostileInputTest, SelWithAHugeExpectedCountAndLittleTextIsLinearInTheText) {
  std::uint64_t steps = 0;
  ReadControl control;
  control.work_steps = &steps;
  const std::string text = "# roles\n0 1 2\n";
  const Result<Eigen::VectorXi> sel = parse_sel(text, 2000000000, control);
  ASSERT_FALSE(sel.ok());
  EXPECT_NE(sel.status().message().find("2000000000"), std::string::npos);
  EXPECT_LE(steps, kStepsPerByte * text.size() + kStepsConstant);
}

TEST(HostileInputTest, DefWithManyCommentLinesIsLinearInTheText) {
  std::uint64_t steps = 0;
  ReadControl control;
  control.work_steps = &steps;
  std::string text;
  for (int i = 0; i < 20000; ++i) text += "#\n";
  text += "1 0 0 0  0 1 0 0  0 0 1 0  0 0 0 1\n";
  const Result<Eigen::Matrix4d> def = parse_def(text, control);
  ASSERT_TRUE(def.ok()) << def.status().message();
  EXPECT_LE(steps, kStepsPerByte * text.size() + kStepsConstant);
}

TEST(HostileInputTest, EditSpecDeepJsonNestingIsRefusedBeforeParsing) {
  std::uint64_t steps = 0;
  ReadControl control;
  control.work_steps = &steps;
  const std::string text = "{\"fixed\":" + std::string(1000000, '[') + std::string(1000000, ']') + "}";
  const Result<EditSpec> spec = parse_edit_spec(text, control);
  ASSERT_FALSE(spec.ok());
  EXPECT_NE(spec.status().message().find("deeper than"), std::string::npos)
      << spec.status().message();
  EXPECT_LE(steps, kStepsPerByte * text.size() + kStepsConstant);
}

// --- Deadlines reach the readers ----------------------------------------------------------------

TEST(HostileInputTest, AStopRequestedBeforeReadingStopsAnyReaderWithinOnePollInterval) {
  // A valid, large OBJ: without the stop it would read to the end.
  std::string bytes;
  for (int i = 0; i < 50000; ++i) bytes += "v 0 0 " + std::to_string(i) + "\n";
  for (int i = 1; i + 2 <= 50000; i += 3) {
    bytes += "f " + std::to_string(i) + " " + std::to_string(i + 1) + " " + std::to_string(i + 2) +
             "\n";
  }
  std::stop_source stop;
  stop.request_stop();
  std::uint64_t steps = 0;
  LoadOptions options;
  options.control.stop = stop.get_token();
  options.control.work_steps = &steps;
  const Result<LoadedMesh> loaded = load_mesh_from_memory(bytes, MeshFormat::Obj, options);
  ASSERT_FALSE(loaded.ok());
  EXPECT_EQ(loaded.status().code(), ErrorCode::Cancelled);
  EXPECT_LE(steps, 2U * 4096U);  // stopped at the first poll, far from the ~66k lines
}

TEST(HostileInputTest, CleaningStopsWhenTheStopIsRequested) {
  std::string bytes = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n";
  std::stop_source stop;
  stop.request_stop();
  // The read polls only every 4096 steps, so this small read finishes; cleaning then stops.
  LoadOptions options;
  options.weld = true;
  options.control.stop = stop.get_token();
  const Result<LoadedMesh> loaded = load_mesh_from_memory(bytes, MeshFormat::Obj, options);
  ASSERT_FALSE(loaded.ok());
  EXPECT_EQ(loaded.status().code(), ErrorCode::Cancelled);
}

}  // namespace
}  // namespace meshdeform::io
