#include "core/io/deform_spec.h"

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <cmath>
#include <filesystem>
#include <limits>
#include <random>
#include <string>

#include "tests/support/mesh_factories.h"

namespace meshdeform::io {
namespace {

namespace fs = std::filesystem;

template <typename T>
std::string message_of(const Result<T>& r) {
  return r.ok() ? std::string("ok") : r.status().message();
}

template <typename T>
void expect_error(const Result<T>& r, ErrorCode code,
                  std::initializer_list<std::string> fragments) {
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.status().code(), code) << r.status().to_string();
  for (const std::string& fragment : fragments) {
    EXPECT_NE(r.status().message().find(fragment), std::string::npos)
        << "message '" << r.status().message() << "' lacks '" << fragment << "'";
  }
}

fs::path temp_file(const std::string& name) {
  return fs::temp_directory_path() /
         ("meshdeform_spec_" + std::to_string(std::random_device{}()) + "_" + name);
}

// --- .sel -----------------------------------------------------------------------------------

TEST(SelTest, ParsesHeaderAndValuesWithAnyWhitespace) {
  const auto sel =
      parse_sel("# benchmark selection\n# second header line\n0\n1 2\n\t2  \n1\r\n", 5);
  ASSERT_TRUE(sel.ok()) << message_of(sel);
  EXPECT_EQ(*sel, (Eigen::VectorXi(5) << 0, 1, 2, 2, 1).finished());
}

TEST(SelTest, NegativeExpectedCountAcceptsAnyLength) {
  const auto sel = parse_sel("0 0 2\n", -1);
  ASSERT_TRUE(sel.ok()) << message_of(sel);
  EXPECT_EQ(sel->size(), 3);
}

TEST(SelTest, RejectsValueOutsideRolesNamingLineAndValue) {
  expect_error(parse_sel("# h\n0\n1\n3\n", 3), ErrorCode::InvalidArgument,
               {"line 4", "'3'", "vertex 2"});
  expect_error(parse_sel("# h\n0\nx\n1\n", 3), ErrorCode::InvalidArgument, {"line 3", "'x'"});
  expect_error(parse_sel("0 -1 1\n", 3), ErrorCode::InvalidArgument, {"line 1", "'-1'"});
}

TEST(SelTest, RejectsWrongCount) {
  expect_error(parse_sel("# h\n0\n1\n", 3), ErrorCode::InvalidArgument,
               {"2 entries", "3 vertices"});
}

TEST(SelTest, FileRoundTripAndMissingFile) {
  const Eigen::VectorXi sel = (Eigen::VectorXi(6) << 0, 0, 1, 1, 2, 2).finished();
  const fs::path path = temp_file("a.sel");
  ASSERT_TRUE(write_sel(path, sel).ok());
  const auto back = read_sel(path, 6);
  fs::remove(path);
  ASSERT_TRUE(back.ok()) << message_of(back);
  EXPECT_EQ(*back, sel);
  expect_error(read_sel(path, 6), ErrorCode::NotFound, {path.filename().string()});
}

TEST(SelTest, WriterRejectsInvalidRole) {
  expect_error(format_sel((Eigen::VectorXi(3) << 0, 5, 1).finished()), ErrorCode::InvalidArgument,
               {"vertex 1", "5"});
}

// --- .def -----------------------------------------------------------------------------------

TEST(DefTest, ParsesRowMajorMatrix) {
  const auto T = parse_def("# transform\n1 0 0 0.5\n0 1 0 -2\n0 0 1 +3e-1\n0 0 0 1\n");
  ASSERT_TRUE(T.ok()) << message_of(T);
  EXPECT_EQ((*T)(0, 3), 0.5);
  EXPECT_EQ((*T)(1, 3), -2.0);
  EXPECT_EQ((*T)(2, 3), 0.3);
  EXPECT_EQ((*T)(3, 3), 1.0);
  EXPECT_EQ((*T)(3, 0), 0.0);
}

TEST(DefTest, RejectsWrongCountAndBadTokens) {
  expect_error(parse_def("# t\n1 0 0 0\n0 1 0 0\n0 0 1 0\n"), ErrorCode::InvalidArgument,
               {"16 numbers", "got 12"});
  expect_error(parse_def("# t\n1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1 7\n"), ErrorCode::InvalidArgument,
               {"line 5", "more than 16", "'7'"});
  expect_error(parse_def("# t\n1 0 0 0\n0 one 0 0\n"), ErrorCode::InvalidArgument,
               {"line 3", "'one'"});
  expect_error(parse_def("# t\n1 0 0 nan\n0 1 0 0\n0 0 1 0\n0 0 0 1\n"), ErrorCode::InvalidArgument,
               {"line 2", "not finite"});
}

TEST(DefTest, FileRoundTripIsExact) {
  Eigen::Matrix4d T = Eigen::Matrix4d::Identity();
  T.topLeftCorner<3, 3>() =
      Eigen::AngleAxisd(0.7, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix();
  T.topRightCorner<3, 1>() << 1.0 / 3.0, -M_PI, 1e-17;
  const fs::path path = temp_file("a.def");
  ASSERT_TRUE(write_def(path, T).ok());
  const auto back = read_def(path);
  fs::remove(path);
  ASSERT_TRUE(back.ok()) << message_of(back);
  EXPECT_EQ(*back, T);
}

// --- JSON edit spec -------------------------------------------------------------------------

class EditSpecTest : public ::testing::Test {
 protected:
  MeshData grid_ = test::make_grid(4);  // 25 vertices on [0,1]^2
};

TEST_F(EditSpecTest, ResolvesAllHandleFormsSortedAndUnique) {
  const std::string json = R"({
    "fixed": [3, 0, 1, 0],
    "handles": [
      {"vertices": [24, 20], "translation": [0, 0, 1]},
      {"vertices": [12], "matrix": [1,0,0,0.5, 0,1,0,0, 0,0,1,0, 0,0,0,1]},
      {"vertices": [6, 7], "targets": [[0, 0, 5], [1, 1, 5]]}
    ],
    "options": {"iterations": 7, "tolerance": 1e-5, "inner_iterations": 3}
  })";
  const auto spec = parse_edit_spec(json);
  ASSERT_TRUE(spec.ok()) << message_of(spec);
  EXPECT_EQ(spec->options.iterations, 7);
  EXPECT_EQ(spec->options.tolerance, 1e-5);
  EXPECT_EQ(spec->options.inner_iterations, 3);
  const auto setup = resolve_edit(*spec, grid_.V);
  ASSERT_TRUE(setup.ok()) << message_of(setup);
  EXPECT_EQ(setup->constrained, (Eigen::VectorXi(8) << 0, 1, 3, 6, 7, 12, 20, 24).finished());
  ASSERT_EQ(setup->targets.rows(), 8);
  EXPECT_EQ(setup->targets.row(0), grid_.V.row(0));               // fixed
  EXPECT_EQ(setup->targets.row(2), grid_.V.row(3));               // fixed
  EXPECT_EQ(setup->targets.row(3), Eigen::RowVector3d(0, 0, 5));  // targets
  EXPECT_EQ(setup->targets.row(4), Eigen::RowVector3d(1, 1, 5));
  EXPECT_EQ(setup->targets.row(5), grid_.V.row(12) + Eigen::RowVector3d(0.5, 0, 0));  // matrix
  EXPECT_EQ(setup->targets.row(6), grid_.V.row(20) + Eigen::RowVector3d(0, 0, 1));    // rigid
  EXPECT_EQ(setup->targets.row(7), grid_.V.row(24) + Eigen::RowVector3d(0, 0, 1));
}

