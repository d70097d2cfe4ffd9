#include "core/io/mesh_io.h"

#include <gtest/gtest.h>

#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <random>
#include <string>
#include <vector>

#include "tests/support/mesh_factories.h"

namespace meshdeform::io {
namespace {

namespace fs = std::filesystem;

constexpr MeshFormat kAllFormats[] = {MeshFormat::Obj, MeshFormat::Off, MeshFormat::Ply,
                                      MeshFormat::Stl, MeshFormat::Glb, MeshFormat::Gltf};

fs::path data_path(const std::string& name) { return fs::path(MESHDEFORM_TEST_DATA_DIR) / name; }

// A per-test scratch directory, removed afterwards.
class TempDir {
 public:
  TempDir() {
    const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
    path_ =
        fs::temp_directory_path() / ("meshdeform_io_" + std::string(info->test_suite_name()) + "_" +
                                     info->name() + "_" + std::to_string(std::random_device{}()));
    fs::create_directories(path_);
  }
  ~TempDir() {
    std::error_code ec;
    fs::remove_all(path_, ec);
  }
  TempDir(const TempDir&) = delete;
  TempDir& operator=(const TempDir&) = delete;
  const fs::path& path() const { return path_; }

 private:
  fs::path path_;
};

std::string slurp(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

// Icosphere scaled by an irrational factor so that coordinates use all 53 mantissa bits.
MeshData double_precision_mesh() {
  MeshData m = test::make_icosphere(2);
  m.V *= 1.0 / 3.0;
  m.V.col(0).array() += M_PI;
  return m;
}

// The same mesh rounded to float32, which GLB/STL store exactly.
MeshData float_mesh() {
  MeshData m = double_precision_mesh();
  m.V = m.V.cast<float>().cast<double>();
  return m;
}

std::string error_of(const Result<MeshData>& r) { return r.ok() ? "ok" : r.status().to_string(); }

// --- format names ---------------------------------------------------------------------------

TEST(MeshFormatTest, FormatFromPathIsCaseInsensitive) {
  EXPECT_EQ(format_from_path("a/b/model.OBJ").value(), MeshFormat::Obj);
  EXPECT_EQ(format_from_path("x.off").value(), MeshFormat::Off);
  EXPECT_EQ(format_from_path("x.Ply").value(), MeshFormat::Ply);
  EXPECT_EQ(format_from_path("x.tar.stl").value(), MeshFormat::Stl);
  EXPECT_EQ(format_from_path("x.GLB").value(), MeshFormat::Glb);
  EXPECT_EQ(format_from_path("x.gltf").value(), MeshFormat::Gltf);
}

TEST(MeshFormatTest, FormatFromPathRejectsUnknownOrMissingExtension) {
  const auto unknown = format_from_path("scene.fbx");
  ASSERT_FALSE(unknown.ok());
  EXPECT_EQ(unknown.status().code(), ErrorCode::InvalidArgument);
  EXPECT_NE(unknown.status().message().find(".fbx"), std::string::npos);
  const auto none = format_from_path("README");
  ASSERT_FALSE(none.ok());
  EXPECT_EQ(none.status().code(), ErrorCode::InvalidArgument);
}

TEST(MeshFormatTest, ParseFormatRoundTripsNames) {
  for (const MeshFormat f : kAllFormats) {
    EXPECT_EQ(parse_format(format_name(f)).value(), f);
  }
  EXPECT_EQ(parse_format("GLTF").value(), MeshFormat::Gltf);
  const auto bad = parse_format("3ds");
  ASSERT_FALSE(bad.ok());
  EXPECT_EQ(bad.status().code(), ErrorCode::InvalidArgument);
  EXPECT_NE(bad.status().message().find("3ds"), std::string::npos);
}

// --- round trips ----------------------------------------------------------------------------

class LosslessRoundTripTest : public ::testing::TestWithParam<MeshFormat> {};

TEST_P(LosslessRoundTripTest, DoublePositionsAndFacesArePreservedExactly) {
  const MeshData mesh = double_precision_mesh();
  const auto bytes = write_mesh_to_memory(mesh, GetParam());
  ASSERT_TRUE(bytes.ok()) << bytes.status().to_string();
  const auto back = read_mesh_from_memory(*bytes, GetParam());
  ASSERT_TRUE(back.ok()) << error_of(back);
  EXPECT_EQ(back->V, mesh.V);  // bit-exact
  EXPECT_EQ(back->F, mesh.F);
}

INSTANTIATE_TEST_SUITE_P(TextFormats, LosslessRoundTripTest,
                         ::testing::Values(MeshFormat::Obj, MeshFormat::Off, MeshFormat::Ply),
                         [](const auto& info) { return std::string(format_name(info.param)); });

class Float32RoundTripTest : public ::testing::TestWithParam<MeshFormat> {};

TEST_P(Float32RoundTripTest, FloatRepresentablePositionsAndFacesArePreserved) {
  const MeshData mesh = float_mesh();
  const auto bytes = write_mesh_to_memory(mesh, GetParam());
  ASSERT_TRUE(bytes.ok()) << bytes.status().to_string();
  const auto back = read_mesh_from_memory(*bytes, GetParam());
  ASSERT_TRUE(back.ok()) << error_of(back);
  EXPECT_EQ(back->V, mesh.V);
  EXPECT_EQ(back->F, mesh.F);
}

INSTANTIATE_TEST_SUITE_P(GltfFormats, Float32RoundTripTest,
                         ::testing::Values(MeshFormat::Glb, MeshFormat::Gltf),
                         [](const auto& info) { return std::string(format_name(info.param)); });

TEST(MeshIoTest, GlbStartsWithMagicAndRoundsDoublesToFloat) {
  const MeshData mesh = double_precision_mesh();
  const auto bytes = write_mesh_to_memory(mesh, MeshFormat::Glb);
  ASSERT_TRUE(bytes.ok()) << bytes.status().to_string();
  EXPECT_EQ(bytes->substr(0, 4), "glTF");
  const auto back = read_mesh_from_memory(*bytes, MeshFormat::Glb);
  ASSERT_TRUE(back.ok()) << error_of(back);
  EXPECT_EQ(back->V, float_mesh().V);
}

TEST(MeshIoTest, StlRoundTripAfterWelding) {
  const MeshData mesh = float_mesh();
  const auto bytes = write_mesh_to_memory(mesh, MeshFormat::Stl);
  ASSERT_TRUE(bytes.ok()) << bytes.status().to_string();
  EXPECT_EQ(bytes->size(), 84 + 50 * static_cast<std::size_t>(mesh.F.rows()));

  // The raw read is a soup: three fresh vertices per face.
  const auto soup = read_mesh_from_memory(*bytes, MeshFormat::Stl);
  ASSERT_TRUE(soup.ok()) << error_of(soup);
  EXPECT_EQ(soup->V.rows(), 3 * mesh.F.rows());

  const auto loaded = load_mesh_from_memory(*bytes, MeshFormat::Stl);
  ASSERT_TRUE(loaded.ok()) << loaded.status().to_string();
  ASSERT_EQ(loaded->mesh.V.rows(), mesh.V.rows());
  ASSERT_EQ(loaded->mesh.F.rows(), mesh.F.rows());
  EXPECT_EQ(loaded->report.welded_vertices, 3 * mesh.F.rows() - mesh.V.rows());
  // Vertex order follows first use in the soup; compare every face corner's position.
  for (Eigen::Index f = 0; f < mesh.F.rows(); ++f) {
    for (int k = 0; k < 3; ++k) {
      ASSERT_EQ(loaded->mesh.V.row(loaded->mesh.F(f, k)), mesh.V.row(mesh.F(f, k)))
          << "face " << f << " corner " << k;
    }
  }
}

TEST(MeshIoTest, WeldingAnStlSoupGivesTheGridVertexCount) {
  const MeshData grid = test::make_grid(3);  // 16 vertices, 18 faces
  const auto bytes = write_mesh_to_memory(grid, MeshFormat::Stl);
  ASSERT_TRUE(bytes.ok());
  const auto loaded = load_mesh_from_memory(*bytes, MeshFormat::Stl);
  ASSERT_TRUE(loaded.ok()) << loaded.status().to_string();
  EXPECT_EQ(loaded->mesh.V.rows(), 16);
  EXPECT_EQ(loaded->mesh.F.rows(), 18);
  EXPECT_EQ(loaded->report.welded_vertices, 3 * 18 - 16);
  EXPECT_EQ(loaded->report.old_to_new.size(), 3 * 18);
}

TEST(MeshIoTest, AsciiStlIsReadAndWelded) {
  const std::string stl =
      "solid quad\n"
      "  facet normal 0 0 1\n    outer loop\n      vertex 0 0 0\n      vertex 1 0 0\n"
      "      vertex 0 1 0\n    endloop\n  endfacet\n"
      "  facet normal 0 0 1\n    outer loop\n      vertex 0 1 0\n      vertex 1 0 0\n"
      "      vertex 1 1 0\n    endloop\n  endfacet\n"
      "endsolid quad\n";
  const auto loaded = load_mesh_from_memory(stl, MeshFormat::Stl);
  ASSERT_TRUE(loaded.ok()) << loaded.status().to_string();
  EXPECT_EQ(loaded->mesh.V.rows(), 4);
  EXPECT_EQ(loaded->mesh.F.rows(), 2);
  EXPECT_EQ(loaded->report.welded_vertices, 2);
}

// --- files vs memory ------------------------------------------------------------------------

TEST(MeshIoTest, SpotObjLoads) {
  const auto raw = read_mesh(data_path("spot.obj"));
  ASSERT_TRUE(raw.ok()) << error_of(raw);
  EXPECT_EQ(raw->V.rows(), 2930);
  EXPECT_EQ(raw->F.rows(), 5856);
  const auto loaded = load_mesh(data_path("spot.obj"));
  ASSERT_TRUE(loaded.ok()) << loaded.status().to_string();
  EXPECT_EQ(loaded->mesh.V.rows(), 2930);
  EXPECT_EQ(loaded->mesh.F.rows(), 5856);
  EXPECT_EQ(loaded->format, MeshFormat::Obj);
  EXPECT_EQ(loaded->report.welded_vertices, 0);
  EXPECT_EQ(loaded->report.dropped_unreferenced, 0);
}

TEST(MeshIoTest, ReadingFromMemoryEqualsReadingFromFile) {
  TempDir dir;
  const auto spot = read_mesh(data_path("spot.obj"));
  ASSERT_TRUE(spot.ok()) << error_of(spot);
  for (const MeshFormat format : kAllFormats) {
    SCOPED_TRACE(format_name(format));
    const fs::path path = dir.path() / (std::string("spot.") + format_name(format));
    ASSERT_TRUE(write_mesh(path, *spot).ok());
    const auto from_file = read_mesh(path);
    ASSERT_TRUE(from_file.ok()) << error_of(from_file);
    const auto from_memory = read_mesh_from_memory(slurp(path), format);
    ASSERT_TRUE(from_memory.ok()) << error_of(from_memory);
    EXPECT_EQ(from_file->V, from_memory->V);
    EXPECT_EQ(from_file->F, from_memory->F);
    // And the file content is exactly what write_mesh_to_memory produces.
    EXPECT_EQ(slurp(path), write_mesh_to_memory(*spot, format).value());
  }
}

TEST(MeshIoTest, MissingFileIsNotFound) {
  const auto r = read_mesh(data_path("does_not_exist.obj"));
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.status().code(), ErrorCode::NotFound);
  EXPECT_NE(r.status().message().find("does_not_exist.obj"), std::string::npos);
  const auto loaded = load_mesh(data_path("does_not_exist.ply"));
  ASSERT_FALSE(loaded.ok());
  EXPECT_EQ(loaded.status().code(), ErrorCode::NotFound);
}

TEST(MeshIoTest, ADirectoryIsInvalidArgumentNamingThePath) {
  TempDir dir;
  const fs::path folder = dir.path() / "looks_like_a_mesh.obj";
  fs::create_directories(folder);
  const auto r = read_mesh(folder);
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.status().code(), ErrorCode::InvalidArgument);
  EXPECT_NE(r.status().message().find(folder.string() + "' is a directory"), std::string::npos)
      << r.status().message();
}

TEST(MeshIoTest, WriteRejectsIndexOutOfRangeAndUnknownExtension) {
  MeshData m = test::make_triangle();
  m.F(0, 2) = 3;
  for (const MeshFormat format : kAllFormats) {
    const auto bytes = write_mesh_to_memory(m, format);
    ASSERT_FALSE(bytes.ok()) << format_name(format);
    EXPECT_NE(bytes.status().message().find("face 0 references vertex 3 (#V=3)"),
              std::string::npos);
  }
  TempDir dir;
  const Status s = write_mesh(dir.path() / "mesh.xyz", test::make_triangle());
  EXPECT_EQ(s.code(), ErrorCode::InvalidArgument);
}

TEST(MeshIoTest, Float32FormatsRejectCoordinatesOutsideFloatRange) {
  MeshData m = test::make_triangle();
  m.V(1, 0) = 1e300;
  EXPECT_FALSE(write_mesh_to_memory(m, MeshFormat::Stl).ok());
  EXPECT_FALSE(write_mesh_to_memory(m, MeshFormat::Glb).ok());
  EXPECT_TRUE(write_mesh_to_memory(m, MeshFormat::Obj).ok());
}

// --- readers keep what they read; validation decides ----------------------------------------

TEST(MeshIoTest, ObjReaderKeepsNonManifoldAndDegenerateFaces) {
  const std::string obj =
      "v 0 0 0\nv 1 0 0\nv 0.5 1 0\nv 0.5 -1 0\nv 0.5 0 1\n"
      "f 1 2 3\nf 2 1 4\nf 2 1 5\n";
  const auto raw = read_mesh_from_memory(obj, MeshFormat::Obj);
  ASSERT_TRUE(raw.ok()) << error_of(raw);
  EXPECT_EQ(raw->F.rows(), 3);  // OpenMesh's TriMesh reader would drop the third face
  const auto loaded = load_mesh_from_memory(obj, MeshFormat::Obj);
  ASSERT_FALSE(loaded.ok());
  EXPECT_NE(loaded.status().message().find("non-manifold edge (0, 1)"), std::string::npos)
      << loaded.status().message();

  const std::string repeated = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 2\n";
  const auto raw_repeated = read_mesh_from_memory(repeated, MeshFormat::Obj);
  ASSERT_TRUE(raw_repeated.ok()) << error_of(raw_repeated);
  EXPECT_EQ(raw_repeated->F.row(0), Eigen::RowVector3i(0, 1, 1));
  const auto loaded_repeated = load_mesh_from_memory(repeated, MeshFormat::Obj);
  ASSERT_FALSE(loaded_repeated.ok());
  EXPECT_NE(loaded_repeated.status().message().find("repeats vertex 1"), std::string::npos);
}

TEST(MeshIoTest, ObjReaderKeepsOutOfRangeIndicesForValidation) {
  const std::string obj = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n";
  const auto raw = read_mesh_from_memory(obj, MeshFormat::Obj);
  ASSERT_TRUE(raw.ok()) << error_of(raw);
  const auto loaded = load_mesh_from_memory(obj, MeshFormat::Obj);
  ASSERT_FALSE(loaded.ok());
  EXPECT_NE(loaded.status().message().find("face 0 references vertex 8 (#V=3)"), std::string::npos)
      << loaded.status().message();
}

TEST(MeshIoTest, ObjPolygonsAreFanTriangulatedAndIndexFormsAreUnderstood) {
  const std::string obj =
      "# comment\nmtllib /etc/passwd\no quad\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n"
      "vt 0 0\nvn 0 0 1\nusemtl none\ns off\nf 1/1/1 2/1/1 3//1 4\nv 2 0 0\nf -4 -1 -3\n";
  const auto raw = read_mesh_from_memory(obj, MeshFormat::Obj);
  ASSERT_TRUE(raw.ok()) << error_of(raw);
  ASSERT_EQ(raw->F.rows(), 3);
  EXPECT_EQ(raw->F.row(0), Eigen::RowVector3i(0, 1, 2));
  EXPECT_EQ(raw->F.row(1), Eigen::RowVector3i(0, 2, 3));
  EXPECT_EQ(raw->F.row(2), Eigen::RowVector3i(1, 4, 2));  // relative to the 5 vertices so far
  EXPECT_EQ(raw->V.row(4), Eigen::RowVector3d(2, 0, 0));
}

TEST(MeshIoTest, OffPolygonsAndCommentsAreRead) {
  const std::string off =
      "OFF\n# a comment\n5 2 0\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n2 0 0\n4 0 1 2 3\n3 1 4 2 255 0 0\n";
  const auto raw = read_mesh_from_memory(off, MeshFormat::Off);
  ASSERT_TRUE(raw.ok()) << error_of(raw);
  ASSERT_EQ(raw->F.rows(), 3);
  EXPECT_EQ(raw->F.row(1), Eigen::RowVector3i(0, 2, 3));
  EXPECT_EQ(raw->F.row(2), Eigen::RowVector3i(1, 4, 2));
}

// Binary PLY with float vertices, an extra vertex property, and an extra element.
std::string binary_ply(bool big_endian) {
  std::string header = std::string("ply\nformat ") +
                       (big_endian ? "binary_big_endian" : "binary_little_endian") +
                       " 1.0\ncomment test\nelement vertex 4\nproperty float x\nproperty float y\n"
                       "property float z\nproperty uchar red\nelement face 2\n"
                       "property list uchar int vertex_indices\nelement edge 1\n"
                       "property int vertex1\nproperty int vertex2\nend_header\n";
  auto put = [&](const void* p, std::size_t n) {
    const auto* b = static_cast<const char*>(p);
    for (std::size_t i = 0; i < n; ++i) header += b[big_endian ? n - 1 - i : i];
  };
  const float xyz[4][3] = {{0, 0, 0}, {1.5f, 0, 0}, {0, 1, 0}, {1, 1, 0.25f}};
  for (const auto& v : xyz) {
    for (const float c : v) put(&c, 4);
    header += static_cast<char>(200);
  }
  const int faces[2][3] = {{0, 1, 2}, {2, 1, 3}};
  for (const auto& f : faces) {
    header += static_cast<char>(3);
    for (const int i : f) put(&i, 4);
  }
  const int edge[2] = {0, 1};
  for (const int i : edge) put(&i, 4);
  return header;
}

TEST(MeshIoTest, BinaryPlyBothEndiannesses) {
  for (const bool big : {false, true}) {
    const auto raw = read_mesh_from_memory(binary_ply(big), MeshFormat::Ply);
    ASSERT_TRUE(raw.ok()) << error_of(raw);
    ASSERT_EQ(raw->V.rows(), 4);
    ASSERT_EQ(raw->F.rows(), 2);
    EXPECT_EQ(raw->V.row(1), Eigen::RowVector3d(1.5, 0, 0));
    EXPECT_EQ(raw->V.row(3), Eigen::RowVector3d(1, 1, 0.25));
    EXPECT_EQ(raw->F.row(1), Eigen::RowVector3i(2, 1, 3));
  }
}

// --- glTF specifics -------------------------------------------------------------------------

std::string base64(const std::string& bytes) {
  static const char* kTable = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
  std::string out;
  std::size_t i = 0;
  for (; i + 2 < bytes.size(); i += 3) {
    const std::uint32_t n = (static_cast<std::uint8_t>(bytes[i]) << 16U) |
                            (static_cast<std::uint8_t>(bytes[i + 1]) << 8U) |
                            static_cast<std::uint8_t>(bytes[i + 2]);
    for (int k = 3; k >= 0; --k) out += kTable[(n >> (6U * static_cast<unsigned>(k))) & 63U];
  }
  if (i < bytes.size()) {
    std::uint32_t n = static_cast<std::uint8_t>(bytes[i]) << 16U;
    if (i + 1 < bytes.size()) n |= static_cast<std::uint8_t>(bytes[i + 1]) << 8U;
    out += kTable[(n >> 18U) & 63U];
    out += kTable[(n >> 12U) & 63U];
    out += i + 1 < bytes.size() ? kTable[(n >> 6U) & 63U] : '=';
    out += '=';
  }
  return out;
}

// Two primitives (float positions; uint16 and uint8 indices) in one mesh, under a translated node.
std::string two_primitive_gltf(int position_count = 3) {
  std::string buffer;
  auto put = [&](const void* p, std::size_t n) { buffer.append(static_cast<const char*>(p), n); };
  const float positions[6][3] = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {0, 0, 1}, {1, 0, 1}, {0, 1, 1}};
  for (const auto& p : positions) put(p, sizeof(p));
  const std::uint16_t i16[3] = {0, 1, 2};
  put(i16, sizeof(i16));
  const std::uint8_t i8[3] = {2, 1, 0};
  put(i8, sizeof(i8));
  buffer.append(3, '\0');  // 84 bytes
  const std::string count = std::to_string(position_count);
  return R"({"asset":{"version":"2.0"},"scene":0,"scenes":[{"nodes":[0]}],
    "nodes":[{"mesh":0,"translation":[10,0,0]}],
    "buffers":[{"byteLength":84,"uri":"data:application/octet-stream;base64,)" +
         base64(buffer) + R"("}],
    "bufferViews":[{"buffer":0,"byteOffset":0,"byteLength":72},
                   {"buffer":0,"byteOffset":72,"byteLength":6},
                   {"buffer":0,"byteOffset":78,"byteLength":3}],
    "accessors":[{"bufferView":0,"byteOffset":0,"componentType":5126,"count":)" +
         count + R"(,"type":"VEC3"},
                 {"bufferView":0,"byteOffset":36,"componentType":5126,"count":3,"type":"VEC3"},
                 {"bufferView":1,"componentType":5123,"count":3,"type":"SCALAR"},
                 {"bufferView":2,"componentType":5121,"count":3,"type":"SCALAR"}],
    "meshes":[{"primitives":[{"attributes":{"POSITION":0},"indices":2},
                             {"attributes":{"POSITION":1},"indices":3}]}]})";
}

