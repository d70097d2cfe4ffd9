// Issue 15, item 5: CreateSession and SetHandles report their phases (ProgressEvent) while they
// run, in order, each from fraction 0 to 1, all before the call's result.
#include <gtest/gtest.h>

#include <algorithm>
#include <future>
#include <mutex>
#include <string>
#include <vector>

#include "server/service/deformation_service.h"

namespace meshdeform::service {
namespace {

/// Collects events; `done` marks the result's arrival so late events are caught.
struct Recorder {
  std::mutex mutex;
  std::vector<ProgressEvent> events;
  bool finished = false;
  int after_finish = 0;

  ProgressFn fn() {
    return [this](const ProgressEvent& event) {
      const std::lock_guard lock(mutex);
      if (finished) ++after_finish;
      events.push_back(event);
    };
  }
  void finish() {
    const std::lock_guard lock(mutex);
    finished = true;
  }
  /// Phase names in first-seen order.
  std::vector<std::string> phases() {
    const std::lock_guard lock(mutex);
    std::vector<std::string> out;
    for (const ProgressEvent& e : events) {
      if (std::find(out.begin(), out.end(), e.phase) == out.end()) out.push_back(e.phase);
    }
    return out;
  }
};

/// Every phase runs 0 ... 1 without going back, phases do not interleave (except "validate",
/// which a multiresolution build reports for its levels after its own mesh checks), time and
/// fractions never decrease within a phase.
void expect_well_formed(const std::vector<ProgressEvent>& events) {
  ASSERT_FALSE(events.empty());
  std::vector<std::string> closed;
  for (std::size_t i = 0; i < events.size(); ++i) {
    const ProgressEvent& e = events[i];
    EXPECT_GE(e.fraction, 0.0);
    EXPECT_LE(e.fraction, 1.0);
    EXPECT_GE(e.elapsed_seconds, 0.0);
    if (i > 0) {
      EXPECT_GE(e.elapsed_seconds, events[i - 1].elapsed_seconds) << "event " << i;
    }
    const bool starts = i == 0 || events[i - 1].phase != e.phase;
    if (starts) {
      EXPECT_EQ(e.fraction, 0.0) << e.phase << " starts at " << e.fraction;
      if (i > 0) {
        EXPECT_EQ(events[i - 1].fraction, 1.0) << events[i - 1].phase << " did not end";
        closed.push_back(events[i - 1].phase);
      }
    } else {
      EXPECT_GE(e.fraction, events[i - 1].fraction) << e.phase << " went back";
    }
  }
  EXPECT_EQ(events.back().fraction, 1.0) << events.back().phase << " did not end";
}

TEST(ProgressTest, CreateSessionReportsQueuedParseAndSessionBeforeItsResult) {
  ServiceOptions options;
  options.workers = 1;
  DeformationService service(options);
  CreateSessionRequest request;
  request.mesh_bytes =
      "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf 1 2 3\nf 2 4 3\n";
  request.format = io::MeshFormat::Obj;
  Recorder recorder;
  std::promise<Result<CreatedSession>> promise;
  service.create_session_async(
      request, {},
      [&](Result<CreatedSession> r) {
        recorder.finish();
        promise.set_value(std::move(r));
      },
      recorder.fn());
  Result<CreatedSession> created = promise.get_future().get();
  ASSERT_TRUE(created.ok()) << created.status().to_string();
  EXPECT_EQ(recorder.phases(), (std::vector<std::string>{"queued", "parse", "session"}));
  expect_well_formed(recorder.events);
  EXPECT_EQ(recorder.after_finish, 0);
}

TEST(ProgressTest, AFailedParseEndsWithoutTheSessionPhase) {
  DeformationService service(ServiceOptions{});
  CreateSessionRequest request;
  request.mesh_bytes = "v 0 0 0\nf 1 2 3\n";  // a face with missing vertices
  request.format = io::MeshFormat::Obj;
  Recorder recorder;
  Result<CreatedSession> created = service.create_session(request, {}, recorder.fn());
  ASSERT_FALSE(created.ok());
  EXPECT_EQ(created.status().code(), ErrorCode::InvalidArgument);
  EXPECT_EQ(recorder.phases(), (std::vector<std::string>{"parse"}));
}

TEST(ProgressTest, SetHandlesReportsThePrecomputePhasesAndNoneWhenCached) {
  DeformationService service(ServiceOptions{});
  CreateSessionRequest create;
  create.sample = "cylinder_small";
  Result<CreatedSession> created = service.create_session(create);
  ASSERT_TRUE(created.ok()) << created.status().to_string();
  SetHandlesRequest handles;
  handles.groups = created->suggested_groups;

  Recorder first;
  ASSERT_TRUE(service.set_handles(created->id, created->edit_token, handles, {}, first.fn()).ok());
  EXPECT_EQ(first.phases(),
            (std::vector<std::string>{"queued", "validate", "rigid_start", "step_two"}));
  expect_well_formed(first.events);

  // The same handle set again: the factorization is cached, only the queue is reported.
  Recorder again;
  ASSERT_TRUE(service.set_handles(created->id, created->edit_token, handles, {}, again.fn()).ok());
  EXPECT_EQ(again.phases(), (std::vector<std::string>{"queued"}));

  handles.prepare = core::Method::Arap;
  Recorder arap;
  ASSERT_TRUE(service.set_handles(created->id, created->edit_token, handles, {}, arap.fn()).ok());
  EXPECT_EQ(arap.phases(), (std::vector<std::string>{"queued", "factorize"}));
  expect_well_formed(arap.events);
}

TEST(ProgressTest, AMultiresolutionSessionReportsTheHierarchyPhases) {
  ServiceOptions options;
  options.multires_above = 1000;
  options.multires_coarse_vertices = 1000;
  options.refine_budget = 0;
  DeformationService service(options);
  CreateSessionRequest create;
  create.sample = "cylinder";  // 4,802 vertices
  Result<CreatedSession> created = service.create_session(create);
  ASSERT_TRUE(created.ok()) << created.status().to_string();
  SetHandlesRequest handles;
  handles.groups = created->suggested_groups;
  Recorder recorder;
  ASSERT_TRUE(
      service.set_handles(created->id, created->edit_token, handles, {}, recorder.fn()).ok());
  const std::vector<std::string> phases = recorder.phases();
  for (const char* phase : {"queued", "decimate", "prolongation", "coarse_precompute"}) {
    EXPECT_NE(std::find(phases.begin(), phases.end(), phase), phases.end()) << phase;
  }
  EXPECT_EQ(phases.front(), "queued");
  EXPECT_EQ(phases.back(), "coarse_precompute");
  EXPECT_EQ(std::find(phases.begin(), phases.end(), "fine_precompute"), phases.end())
      << "the full-resolution solver is built later, off the call";
  // Decimation reports fractions between its ends (progress of a long phase, not just 0 and 1).
  int between = 0;
  for (const ProgressEvent& e : recorder.events) {
    if (e.phase == "decimate" && e.fraction > 0 && e.fraction < 1) ++between;
  }
  EXPECT_GT(between, 0);
}

TEST(ProgressTest, ARefusedCallReportsNothing) {
  DeformationService service(ServiceOptions{});
  CreateSessionRequest create;
  create.sample = "cylinder_small";
  Result<CreatedSession> created = service.create_session(create);
  ASSERT_TRUE(created.ok());
  SetHandlesRequest handles;
  handles.groups = created->suggested_groups;
  Recorder recorder;
  Result<SessionInfo> refused = service.set_handles(created->id, created->view_token, handles, {},
                                                    recorder.fn());
  EXPECT_EQ(refused.status().code(), ErrorCode::PermissionDenied);
  EXPECT_TRUE(recorder.phases().empty());
}

}  // namespace
}  // namespace meshdeform::service