TEST_F(EditSpecTest, RigidRotationScaleAndPivot) {
  // Vertices 0 = (0,0,0) and 4 = (1,0,0); default pivot is their centroid (0.5,0,0).
  const auto spec = parse_edit_spec(R"({"handles": [
      {"vertices": [0, 4], "translation": [0, 0, 2], "rotation": {"axis": [0, 0, 3], "angle_deg": 90}},
      {"vertices": [24], "translation": [0, 0, 0], "quaternion": [0, 0, 0, 1], "scale": 2,
       "pivot": [0, 0, 0]}]})");
  ASSERT_TRUE(spec.ok()) << message_of(spec);
  const auto setup = resolve_edit(*spec, grid_.V);
  ASSERT_TRUE(setup.ok()) << message_of(setup);
  ASSERT_EQ(setup->constrained, (Eigen::VectorXi(3) << 0, 4, 24).finished());
  EXPECT_TRUE(setup->targets.row(0).isApprox(Eigen::RowVector3d(0.5, -0.5, 2), 1e-12))
      << setup->targets;
  EXPECT_TRUE(setup->targets.row(1).isApprox(Eigen::RowVector3d(0.5, 0.5, 2), 1e-12))
      << setup->targets;
  // Vertex 24 = (1,1,0): scaled by 2 about the origin, rotated 180 degrees about z.
  EXPECT_TRUE(setup->targets.row(2).isApprox(Eigen::RowVector3d(-2, -2, 0), 1e-12))
      << setup->targets;
}