TEST(MeshIoTest, GltfMergesPrimitivesWithIndexOffsetsAndAppliesNodeTransforms) {
  const auto raw = read_mesh_from_memory(two_primitive_gltf(), MeshFormat::Gltf);
  ASSERT_TRUE(raw.ok()) << error_of(raw);
  ASSERT_EQ(raw->V.rows(), 6);
  ASSERT_EQ(raw->F.rows(), 2);
  EXPECT_EQ(raw->F.row(0), Eigen::RowVector3i(0, 1, 2));
  EXPECT_EQ(raw->F.row(1), Eigen::RowVector3i(5, 4, 3));
  EXPECT_EQ(raw->V.row(0), Eigen::RowVector3d(10, 0, 0));
  EXPECT_EQ(raw->V.row(5), Eigen::RowVector3d(10, 1, 1));
}

TEST(MeshIoTest, GltfAccessorBeyondItsBufferIsAnErrorNotARead) {
  const auto r = read_mesh_from_memory(two_primitive_gltf(1000000), MeshFormat::Gltf);
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.status().code(), ErrorCode::InvalidArgument);
  EXPECT_NE(r.status().message().find("accessor 0"), std::string::npos) << r.status().message();
}

std::string external_buffer_gltf(const std::string& uri) {
  return R"({"asset":{"version":"2.0"},"buffers":[{"byteLength":12,"uri":")" + uri +
         R"("}],"meshes":[]})";
}

