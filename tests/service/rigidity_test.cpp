// Scale control through the service (issue 12): a session default (CreateSessionRequest) and a
// per-move value (MoveRequest), range-checked by the service, reported with every result and
// carried into background refinement.

#include <gtest/gtest.h>

#include <cmath>
#include <initializer_list>
#include <string>

#include "server/service/deformation_service.h"

namespace meshdeform::service {
namespace {

ServiceOptions options() {
  ServiceOptions o;
  o.workers = 2;
  o.create_rate = {};
  return o;
}

struct Prepared {
  CreatedSession created;
};

Prepared prepare(DeformationService& service, std::optional<double> rigidity = {}) {
  CreateSessionRequest request;
  request.sample = "cylinder_small";
  request.rigidity = rigidity;
  Result<CreatedSession> created = service.create_session(request);
  EXPECT_TRUE(created.ok()) << created.status().to_string();
  SetHandlesRequest handles{created->suggested_groups, core::Method::ScaleAware, "test"};
  EXPECT_TRUE(service.set_handles(created->id, created->edit_token, handles).ok());
  return {*created};
}

MoveRequest stretch(std::optional<double> rigidity, int iterations = 8) {
  MoveRequest move;
  GroupMove g;
  g.group = 1;
  g.translation = Eigen::Vector3d(0, 0, 0.3);  // pull the handle away from the fixed end
  move.moves.push_back(g);
  move.max_iterations = iterations;
  move.rigidity = rigidity;
  return move;
}

TEST(RigidityServiceTest, SessionDefaultAndPerMoveValuesAreUsedAndReported) {
  DeformationService service(options());
  const Prepared p = prepare(service, 0.5);
  Result<SessionInfo> info = service.session_info(p.created.id, p.created.view_token);
  ASSERT_TRUE(info.ok());
  EXPECT_EQ(info->rigidity, 0.5);
  Result<DeformResult> by_default = service.move_handles(p.created.id, p.created.edit_token,
                                                         stretch(std::nullopt));
  ASSERT_TRUE(by_default.ok()) << by_default.status().to_string();
  EXPECT_EQ(by_default->rigidity, 0.5);
  Result<DeformResult> explicit_value =
      service.move_handles(p.created.id, p.created.edit_token, stretch(20.0));
  ASSERT_TRUE(explicit_value.ok());
  EXPECT_EQ(explicit_value->rigidity, 20.0);
  MoveRequest arap = stretch(20.0);
  arap.method = core::Method::Arap;
  Result<DeformResult> arap_result = service.move_handles(p.created.id, p.created.edit_token, arap);
  ASSERT_TRUE(arap_result.ok());
  EXPECT_EQ(arap_result->rigidity, 0.0);  // ARAP has no scale term
}

TEST(RigidityServiceTest, TheDefaultSessionUsesTheLibraryDefault) {
  DeformationService service(options());
  const Prepared p = prepare(service);
  EXPECT_EQ(service.session_info(p.created.id, p.created.view_token)->rigidity,
            core::kDefaultRigidity);
}

TEST(RigidityServiceTest, ScaleControlReducesAreaDistortionOfAStretch) {
  DeformationService service(options());
  const Prepared pure = prepare(service);
  const Prepared rigid = prepare(service);
  Result<DeformResult> a = service.move_handles(pure.created.id, pure.created.edit_token,
                                                stretch(0.0, 15));
  Result<DeformResult> b = service.move_handles(rigid.created.id, rigid.created.edit_token,
                                                stretch(100.0, 15));
  ASSERT_TRUE(a.ok() && b.ok());
  EXPECT_LT(b->area_log_rms, a->area_log_rms) << "pure " << a->area_log_rms << ", rigid "
                                              << b->area_log_rms;
}

TEST(RigidityServiceTest, OutOfRangeValuesAreInvalidArgumentAndCommitNothing) {
  DeformationService service(options());
  const Prepared p = prepare(service);
  for (const double bad : std::initializer_list<double>{-1.0, std::nan(""), 1e9, INFINITY}) {
    Result<DeformResult> r = service.move_handles(p.created.id, p.created.edit_token, stretch(bad));
    ASSERT_FALSE(r.ok());
    EXPECT_EQ(r.status().code(), ErrorCode::InvalidArgument);
    EXPECT_NE(r.status().message().find("rigidity"), std::string::npos);
  }
  EXPECT_EQ(service.session_info(p.created.id, p.created.view_token)->revision, 0u);
  CreateSessionRequest request;
  request.sample = "bar_small";
  request.rigidity = -2.0;
  Result<CreatedSession> created = service.create_session(request);
  ASSERT_FALSE(created.ok());
  EXPECT_EQ(created.status().code(), ErrorCode::InvalidArgument);
}

}  // namespace
}  // namespace meshdeform::service