TEST_F(EditSpecTest, RejectsIndexOutOfRangeNamingKey) {
  auto spec = parse_edit_spec(R"({"fixed": [0, 25]})");
  ASSERT_TRUE(spec.ok());
  expect_error(resolve_edit(*spec, grid_.V), ErrorCode::InvalidArgument,
               {"fixed[1]", "vertex 25", "#V=25"});
  spec = parse_edit_spec(R"({"handles": [{"vertices": [1, -3], "translation": [0,0,1]}]})");
  ASSERT_TRUE(spec.ok());
  expect_error(resolve_edit(*spec, grid_.V), ErrorCode::InvalidArgument,
               {"handles[0].vertices[1]", "-3"});
}

TEST_F(EditSpecTest, RejectsVertexInTwoGroups) {
  auto spec = parse_edit_spec(
      R"({"fixed": [5], "handles": [{"vertices": [1, 5], "translation": [0,0,1]}]})");
  ASSERT_TRUE(spec.ok());
  expect_error(resolve_edit(*spec, grid_.V), ErrorCode::InvalidArgument,
               {"vertex 5", "fixed", "handles[0]"});
  spec = parse_edit_spec(R"({"handles": [{"vertices": [2], "translation": [0,0,1]},
                                         {"vertices": [2], "translation": [0,0,2]}]})");
  ASSERT_TRUE(spec.ok());
  expect_error(resolve_edit(*spec, grid_.V), ErrorCode::InvalidArgument,
               {"vertex 2", "handles[0]", "handles[1]"});
}

TEST_F(EditSpecTest, RejectsConflictingTargetsForRepeatedVertex) {
  const auto spec =
      parse_edit_spec(R"({"handles": [{"vertices": [2, 2], "targets": [[0,0,0],[1,1,1]]}]})");
  ASSERT_TRUE(spec.ok());
  expect_error(resolve_edit(*spec, grid_.V), ErrorCode::InvalidArgument,
               {"handles[0]", "vertex 2", "twice"});
}

TEST_F(EditSpecTest, RejectsNoConstrainedVertices) {
  const auto spec = parse_edit_spec(R"({"fixed": [], "options": {"iterations": 3}})");
  ASSERT_TRUE(spec.ok());
  expect_error(resolve_edit(*spec, grid_.V), ErrorCode::InvalidArgument,
               {"constrains no vertices"});
}

TEST_F(EditSpecTest, RejectsNonAffineMatrix) {
  const auto spec = parse_edit_spec(
      R"({"handles": [{"vertices": [3], "matrix": [1,0,0,0, 0,1,0,0, 0,0,1,0, 0,0,1,1]}]})");
  ASSERT_TRUE(spec.ok());
  expect_error(resolve_edit(*spec, grid_.V), ErrorCode::InvalidArgument,
               {"handles[0].matrix", "affine"});
}