TEST(MeshIoTest, GltfFromFileLoadsExternalBuffersNextToIt) {
  TempDir dir;
  std::ofstream(dir.path() / "data.bin", std::ios::binary) << std::string(12, '\0');
  std::ofstream(dir.path() / "external.gltf") << external_buffer_gltf("data.bin");
  const auto r = read_mesh(dir.path() / "external.gltf");
  ASSERT_FALSE(r.ok());  // the buffer loads; the model simply has no mesh
  EXPECT_NE(r.status().message().find("no vertices"), std::string::npos) << r.status().message();
}

TEST(MeshIoTest, GltfFromMemoryRefusesExternalFiles) {
  // The buffer file exists relative to the working directory, where tinygltf's default callbacks
  // would find it; reading request bytes must not touch the filesystem at all.
  const std::string name = "meshdeform_probe_" + std::to_string(std::random_device{}()) + ".bin";
  const fs::path probe = fs::current_path() / name;
  std::ofstream(probe, std::ios::binary) << std::string(12, '\0');
  ASSERT_TRUE(fs::exists(probe));
  const auto r = read_mesh_from_memory(external_buffer_gltf(name), MeshFormat::Gltf);
  fs::remove(probe);
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.status().code(), ErrorCode::InvalidArgument);
  EXPECT_NE(r.status().message().find("File not found"), std::string::npos) << r.status().message();
  EXPECT_EQ(r.status().message().find("no vertices"), std::string::npos) << r.status().message();
}

