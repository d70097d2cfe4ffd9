// Hostile input at the service (issue 11): heavy work (uploads, SetHandles precompute) is
// admitted per client and in total, runs on the pool's heavy lanes so moves keep a worker, and
// stops when its call's stop token fires. Every wait has a generous bound and a condition: no
// test depends on how fast this machine is.

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <future>
#include <mutex>
#include <stop_token>
#include <string>
#include <thread>
#include <vector>

#include <gtest/gtest.h>

#include "core/io/mesh_io.h"
#include "server/service/admission.h"
#include "server/service/deformation_service.h"
#include "server/service/worker_pool.h"
#include "tests/support/mesh_factories.h"

namespace meshdeform::service {
namespace {

using namespace std::chrono_literals;

/// A gate a task waits on until the test opens it (bounded: a stuck test fails, never hangs).
class Gate {
 public:
  void open() {
    {
      std::lock_guard lock(mutex_);
      open_ = true;
    }
    cv_.notify_all();
  }
  bool wait() {
    std::unique_lock lock(mutex_);
    return cv_.wait_for(lock, 60s, [this] { return open_; });
  }

 private:
  std::mutex mutex_;
  std::condition_variable cv_;
  bool open_ = false;
};

TEST(HeavyWorkAdmissionTest, LimitsPerClientAndInTotalAndReleasesOnDestruction) {
  HeavyWorkAdmission admission({/*per_client=*/2, /*total=*/3});
  Result<HeavyWorkAdmission::Ticket> a1 = admission.admit("a", "upload");
  Result<HeavyWorkAdmission::Ticket> a2 = admission.admit("a", "upload");
  ASSERT_TRUE(a1.ok() && a2.ok());
  Result<HeavyWorkAdmission::Ticket> a3 = admission.admit("a", "upload");
  ASSERT_FALSE(a3.ok());
  EXPECT_EQ(a3.status().code(), ErrorCode::ResourceExhausted);
  EXPECT_NE(a3.status().message().find("per client"), std::string::npos) << a3.status().message();
  Result<HeavyWorkAdmission::Ticket> b1 = admission.admit("b", "upload");
  ASSERT_TRUE(b1.ok());
  Result<HeavyWorkAdmission::Ticket> c1 = admission.admit("c", "upload");
  ASSERT_FALSE(c1.ok());  // 3 admitted in total
  EXPECT_NE(c1.status().message().find("server busy"), std::string::npos) << c1.status().message();
  EXPECT_EQ(admission.admitted(), 3);
  EXPECT_EQ(admission.rejected(), 2u);
  a1->release();
  EXPECT_EQ(admission.admitted(), 2);
  EXPECT_TRUE(admission.admit("c", "upload").ok());  // admitted, and released at once
  { HeavyWorkAdmission::Ticket moved = std::move(a2).value(); }
  EXPECT_EQ(admission.admitted(), 1);
  EXPECT_TRUE(admission.admit("a", "upload").ok());
}

TEST(WorkerPoolTest, HeavyTasksNeverTakeTheLastWorker) {
  Gate gate;
  std::atomic<int> heavy_started{0};
  std::promise<void> light_ran;
  {
    WorkerPool pool(2);
    // Declared after the pool, so destroyed before it: an early ASSERT opens the gate and the
    // pool's drain does not wait on it.
    struct OpenOnExit {
      Gate& gate;
      ~OpenOnExit() { gate.open(); }
    } open_on_exit{gate};
    EXPECT_EQ(pool.heavy_lanes(), 1);
    // Three heavy tasks that block until the gate opens: one runs, two wait.
    std::promise<void> first_started;
    for (int i = 0; i < 3; ++i) {
      pool.submit(
          [&] {
            if (heavy_started.fetch_add(1) == 0) first_started.set_value();
            gate.wait();
          },
          TaskClass::Heavy);
    }
    ASSERT_EQ(first_started.get_future().wait_for(60s), std::future_status::ready);
    pool.submit([&] { light_ran.set_value(); });
    // The light task runs on the worker heavy work may not take, while the heavy lane is busy.
    EXPECT_EQ(light_ran.get_future().wait_for(60s), std::future_status::ready);
    EXPECT_EQ(heavy_started.load(), 1);
    const QueueDepths depths = pool.depths();
    EXPECT_EQ(depths.heavy_running, 1);
    EXPECT_EQ(depths.heavy, 2u);
    gate.open();
  }  // drains the queued heavy tasks
  EXPECT_EQ(heavy_started.load(), 3);
}

TEST(WorkerPoolTest, ASingleWorkerRunsHeavyTasksToo) {
  std::atomic<int> ran{0};
  {
    WorkerPool pool(1);
    pool.submit([&] { ran.fetch_add(1); }, TaskClass::Heavy);
    pool.submit([&] { ran.fetch_add(1); });
  }
  EXPECT_EQ(ran.load(), 2);
}

ServiceOptions two_workers() {
  ServiceOptions options;
  options.workers = 2;
  options.heavy_work = {/*per_client=*/1, /*total=*/2};
  options.create_rate = {};  // unlimited: this test is about heavy work, not rates
  return options;
}

TEST(HeavyWorkServiceTest, AClientOverItsHeavyLimitIsRefusedAndOthersAreServed) {
  DeformationService service(two_workers());
  CreateSessionRequest sample;
  sample.sample = "cylinder_small";
  Result<CreatedSession> created = service.create_session(sample);
  ASSERT_TRUE(created.ok()) << created.status().to_string();
  SetHandlesRequest handles{created->suggested_groups, core::Method::ScaleAware, "editor"};
  ASSERT_TRUE(service.set_handles(created->id, created->edit_token, handles).ok());

  // The hostile client holds its one heavy slot (as a running upload would).
  Result<HeavyWorkAdmission::Ticket> held = service.heavy_work().admit("hostile", "test");
  ASSERT_TRUE(held.ok());
  CreateSessionRequest upload;
  upload.sample = "bar_small";
  upload.client = "hostile";
  std::promise<Result<CreatedSession>> refused_promise;
  service.create_session_async(upload, {}, [&](Result<CreatedSession> r) {
    refused_promise.set_value(std::move(r));
  });
  Result<CreatedSession> refused = refused_promise.get_future().get();  // at once, nothing queued
  ASSERT_FALSE(refused.ok());
  EXPECT_EQ(refused.status().code(), ErrorCode::ResourceExhausted) << refused.status().to_string();
  EXPECT_EQ(service.stats().heavy_rejected, 1u);

  // Another client's upload and the editor's move are served.
  upload.client = "friendly";
  std::promise<Result<CreatedSession>> served;
  service.create_session_async(upload, {}, [&](Result<CreatedSession> r) {
    served.set_value(std::move(r));
  });
  EXPECT_TRUE(served.get_future().get().ok());
  MoveRequest move;
  GroupMove g;
  g.group = 1;
  g.translation = Eigen::Vector3d(0.05, 0, 0);
  move.moves.push_back(g);
  EXPECT_TRUE(service.move_handles(created->id, created->edit_token, move).ok());

  // Once the slot is released the hostile client is admitted again.
  held->release();
  upload.client = "hostile";
  std::promise<Result<CreatedSession>> again;
  service.create_session_async(upload, {}, [&](Result<CreatedSession> r) {
    again.set_value(std::move(r));
  });
  EXPECT_TRUE(again.get_future().get().ok());
  EXPECT_EQ(service.stats().heavy_admitted, 0);
}

TEST(HeavyWorkServiceTest, AStoppedUploadEndsCancelledAndIsCounted) {
  DeformationService service(two_workers());
  CreateSessionRequest upload;
  upload.mesh_bytes = test::make_grid_obj_text(400);  // 160k vertices: many poll intervals of parsing
  upload.format = io::MeshFormat::Obj;
  upload.client = "c";
  std::stop_source stop;
  std::promise<Result<CreatedSession>> done;
  service.create_session_async(upload, stop.get_token(),
                               [&](Result<CreatedSession> r) { done.set_value(std::move(r)); });
  // Requested while queued or mid-parse (the parse polls every 4096 steps): either way the
  // worker stops without finishing the upload.
  stop.request_stop();
  std::future<Result<CreatedSession>> future = done.get_future();
  ASSERT_EQ(future.wait_for(60s), std::future_status::ready);
  const Result<CreatedSession> result = future.get();
  ASSERT_FALSE(result.ok());
  EXPECT_EQ(result.status().code(), ErrorCode::Cancelled) << result.status().to_string();
  const ServiceStats stats = service.stats();
  EXPECT_EQ(stats.uploads_cancelled, 1u);
  EXPECT_EQ(stats.heavy_admitted, 0);
  EXPECT_EQ(stats.sessions, 0u);
}

TEST(HeavyWorkServiceTest, SetHandlesIsAdmittedAsHeavyWorkPerClient) {
  DeformationService service(two_workers());
  CreateSessionRequest sample;
  sample.sample = "cylinder_small";
  Result<CreatedSession> created = service.create_session(sample);
  ASSERT_TRUE(created.ok());
  Result<HeavyWorkAdmission::Ticket> held = service.heavy_work().admit("busy", "test");
  ASSERT_TRUE(held.ok());
  SetHandlesRequest handles{created->suggested_groups, core::Method::ScaleAware, "busy"};
  Result<SessionInfo> refused = service.set_handles(created->id, created->edit_token, handles);
  ASSERT_FALSE(refused.ok());
  EXPECT_EQ(refused.status().code(), ErrorCode::ResourceExhausted);
  handles.client = "other";
  EXPECT_TRUE(service.set_handles(created->id, created->edit_token, handles).ok());
}

TEST(HeavyWorkServiceTest, ACancelledSetHandlesCommitsNothing) {
  DeformationService service(two_workers());
  CreateSessionRequest sample;
  sample.sample = "cylinder_small";
  Result<CreatedSession> created = service.create_session(sample);
  ASSERT_TRUE(created.ok());
  std::stop_source stop;
  stop.request_stop();
  SetHandlesRequest handles{created->suggested_groups, core::Method::ScaleAware, "c"};
  Result<SessionInfo> result =
      service.set_handles(created->id, created->edit_token, handles, stop.get_token());
  ASSERT_FALSE(result.ok());
  EXPECT_EQ(result.status().code(), ErrorCode::Cancelled);
  Result<SessionInfo> info = service.session_info(created->id, created->edit_token);
  ASSERT_TRUE(info.ok());
  EXPECT_TRUE(info->groups.empty());  // nothing was set
  EXPECT_EQ(service.stats().precomputes_cancelled, 1u);
}

}  // namespace
}  // namespace meshdeform::service