TEST(EditSpecParseTest, RejectsWrongArrayLengthsNamingKey) {
  expect_error(parse_edit_spec(R"({"handles": [{"vertices": [1], "translation": [0, 1]}]})"),
               ErrorCode::InvalidArgument, {"handles[0].translation", "3 numbers", "got 2"});
  expect_error(parse_edit_spec(R"({"handles": [{"vertices": [1], "matrix": [1, 0, 0]}]})"),
               ErrorCode::InvalidArgument, {"handles[0].matrix", "16"});
  expect_error(parse_edit_spec(R"({"handles": [{"vertices": [1, 2], "targets": [[0, 0, 0]]}]})"),
               ErrorCode::InvalidArgument, {"handles[0].targets", "expected 2", "got 1"});
  expect_error(parse_edit_spec(R"({"handles": [{"vertices": [1], "quaternion": [1, 0, 0]}]})"),
               ErrorCode::InvalidArgument, {"handles[0].quaternion", "4 numbers"});
  expect_error(parse_edit_spec(R"({"handles": [{"vertices": [1], "targets": [[0, 0]]}]})"),
               ErrorCode::InvalidArgument, {"handles[0].targets[0]", "3 numbers"});
}

TEST(EditSpecParseTest, RejectsNonFiniteNumbers) {
  // JSON has no NaN/Infinity literal and nlohmann rejects overflowing literals while parsing.
  expect_error(parse_edit_spec(R"({"handles": [{"vertices": [1], "translation": [0, 1e999, 0]}]})"),
               ErrorCode::InvalidArgument, {"not valid JSON", "1e999"});
}

TEST(EditSpecParseTest, ResolveRejectsNonFiniteValuesOfProgrammaticSpecs) {
  const MeshData grid = test::make_grid(2);
  EditSpec spec;
  HandleMotion g;
  g.vertices = {0, 1};
  g.translation.y() = std::numeric_limits<double>::infinity();
  spec.handles = {g};
  expect_error(resolve_edit(spec, grid.V), ErrorCode::InvalidArgument,
               {"handles[0].translation", "not finite"});

  g.translation.y() = 0.0;
  g.form = HandleForm::Targets;
  g.targets = Positions::Zero(2, 3);
  g.targets(1, 2) = std::nan("");
  spec.handles = {g};
  expect_error(resolve_edit(spec, grid.V), ErrorCode::InvalidArgument,
               {"handles[0]", "vertex 1", "not finite"});
}

TEST(EditSpecParseTest, RejectsTypeErrorsAndStructure) {
  expect_error(parse_edit_spec(R"({"fixed": [1, 2.5]})"), ErrorCode::InvalidArgument,
               {"fixed[1]", "integer"});
  expect_error(parse_edit_spec(R"({"fixed": [1, 3000000000]})"), ErrorCode::InvalidArgument,
               {"fixed[1]", "does not fit"});
  expect_error(parse_edit_spec(R"({"handles": [{"vertices": [1]}]})"), ErrorCode::InvalidArgument,
               {"handles[0]", "needs one of"});
  expect_error(
      parse_edit_spec(
          R"({"handles": [{"vertices": [1], "translation": [0,0,0], "targets": [[0,0,0]]}]})"),
      ErrorCode::InvalidArgument, {"handles[0]", "exactly one"});
  expect_error(parse_edit_spec(
                   R"({"handles": [{"vertices": [1], "rotation": {"axis": [0,0,1], "angle_deg": 1},
                                                 "quaternion": [1,0,0,0]}]})"),
               ErrorCode::InvalidArgument, {"handles[0]", "not both"});
  expect_error(parse_edit_spec(R"({"handles": [{"vertices": [], "translation": [0,0,0]}]})"),
               ErrorCode::InvalidArgument, {"handles[0].vertices", "empty"});
  expect_error(parse_edit_spec(R"({"handles": [{"vertices": [1], "translaton": [0,0,0]}]})"),
               ErrorCode::InvalidArgument, {"handles[0]", "unknown key 'translaton'"});
  expect_error(
      parse_edit_spec(
          R"({"handles": [{"vertices": [1], "rotation": {"axis": [0,0,0], "angle_deg": 5}}]})"),
      ErrorCode::InvalidArgument, {"handles[0].rotation.axis", "zero"});
  expect_error(parse_edit_spec(R"({"options": {"iterations": 0}})"), ErrorCode::InvalidArgument,
               {"options.iterations", ">= 1"});
  expect_error(parse_edit_spec(R"({"options": {"tolerance": -1}})"), ErrorCode::InvalidArgument,
               {"options.tolerance", "> 0"});
  expect_error(parse_edit_spec(R"([1, 2])"), ErrorCode::InvalidArgument, {"JSON object"});
  expect_error(parse_edit_spec(R"({"fixed": [1, 2)"), ErrorCode::InvalidArgument,
               {"not valid JSON"});
  expect_error(parse_edit_spec(""), ErrorCode::InvalidArgument, {"not valid JSON"});
}