// --- garbage never crashes ------------------------------------------------------------------

class GarbageTest : public ::testing::TestWithParam<MeshFormat> {};

TEST_P(GarbageTest, EmptyBytesAreAnError) {
  const auto r = read_mesh_from_memory("", GetParam());
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.status().code(), ErrorCode::InvalidArgument);
}

TEST_P(GarbageTest, RandomBytesAreAnError) {
  std::mt19937 rng(1234);
  for (const std::size_t size : {1, 3, 17, 84, 134, 1000, 4096}) {
    for (int trial = 0; trial < 5; ++trial) {
      std::string bytes(size, '\0');
      for (char& c : bytes) c = static_cast<char>(rng() & 0xffU);
      const auto r = read_mesh_from_memory(bytes, GetParam());
      EXPECT_FALSE(r.ok()) << "size " << size << " trial " << trial;
      if (!r.ok()) {
        EXPECT_EQ(r.status().code(), ErrorCode::InvalidArgument);
      }
    }
  }
}

TEST_P(GarbageTest, TruncatedFilesAreAnError) {
  const auto full = write_mesh_to_memory(float_mesh(), GetParam());
  ASSERT_TRUE(full.ok());
  // OBJ has no element counts, so a cut at a line boundary is a valid shorter file; cut it only
  // inside the vertex block (no faces left). TruncatedObjFaceIsAnError covers cut face lines.
  const std::vector<double> fractions = GetParam() == MeshFormat::Obj
                                            ? std::vector<double>{0.02, 0.25, 0.5}
                                            : std::vector<double>{0.02, 0.25, 0.5, 0.9};
  for (const double fraction : fractions) {
    const std::string truncated =
        full->substr(0, static_cast<std::size_t>(fraction * full->size()));
    const auto r = read_mesh_from_memory(truncated, GetParam());
    EXPECT_FALSE(r.ok()) << "kept " << fraction << " of " << full->size() << " bytes";
  }
}

