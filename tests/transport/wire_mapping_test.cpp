// The wire mapping shared by the server's transport, the C++ client and the load tester
// (proto/wire/wire_mapping.h): every enum value both ways, every gRPC code name, unknown values.

#include "proto/wire/wire_mapping.h"

#include <gtest/gtest.h>
#include <grpcpp/support/status.h>

#include <climits>
#include <cmath>
#include <limits>
#include <set>
#include <utility>
#include <vector>

#include "server/service/types.h"
#include "server/transport/status_mapping.h"

namespace meshdeform::wire {
namespace {

TEST(WireMappingTest, EveryGrpcCodeHasItsCanonicalName) {
  const std::vector<std::pair<grpc::StatusCode, std::string_view>> codes = {
      {grpc::StatusCode::OK, "OK"},
      {grpc::StatusCode::CANCELLED, "CANCELLED"},
      {grpc::StatusCode::UNKNOWN, "UNKNOWN"},
      {grpc::StatusCode::INVALID_ARGUMENT, "INVALID_ARGUMENT"},
      {grpc::StatusCode::DEADLINE_EXCEEDED, "DEADLINE_EXCEEDED"},
      {grpc::StatusCode::NOT_FOUND, "NOT_FOUND"},
      {grpc::StatusCode::ALREADY_EXISTS, "ALREADY_EXISTS"},
      {grpc::StatusCode::PERMISSION_DENIED, "PERMISSION_DENIED"},
      {grpc::StatusCode::RESOURCE_EXHAUSTED, "RESOURCE_EXHAUSTED"},
      {grpc::StatusCode::FAILED_PRECONDITION, "FAILED_PRECONDITION"},
      {grpc::StatusCode::ABORTED, "ABORTED"},
      {grpc::StatusCode::OUT_OF_RANGE, "OUT_OF_RANGE"},
      {grpc::StatusCode::UNIMPLEMENTED, "UNIMPLEMENTED"},
      {grpc::StatusCode::INTERNAL, "INTERNAL"},
      {grpc::StatusCode::UNAVAILABLE, "UNAVAILABLE"},
      {grpc::StatusCode::DATA_LOSS, "DATA_LOSS"},
      {grpc::StatusCode::UNAUTHENTICATED, "UNAUTHENTICATED"},
  };
  ASSERT_EQ(codes.size(), static_cast<std::size_t>(kGrpcCodeCount));
  for (const auto& [code, name] : codes) {
    SCOPED_TRACE(name);
    const int value = static_cast<int>(code);
    EXPECT_EQ(grpc_code_name(value), std::optional<std::string_view>(name));
    EXPECT_EQ(grpc_code_label(value), name);
    EXPECT_EQ(transport::grpc_code_name(code), name);  // the server's metrics label
  }
}

TEST(WireMappingTest, CodesWithoutANameAreRejected) {
  for (const int code : {-1, kGrpcCodeCount, 99, INT_MIN, INT_MAX}) {
    SCOPED_TRACE(code);
    EXPECT_EQ(grpc_code_name(code), std::nullopt);
    EXPECT_EQ(grpc_code_label(code), "CODE_" + std::to_string(code));
  }
  // The server reports DO_NOT_USE (-1) and out-of-range values as UNKNOWN.
  EXPECT_EQ(transport::grpc_code_name(grpc::StatusCode::DO_NOT_USE), "UNKNOWN");
  // 20: unnamed, yet inside the enumeration's range (its enumerators -1..16 fit in 6 signed
  // bits, so -32..31), where the cast is defined; 40 would be undefined behaviour.
  EXPECT_EQ(transport::grpc_code_name(static_cast<grpc::StatusCode>(20)), "UNKNOWN");
}

/// Every C++ value in `values` maps to a distinct wire value that maps back to it; every value the
/// .proto names (`names`) is read: UNSPECIFIED (0) as nullopt, the others back to themselves.
template <typename Cpp, typename Wire, typename ToWire, typename FromWire>
void expect_round_trips(const std::vector<Cpp>& values, const google::protobuf::EnumDescriptor* names,
                        ToWire to_wire, FromWire from_wire) {
  std::set<int> wire_values;
  for (const Cpp value : values) {
    const Wire on_wire = to_wire(value);
    EXPECT_NE(static_cast<int>(on_wire), 0) << "mapped to UNSPECIFIED";
    wire_values.insert(static_cast<int>(on_wire));
    const Result<std::optional<Cpp>> back = from_wire(on_wire);
    ASSERT_TRUE(back.ok()) << back.status().to_string();
    EXPECT_EQ(*back, std::optional<Cpp>(value));
  }
  EXPECT_EQ(wire_values.size(), values.size()) << "two values share a wire value";
  EXPECT_EQ(names->value_count(), static_cast<int>(values.size()) + 1);
  for (int i = 0; i < names->value_count(); ++i) {
    const auto value = static_cast<Wire>(names->value(i)->number());
    SCOPED_TRACE(names->value(i)->name());
    const Result<std::optional<Cpp>> read = from_wire(value);
    ASSERT_TRUE(read.ok()) << read.status().to_string();
    if (static_cast<int>(value) == 0) {
      EXPECT_EQ(*read, std::nullopt);
    } else {
      ASSERT_TRUE(read->has_value());
      EXPECT_EQ(to_wire(**read), value);
    }
  }
}

TEST(WireMappingTest, EveryMethodRoundTrips) {
  expect_round_trips<core::Method, v1::Method>(
      {core::Method::ScaleAware, core::Method::Arap, core::Method::Laplacian},
      v1::Method_descriptor(), method_to_proto<core::Method>, method_from_proto);
}

TEST(WireMappingTest, UnknownMethodIsRejected) {
  const Result<std::optional<core::Method>> read = method_from_proto(static_cast<v1::Method>(99));
  ASSERT_FALSE(read.ok());
  EXPECT_EQ(read.status().code(), ErrorCode::InvalidArgument);
  EXPECT_EQ(read.status().message(), "unknown method 99");
  EXPECT_FALSE(method_from_proto(static_cast<v1::Method>(-3)).ok());
}

TEST(WireMappingTest, EveryMeshFormatRoundTrips) {
  expect_round_trips<io::MeshFormat, v1::MeshFormat>(
      {io::MeshFormat::Obj, io::MeshFormat::Off, io::MeshFormat::Ply, io::MeshFormat::Stl,
       io::MeshFormat::Glb, io::MeshFormat::Gltf},
      v1::MeshFormat_descriptor(), format_to_proto, format_from_proto);
}

TEST(WireMappingTest, UnknownMeshFormatIsRejected) {
  const Result<std::optional<io::MeshFormat>> read =
      format_from_proto(static_cast<v1::MeshFormat>(42));
  ASSERT_FALSE(read.ok());
  EXPECT_EQ(read.status().code(), ErrorCode::InvalidArgument);
  EXPECT_EQ(read.status().message(), "unknown format 42");
}

TEST(WireMappingTest, EveryHistoryActionRoundTripsAndUnknownOnesAreRejected) {
  for (const service::HistoryAction action : {service::HistoryAction::Record,
                                              service::HistoryAction::Undo,
                                              service::HistoryAction::Redo}) {
    EXPECT_EQ(history_from_proto(history_to_proto(action)), action);
  }
  EXPECT_EQ(history_to_proto(service::HistoryAction::Record), v1::HISTORY_ACTION_UNSPECIFIED);
  EXPECT_EQ(history_from_proto(static_cast<v1::HistoryAction>(9)),
            std::nullopt);
}

TEST(WireMappingTest, EveryHandleRoleRoundTripsAndUnknownRolesAreRejected) {
  using service::HandleRole;
  for (const HandleRole role : {HandleRole::Fixed, HandleRole::Handle}) {
    EXPECT_EQ(role_from_proto(role_to_proto(role)), std::optional<HandleRole>(role));
  }
  EXPECT_EQ(role_to_proto(HandleRole::Fixed), v1::HANDLE_ROLE_FIXED);
  EXPECT_EQ(role_to_proto(HandleRole::Handle), v1::HANDLE_ROLE_HANDLE);
  EXPECT_EQ(role_from_proto(v1::HANDLE_ROLE_UNSPECIFIED), std::nullopt);
  EXPECT_EQ(role_from_proto(static_cast<v1::HandleRole>(7)), std::nullopt);
}

TEST(WireMappingTest, VectorsAndQuaternionsRoundTripBitForBit) {
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const Eigen::Vector3d v(1.5, -0.0, 1e300);
  v1::Vec3 on_wire;
  vec_to_proto(v, &on_wire);
  EXPECT_EQ(on_wire.x(), 1.5);
  EXPECT_TRUE(std::signbit(on_wire.y()));
  EXPECT_EQ(on_wire.z(), 1e300);
  EXPECT_EQ(vec_from_proto(on_wire), v);
  // No checks here: a NaN passes through for the caller to judge.
  on_wire.set_y(nan);
  EXPECT_TRUE(std::isnan(vec_from_proto(on_wire).y()));

  const Eigen::Quaterniond q(0.5, -0.25, 0.75, 2.0);  // (w, x, y, z), not normalised
  v1::Quaternion q_wire;
  quat_to_proto(q, &q_wire);
  EXPECT_EQ(q_wire.w(), 0.5);
  EXPECT_EQ(q_wire.x(), -0.25);
  EXPECT_EQ(q_wire.y(), 0.75);
  EXPECT_EQ(q_wire.z(), 2.0);
  EXPECT_EQ(quat_from_proto(q_wire).coeffs(), q.coeffs());
}

TEST(WireMappingTest, IndicesAboveIntMaxAreRejectedWithTheirPosition) {
  google::protobuf::RepeatedField<std::uint32_t> in;
  in.Add(0);
  in.Add(static_cast<std::uint32_t>(INT_MAX));
  std::optional<std::vector<int>> read = indices_from_proto(in);
  ASSERT_TRUE(read.has_value());
  EXPECT_EQ(*read, (std::vector<int>{0, INT_MAX}));
  EXPECT_EQ(index_from_proto(static_cast<std::uint32_t>(INT_MAX)), std::optional<int>(INT_MAX));

  const std::uint32_t too_big = static_cast<std::uint32_t>(INT_MAX) + 1u;
  EXPECT_EQ(index_from_proto(too_big), std::nullopt);
  in.Add(too_big);
  in.Add(3);
  int bad = -1;
  EXPECT_EQ(indices_from_proto(in, &bad), std::nullopt);
  EXPECT_EQ(bad, 2);
}

TEST(WireMappingTest, IndexListsRoundTripAndStopAtANegativeIndex) {
  google::protobuf::RepeatedField<std::uint32_t> out;
  EXPECT_EQ(indices_to_proto({4, 0, 7}, &out), std::nullopt);
  EXPECT_EQ(indices_from_proto(out), (std::vector<int>{4, 0, 7}));

  google::protobuf::RepeatedField<std::uint32_t> partial;
  EXPECT_EQ(indices_to_proto({1, -2, 3}, &partial), std::optional<std::size_t>(1));
  ASSERT_EQ(partial.size(), 1);
  EXPECT_EQ(partial.Get(0), 1u);
}

TEST(WireMappingTest, PositionRowsRoundTripAndNeedThreeValuesPerRow) {
  Positions rows(2, 3);
  rows << 1, 2, 3, -4, 5.5, 1e-300;
  google::protobuf::RepeatedField<double> flat;
  rows_to_proto(rows, &flat);
  ASSERT_EQ(flat.size(), 6);
  EXPECT_EQ(flat.Get(3), -4.0);
  const std::optional<Positions> back = rows_from_proto(flat);
  ASSERT_TRUE(back.has_value());
  EXPECT_EQ(*back, rows);
  rows_to_proto(Positions(0, 3), &flat);  // replaces, does not append
  EXPECT_EQ(flat.size(), 0);

  google::protobuf::RepeatedField<double> ragged;
  for (int i = 0; i < 4; ++i) ragged.Add(i);
  EXPECT_EQ(rows_from_proto(ragged), std::nullopt);
}

TEST(WireMappingTest, GroupMovesRoundTripAndAbsentFieldsAreDefaults) {
  service::GroupMove move;
  move.group = 3;
  move.translation = Eigen::Vector3d(1, 2, 3);
  move.rotation = Eigen::Quaterniond(0, 1, 0, 0);
  move.scale = 2.5;
  move.pivot = Eigen::Vector3d(-1, 0, 4);
  v1::GroupMove on_wire;
  group_move_to_proto(move, &on_wire);
  EXPECT_EQ(on_wire.group(), 3u);
  EXPECT_TRUE(on_wire.has_scale());
  EXPECT_TRUE(on_wire.has_pivot());
  const auto back = group_move_from_proto(on_wire);
  EXPECT_EQ(back.group, 3);
  EXPECT_EQ(back.translation, move.translation);
  EXPECT_EQ(back.rotation.coeffs(), move.rotation.coeffs());
  EXPECT_EQ(back.scale, 2.5);
  EXPECT_EQ(back.pivot, move.pivot);

  move.pivot.reset();
  v1::GroupMove no_pivot;
  group_move_to_proto(move, &no_pivot);
  EXPECT_FALSE(no_pivot.has_pivot());

  v1::GroupMove bare;
  bare.set_group(1);
  const auto defaults = group_move_from_proto(bare);
  EXPECT_EQ(defaults.group, 1);
  EXPECT_EQ(defaults.translation, Eigen::Vector3d::Zero());
  EXPECT_EQ(defaults.rotation.coeffs(), Eigen::Quaterniond::Identity().coeffs());
  EXPECT_EQ(defaults.scale, 1.0);
  EXPECT_FALSE(defaults.pivot.has_value());
}

}  // namespace
}  // namespace meshdeform::wire