TEST(EditSpecParseTest, WriterRoundTripsEveryForm) {
  EditSpec spec;
  spec.fixed = {4, 1, 9};
  HandleMotion rigid;
  rigid.vertices = {10, 11};
  rigid.translation = Eigen::Vector3d(1.0 / 3.0, -2, M_PI);
  rigid.rotation = AxisAngle{Eigen::Vector3d(0, 1, 1), 33.3};
  rigid.scale = 0.75;
  rigid.pivot = Eigen::Vector3d(0.1, 0.2, 0.3);
  HandleMotion quat;
  quat.vertices = {12};
  quat.quaternion = Eigen::Vector4d(0.5, 0.5, 0.5, 0.5);
  HandleMotion matrix;
  matrix.form = HandleForm::Matrix;
  matrix.vertices = {13, 14};
  matrix.matrix.topRightCorner<3, 1>() << 1e-300, 2, 3;
  HandleMotion targets;
  targets.form = HandleForm::Targets;
  targets.vertices = {15, 16};
  targets.targets.resize(2, 3);
  targets.targets << 1, 2, 3, 4.25, 5, 1e10;
  spec.handles = {rigid, quat, matrix, targets};
  spec.options.tolerance = 1e-7;

  const auto text = format_edit_spec(spec);
  ASSERT_TRUE(text.ok()) << message_of(text);
  const auto back = parse_edit_spec(*text);
  ASSERT_TRUE(back.ok()) << message_of(back) << "\n" << *text;
  EXPECT_EQ(back->fixed, spec.fixed);
  ASSERT_EQ(back->handles.size(), 4U);
  EXPECT_EQ(back->handles[0].form, HandleForm::Rigid);
  EXPECT_EQ(back->handles[0].vertices, rigid.vertices);
  EXPECT_EQ(back->handles[0].translation, rigid.translation);
  ASSERT_TRUE(back->handles[0].rotation.has_value());
  EXPECT_EQ(back->handles[0].rotation->axis, rigid.rotation->axis);
  EXPECT_EQ(back->handles[0].rotation->angle_deg, 33.3);
  EXPECT_EQ(back->handles[0].scale, 0.75);
  EXPECT_EQ(back->handles[0].pivot, rigid.pivot);
  EXPECT_EQ(back->handles[1].quaternion, quat.quaternion);
  EXPECT_FALSE(back->handles[1].pivot.has_value());
  EXPECT_EQ(back->handles[2].form, HandleForm::Matrix);
  EXPECT_EQ(back->handles[2].matrix, matrix.matrix);
  EXPECT_EQ(back->handles[3].form, HandleForm::Targets);
  EXPECT_EQ(back->handles[3].targets, targets.targets);
  EXPECT_EQ(back->options.tolerance, 1e-7);
  EXPECT_FALSE(back->options.iterations.has_value());

  // Resolving the original and the round-tripped spec gives identical constraints.
  const MeshData grid = test::make_grid(4);
  const auto a = resolve_edit(spec, grid.V);
  const auto b = resolve_edit(*back, grid.V);
  ASSERT_TRUE(a.ok()) << message_of(a);
  ASSERT_TRUE(b.ok()) << message_of(b);
  EXPECT_EQ(a->constrained, b->constrained);
  EXPECT_EQ(a->targets, b->targets);

  const fs::path path = temp_file("spec.json");
  ASSERT_TRUE(write_edit_spec(path, spec).ok());
  const auto from_file = read_edit_spec(path);
  fs::remove(path);
  ASSERT_TRUE(from_file.ok()) << message_of(from_file);
  EXPECT_EQ(from_file->handles.size(), 4U);
}

TEST(EditSpecParseTest, WriterRejectsNonFinite) {
  EditSpec spec;
  HandleMotion g;
  g.vertices = {0};
  g.translation.x() = std::nan("");
  spec.handles = {g};
  expect_error(format_edit_spec(spec), ErrorCode::InvalidArgument, {"handles[0]", "not finite"});
}