TEST_P(GarbageTest, FlippedBytesNeverCrash) {
  // Corrupt single bytes of a valid file: the result may be ok or an error, but must not crash
  // and an ok result must be a consistent mesh.
  const auto full = write_mesh_to_memory(test::make_icosphere(1), GetParam());
  ASSERT_TRUE(full.ok());
  std::mt19937 rng(99);
  int errors = 0;
  for (int trial = 0; trial < 200; ++trial) {
    std::string bytes = *full;
    bytes[rng() % bytes.size()] = static_cast<char>(rng() & 0xffU);
    const auto r = read_mesh_from_memory(bytes, GetParam());
    if (r.ok()) {
      EXPECT_EQ(r->V.cols(), 3);
      EXPECT_GT(r->F.rows(), 0);
    } else {
      ++errors;
    }
  }
  RecordProperty("errors", errors);
}

INSTANTIATE_TEST_SUITE_P(AllFormats, GarbageTest, ::testing::ValuesIn(kAllFormats),
                         [](const auto& info) { return std::string(format_name(info.param)); });

TEST(MeshIoTest, TruncatedObjFaceIsAnError) {
  const std::string obj = write_mesh_to_memory(float_mesh(), MeshFormat::Obj).value();
  // Cut inside the last face line, after its second index.
  const std::string cut = obj.substr(0, obj.rfind(' '));
  const auto r = read_mesh_from_memory(cut, MeshFormat::Obj);
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("at least 3 vertices"), std::string::npos)
      << r.status().message();
  // Cut inside a vertex line.
  const std::string vcut = obj.substr(0, obj.find("\nv ", obj.size() / 4) + 8);
  EXPECT_FALSE(read_mesh_from_memory(vcut, MeshFormat::Obj).ok());
}