TEST(EditSpecParseTest, MissingFileIsNotFound) {
  expect_error(read_edit_spec(temp_file("missing.json")), ErrorCode::NotFound, {"missing.json"});
}

}  // namespace
}  // namespace meshdeform::io

namespace meshdeform::io {
namespace {

TEST(EditSpecMagnify, ParsesRoundTripsAndRejectsBadRegions) {
  auto spec = parse_edit_spec(R"({"fixed": [0, 1], "magnify": [{"vertices": [2, 3, 4], "scale": 2.5}],
                                  "options": {"method": "arap", "ora": true}})");
  ASSERT_TRUE(spec.ok()) << spec.status().to_string();
  ASSERT_EQ(spec->magnify.size(), 1u);
  EXPECT_EQ(spec->magnify[0].vertices, (std::vector<int>{2, 3, 4}));
  EXPECT_EQ(spec->magnify[0].scale, 2.5);
  EXPECT_EQ(spec->options.method, std::optional<std::string>("arap"));
  EXPECT_EQ(spec->options.ora, std::optional<bool>(true));
  auto text = format_edit_spec(*spec);
  ASSERT_TRUE(text.ok());
  auto again = parse_edit_spec(*text);
  ASSERT_TRUE(again.ok()) << again.status().to_string();
  EXPECT_EQ(again->magnify[0].vertices, spec->magnify[0].vertices);
  EXPECT_EQ(again->options.ora, spec->options.ora);

  auto zero = parse_edit_spec(R"({"magnify": [{"vertices": [1], "scale": 0}]})");
  ASSERT_FALSE(zero.ok());
  EXPECT_NE(zero.status().message().find("magnify[0].scale: must be > 0"), std::string::npos);
  auto empty = parse_edit_spec(R"({"magnify": [{"vertices": [], "scale": 2}]})");
  ASSERT_FALSE(empty.ok());
  EXPECT_NE(empty.status().message().find("magnify[0].vertices: must not be empty"),
            std::string::npos);
  auto missing = parse_edit_spec(R"({"magnify": [{"vertices": [1]}]})");
  ASSERT_FALSE(missing.ok());
  EXPECT_NE(missing.status().message().find("needs 'vertices' and 'scale'"), std::string::npos);
  auto bad_ora = parse_edit_spec(R"({"options": {"ora": 1}})");
  EXPECT_FALSE(bad_ora.ok());
}


TEST(EditSpecRigidity, ParsesRoundTripsAndRejectsBadValues) {
  auto spec = parse_edit_spec(R"({"fixed": [0, 1], "options": {"rigidity": 2.5}})");
  ASSERT_TRUE(spec.ok()) << spec.status().to_string();
  EXPECT_EQ(spec->options.rigidity, std::optional<double>(2.5));
  auto text = format_edit_spec(*spec);
  ASSERT_TRUE(text.ok());
  auto again = parse_edit_spec(*text);
  ASSERT_TRUE(again.ok()) << again.status().to_string();
  EXPECT_EQ(again->options.rigidity, spec->options.rigidity);
  auto zero = parse_edit_spec(R"({"options": {"rigidity": 0}})");
  ASSERT_TRUE(zero.ok()) << zero.status().to_string();
  EXPECT_EQ(zero->options.rigidity, std::optional<double>(0.0));
  auto absent = parse_edit_spec(R"({"fixed": [0]})");
  ASSERT_TRUE(absent.ok());
  EXPECT_FALSE(absent->options.rigidity.has_value());

  auto negative = parse_edit_spec(R"({"options": {"rigidity": -1}})");
  ASSERT_FALSE(negative.ok());
  EXPECT_NE(negative.status().message().find("options.rigidity: must be >= 0"), std::string::npos)
      << negative.status().message();
  auto text_value = parse_edit_spec(R"({"options": {"rigidity": "high"}})");
  ASSERT_FALSE(text_value.ok());
  EXPECT_NE(text_value.status().message().find("options.rigidity"), std::string::npos);
  EditSpec programmatic;
  programmatic.options.rigidity = std::nan("");
  EXPECT_FALSE(format_edit_spec(programmatic).ok());
}

}  // namespace
}  // namespace meshdeform::io