TEST(MeshIoTest, AsciiPlyListCountBeyondAnyIntegerIsAnError) {
  // Found by fuzz_mesh_ply: a list length above 2^64 in ASCII PLY (which does not bound the
  // count by its declared type) was converted to an integer for the message: undefined behaviour.
  const auto r = read_mesh_from_memory(
      "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
      "property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
      "0 0 0\n1 0 0\n0 1 0\n1e300 0 1 2\n",
      MeshFormat::Ply);
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("more than the data holds"), std::string::npos)
      << r.status().message();
}

TEST(MeshIoTest, ForgedHeaderCountsAreAnErrorNotAnAllocation) {
  EXPECT_FALSE(
      read_mesh_from_memory("OFF\n2000000000 2000000000 0\n0 0 0\n", MeshFormat::Off).ok());
  EXPECT_FALSE(
      read_mesh_from_memory("ply\nformat binary_little_endian 1.0\nelement vertex 2000000000\n"
                            "property float x\nproperty float y\nproperty float z\n"
                            "element face 1\nproperty list uint int vertex_indices\nend_header\n",
                            MeshFormat::Ply)
          .ok());
  // A face list claiming 4 billion indices.
  std::string ply = binary_ply(false);
  const std::size_t body = ply.find("end_header\n") + 11;
  std::string forged = ply;
  forged.replace(forged.find("list uchar int"), 14, "list uint int ");
  // Make the first face's count 0xffffffff (4 bytes, replacing the 1-byte count and 3 index bytes).
  const std::size_t face0 = body + 4 * 13;
  forged.replace(face0, 4, std::string(4, '\xff'));
  const auto r = read_mesh_from_memory(forged, MeshFormat::Ply);
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.status().code(), ErrorCode::InvalidArgument);
  std::string stl(84, '\0');
  stl[80] = stl[81] = stl[82] = stl[83] = '\xff';
  EXPECT_FALSE(read_mesh_from_memory(stl, MeshFormat::Stl).ok());
}

}  // namespace
}  // namespace meshdeform::io
