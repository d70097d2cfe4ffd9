// Link-sized updates end to end (issue 45): the real meshdeform-server, an editor on loopback
// that asks every move for its full positions (the solver's exact doubles), and watchers through
// the link emulator (linkemu) asking for quantized or lossless deltas. Every revision a watcher
// receives is reconstructed within the stated tolerance (lossless: bit for bit), a byte budget
// is met by every update and the remainder arrives in continuations, and a watcher on a slow
// line gets the newest revision with the skipped ones counted, never a queue. Bounded waits
// only; no timing assertion.
#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <cstring>
#include <future>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "client_cpp/client.h"
#include "linkemu/link_emulator.h"
#include "tests/support/server_process.h"

namespace meshdeform::client {
namespace {

using std::chrono::milliseconds;
using std::chrono::seconds;
using Clock = std::chrono::steady_clock;

template <typename T>
std::string message_of(const Result<T>& r) {
  return r.ok() ? std::string("ok") : r.status().to_string();
}

MoveSpec bend(double angle_deg) {
  MoveSpec spec;
  GroupMove move;
  move.group = 1;
  move.rotation =
      Eigen::Quaterniond(Eigen::AngleAxisd(angle_deg * M_PI / 180.0, Eigen::Vector3d::UnitY()));
  move.translation = Eigen::Vector3d(0.002 * angle_deg, 0.0, 0.001 * angle_deg);
  spec.moves.push_back(move);
  spec.full_positions = true;  // the solver's exact doubles, to check the watchers against
  return spec;
}

double max_distance(const Positions& a, const Positions& b) {
  return (a - b).rowwise().norm().maxCoeff();
}

class LinkUpdatesTest : public ::testing::Test {
 protected:
  void SetUp() override { start_server({"--refine-budget", "0", "--workers", "2"}); }

  void start_server(const std::vector<std::string>& flags) {
    std::string error;
    server_ = test::ServerProcess::start(MESHDEFORM_SERVER_PATH, flags, error);
    ASSERT_NE(server_, nullptr) << error;
    ClientOptions direct;
    direct.target = server_->address();
    direct.default_timeout = seconds(60);
    direct.watch_timeout = seconds(180);
    Result<Client> editor = Client::connect(direct);
    ASSERT_TRUE(editor.ok()) << message_of(editor);
    editor_.emplace(std::move(editor).value());
  }

  /// A client whose every connection goes through an emulated link `spec`. Its receive window
  /// stays at gRPC's 64 KiB (ClientOptions::adaptive_receive_window false, as a remote viewer
  /// should run): HTTP/2 flow control then bounds what a stream has in flight, and the server's
  /// one-slot mailbox skips what the line cannot carry.
  Client via_link(const std::string& spec) {
    std::string error;
    const std::optional<linkemu::LinkSettings> settings = linkemu::parse_link_spec(spec, error);
    EXPECT_TRUE(settings) << error;
    links_.push_back(
        linkemu::LinkEmulator::start(settings.value_or(linkemu::LinkSettings{}), "127.0.0.1",
                                     server_->port(), error));
    EXPECT_NE(links_.back(), nullptr) << error;
    ClientOptions options;
    options.target = links_.back() ? links_.back()->address() : server_->address();
    options.default_timeout = seconds(60);
    options.watch_timeout = seconds(180);
    options.adaptive_receive_window = false;
    Result<Client> client = Client::connect(options);
    EXPECT_TRUE(client.ok()) << message_of(client);
    return std::move(client).value();
  }

  Session create_with_handles(const std::string& sample) {
    Result<Session> session = editor_->create_session_from_sample(sample);
    EXPECT_TRUE(session.ok()) << message_of(session);
    if (!session.ok()) return {};
    Result<SessionInfo> info = editor_->set_handles(session->edit(), session->suggested_groups);
    EXPECT_TRUE(info.ok()) << message_of(info);
    return *session;
  }

  /// Moves and records the revision's exact positions.
  std::uint64_t move(const Session& session, double angle_deg) {
    Result<DeformResult> result = editor_->move(session.edit(), bend(angle_deg));
    EXPECT_TRUE(result.ok()) << message_of(result);
    if (!result.ok() || !result->positions) return 0;
    const std::lock_guard lock(mutex_);
    exact_[result->revision] = *result->positions;
    return result->revision;
  }

  std::optional<Positions> exact(std::uint64_t revision) {
    const std::lock_guard lock(mutex_);
    const auto found = exact_.find(revision);
    if (found == exact_.end()) return std::nullopt;
    return found->second;
  }

  std::unique_ptr<test::ServerProcess> server_;
  std::optional<Client> editor_;
  std::vector<std::unique_ptr<linkemu::LinkEmulator>> links_;
  std::mutex mutex_;
  std::map<std::uint64_t, Positions> exact_;
};

TEST_F(LinkUpdatesTest, QuantizedDeltasThroughALinkReconstructEveryRevisionWithinTheTolerance) {
  const Session session = create_with_handles("cylinder");
  const Client watcher = via_link("20mbit,40ms");
  Result<SessionInfo> info = editor_->session_info(session.view());
  ASSERT_TRUE(info.ok());
  const double tolerance = 1e-4 * (info->bbox_max - info->bbox_min).norm();
  {
    const std::lock_guard lock(mutex_);
    ASSERT_TRUE(editor_->get_mesh(session.view()).ok());
  }
  UpdateOptions updates;
  updates.mode = UpdateOptions::Mode::Quantized;  // default tolerance: 1e-4 of the diagonal
  WatchStream stream = watcher.open_watch(session.view(), {}, updates);
  // The join update is revision 0, the rest mesh: within the tolerance of SetHandles' anchors.
  Result<std::optional<WatchUpdate>> first = stream.next();
  ASSERT_TRUE(first.ok() && first->has_value()) << message_of(first);
  ASSERT_TRUE((*first)->delta);
  EXPECT_TRUE((*first)->is_snapshot);
  EXPECT_TRUE((*first)->delta->complete());
  EXPECT_LE((*first)->delta->max_error, tolerance);
  std::size_t first_bytes = (*first)->delta->payload_bytes;
  // Lockstep: each revision is moved, then received through the link, then checked.
  std::size_t checked = 0;
  for (int step = 1; step <= 12; ++step) {
    const std::uint64_t revision = move(session, 3.0 * step);
    ASSERT_GT(revision, 0u);
    Result<std::optional<WatchUpdate>> next = stream.next();
    ASSERT_TRUE(next.ok() && next->has_value()) << message_of(next);
    const WatchUpdate& update = **next;
    ASSERT_TRUE(update.delta);
    ASSERT_EQ(update.result.revision, revision);
    EXPECT_FALSE(update.is_snapshot);
    EXPECT_EQ(update.skipped_revisions, 0u);
    EXPECT_TRUE(update.delta->complete());
    const std::optional<Positions> truth = exact(revision);
    ASSERT_TRUE(truth && update.result.positions);
    const double error = max_distance(*update.result.positions, *truth);
    EXPECT_LE(error, tolerance) << "revision " << revision;
    EXPECT_DOUBLE_EQ(update.delta->max_error, error) << "the stream reports what the client has";
    // A drag step moves most vertices by little: far fewer bytes than the join.
    EXPECT_LT(update.delta->payload_bytes, first_bytes) << "revision " << revision;
    ++checked;
  }
  EXPECT_EQ(checked, 12u);
  EXPECT_GT(links_.front()->counters().down.bytes_delivered, first_bytes);
}

TEST_F(LinkUpdatesTest, LosslessDeltasThroughALinkAreBitExact) {
  const Session session = create_with_handles("cylinder_small");
  const Client watcher = via_link("50mbit,20ms,jitter=2ms");
  UpdateOptions updates;
  updates.mode = UpdateOptions::Mode::Lossless;
  WatchStream stream = watcher.open_watch(session.view(), {}, updates);
  Result<std::optional<WatchUpdate>> first = stream.next();
  ASSERT_TRUE(first.ok() && first->has_value()) << message_of(first);
  for (int step = 1; step <= 8; ++step) {
    const std::uint64_t revision = move(session, 5.0 * step);
    Result<std::optional<WatchUpdate>> next = stream.next();
    ASSERT_TRUE(next.ok() && next->has_value()) << message_of(next);
    const WatchUpdate& update = **next;
    ASSERT_EQ(update.result.revision, revision);
    ASSERT_TRUE(update.delta && update.result.positions);
    const std::optional<Positions> truth = exact(revision);
    ASSERT_TRUE(truth);
    ASSERT_EQ(update.result.positions->rows(), truth->rows());
    EXPECT_EQ(std::memcmp(update.result.positions->data(), truth->data(),
                          sizeof(double) * static_cast<std::size_t>(truth->size())),
              0)
        << "revision " << revision << " differs";
    EXPECT_EQ(update.delta->max_error, 0.0);
  }
}

TEST_F(LinkUpdatesTest, ABudgetIsMetByEveryUpdateAndContinuationsCompleteTheRevision) {
  const Session session = create_with_handles("cylinder");
  const Client watcher = via_link("20mbit,40ms");
  Result<SessionInfo> info = editor_->session_info(session.view());
  ASSERT_TRUE(info.ok());
  const double tolerance = 1e-5 * (info->bbox_max - info->bbox_min).norm();
  const std::uint64_t last = move(session, 30.0);  // before the watch: its join is revision 1
  ASSERT_EQ(last, 1u);
  UpdateOptions updates;
  updates.mode = UpdateOptions::Mode::Quantized;
  updates.relative_tolerance = 1e-5;
  updates.max_update_bytes = 4096;
  WatchStream stream = watcher.open_watch(session.view(), {}, updates);
  int continuations = 0;
  std::optional<WatchUpdate> final_update;
  for (int i = 0; i < 400; ++i) {  // bounded: 4.8k vertices at 4 kB per update
    Result<std::optional<WatchUpdate>> next = stream.next();
    ASSERT_TRUE(next.ok() && next->has_value()) << message_of(next);
    const WatchUpdate& update = **next;
    ASSERT_TRUE(update.delta);
    EXPECT_LE(update.delta->payload_bytes, 4096u);
    EXPECT_EQ(update.result.revision, last);
    if (update.delta->continuation) ++continuations;
    const double error = max_distance(*update.result.positions, *exact(last));
    EXPECT_DOUBLE_EQ(update.delta->max_error, error);
    if (update.delta->complete()) {
      final_update = update;
      break;
    }
  }
  ASSERT_TRUE(final_update) << "the stream never completed the revision";
  EXPECT_GT(continuations, 0) << "4,802 vertices from scratch cannot fit one 4 kB update";
  EXPECT_LE(max_distance(*final_update->result.positions, *exact(last)), tolerance);
}

TEST_F(LinkUpdatesTest, ASlowWatcherGetsTheNewestRevisionAndTheSkippedOnesCounted) {
  const Session session = create_with_handles("cylinder");
  // A watcher that stops reading (a stalled viewer, or a line slower than the edits) must not
  // make the server queue revisions: its one-slot mailbox keeps the newest and counts the rest.
  // The reader holds its first update until the whole burst is acknowledged, so what the line
  // can carry meanwhile is bounded by HTTP/2 flow control (a 64 KiB window, see via_link), not by
  // how fast this machine runs the moves.
  const Client slow = via_link("2mbit,100ms");
  std::vector<WatchUpdate> received;
  std::mutex received_mutex;
  std::atomic<bool> done{false};
  std::promise<void> burst_acknowledged;
  const std::shared_future<void> burst = burst_acknowledged.get_future().share();
  UpdateOptions updates;
  updates.mode = UpdateOptions::Mode::Lossless;
  std::stop_source stop;
  std::thread reader([&] {
    CallOptions call;
    call.stop = stop.get_token();
    (void)slow.watch(
        session.view(),
        [&](const WatchUpdate& update) {
          bool first = false;
          {
            const std::lock_guard lock(received_mutex);
            received.push_back(update);
            first = received.size() == 1;
          }
          // Bounded: the burst is 30 moves of a 4.8k-vertex mesh.
          if (first) (void)burst.wait_for(seconds(300));
          return true;
        },
        call, updates);
    done = true;
  });
  // Wait for the join update, then a burst of 30 moves while the watcher does not read.
  for (int i = 0; i < 600; ++i) {
    {
      const std::lock_guard lock(received_mutex);
      if (!received.empty()) break;
    }
    std::this_thread::sleep_for(milliseconds(50));
  }
  std::uint64_t last = 0;
  for (int step = 1; step <= 30; ++step) last = move(session, 2.0 * step);
  burst_acknowledged.set_value();
  ASSERT_EQ(last, 30u);
  // Bounded wait for the last revision to arrive.
  for (int i = 0; i < 1200; ++i) {
    {
      const std::lock_guard lock(received_mutex);
      if (!received.empty() && received.back().result.revision == last) break;
    }
    std::this_thread::sleep_for(milliseconds(50));
  }
  stop.request_stop();
  reader.join();
  const std::lock_guard lock(received_mutex);
  ASSERT_FALSE(received.empty());
  ASSERT_EQ(received.back().result.revision, last);
  // Every revision is either delivered or counted as skipped, and updates come in order.
  std::uint64_t skipped = 0;
  std::uint64_t previous = received.front().result.revision;
  for (std::size_t i = 1; i < received.size(); ++i) {
    const WatchUpdate& u = received[i];
    EXPECT_GT(u.result.revision, previous);
    EXPECT_EQ(u.result.revision - previous - 1, u.skipped_revisions) << "update " << i;
    skipped += u.skipped_revisions;
    previous = u.result.revision;
  }
  EXPECT_EQ(received.size() - 1 + skipped, last - received.front().result.revision);
  EXPECT_GT(skipped, 0u) << "30 revisions were queued for a watcher that did not read";
  // The newest revision arrived exactly.
  const std::optional<Positions> truth = exact(last);
  ASSERT_TRUE(truth && received.back().result.positions);
  EXPECT_TRUE(*received.back().result.positions == *truth);
}

// UpdateOptions.lossless_settled through the link: a quantized watcher gets the settled revision
// (refinement's last: here its budget of 4 iterations ends it) lossless, equal bit for bit to a
// lossless watcher's, the drag's revisions before it quantized, and the next drag quantized
// again from it; a watcher that did not ask gets the settled revision quantized.
class SettledUpdatesTest : public LinkUpdatesTest {
 protected:
  void SetUp() override {
    start_server({"--refine-budget", "4", "--refine-delay-ms", "0", "--workers", "2"});
  }
};

TEST_F(SettledUpdatesTest, ASettledRevisionArrivesExactlyInAQuantizedStream) {
  const Session session = create_with_handles("cylinder");
  Result<SessionInfo> info = editor_->session_info(session.view());
  ASSERT_TRUE(info.ok());
  const double tolerance = 1e-4 * (info->bbox_max - info->bbox_min).norm();
  const Client watcher = via_link("20mbit,40ms");
  UpdateOptions settled_exact;
  settled_exact.mode = UpdateOptions::Mode::Quantized;
  settled_exact.lossless_settled = true;
  UpdateOptions quantized;
  quantized.mode = UpdateOptions::Mode::Quantized;
  UpdateOptions lossless;
  lossless.mode = UpdateOptions::Mode::Lossless;
  WatchStream asked = watcher.open_watch(session.view(), {}, settled_exact);
  WatchStream plain = watcher.open_watch(session.view(), {}, quantized);
  WatchStream reference = editor_->open_watch(session.view(), {}, lossless);

  // Reads a stream up to the first settled revision at or past `revision` (bounded); the
  // updates before it that were sent lossless are counted in `lossless_before`.
  const auto until_settled = [](WatchStream& stream, std::uint64_t revision,
                                int* lossless_before = nullptr) -> std::optional<WatchUpdate> {
    for (int i = 0; i < 200; ++i) {
      Result<std::optional<WatchUpdate>> next = stream.next();
      EXPECT_TRUE(next.ok() && next->has_value()) << message_of(next);
      if (!next.ok() || !next->has_value()) break;
      WatchUpdate update = std::move(**next);
      if (update.result.settled && update.result.revision >= revision) return update;
      if (lossless_before != nullptr && update.delta && update.delta->lossless) ++*lossless_before;
    }
    ADD_FAILURE() << "no settled revision at or past " << revision;
    return std::nullopt;
  };
  int lossless_before = 0;  // in the asking stream, over both drags

  for (int drag = 1; drag <= 2; ++drag) {
    SCOPED_TRACE(drag);
    // One move of a single iteration does not converge: refinement follows, and its last slice
    // (the budget) is the settled revision.
    MoveSpec spec = bend(12.0 * drag);
    spec.max_iterations = 1;
    Result<DeformResult> moved = editor_->move(session.edit(), spec);
    ASSERT_TRUE(moved.ok()) << message_of(moved);
    EXPECT_FALSE(moved->converged);
    EXPECT_FALSE(moved->settled) << "refinement follows a move that did not converge";

    const std::optional<WatchUpdate> exact_update = until_settled(reference, moved->revision);
    const std::optional<WatchUpdate> got = until_settled(asked, moved->revision, &lossless_before);
    const std::optional<WatchUpdate> other = until_settled(plain, moved->revision);
    ASSERT_TRUE(exact_update && got && other);
    ASSERT_EQ(got->result.revision, exact_update->result.revision);
    EXPECT_TRUE(got->result.refinement);
    ASSERT_TRUE(got->delta && got->result.positions && exact_update->result.positions);
    EXPECT_TRUE(got->delta->lossless);
    EXPECT_TRUE(got->delta->complete());
    const Positions& truth = *exact_update->result.positions;
    ASSERT_EQ(got->result.positions->rows(), truth.rows());
    EXPECT_EQ(std::memcmp(got->result.positions->data(), truth.data(),
                          sizeof(double) * static_cast<std::size_t>(truth.size())),
              0)
        << "the settled revision, bit for bit";
    // Without the ask: quantized, within the tolerance, not exact.
    ASSERT_TRUE(other->delta && other->result.positions);
    EXPECT_FALSE(other->delta->lossless);
    EXPECT_LE(max_distance(*other->result.positions, truth), tolerance);
    EXPECT_FALSE(*other->result.positions == truth);
  }
  // Only the join (revision 0, which nothing refines: settled) may have come lossless before.
  EXPECT_LE(lossless_before, 1);
}

// The coarse preview through the C++ client (issue 44's WatchRequest.coarse_preview): a watcher
// that asks for it gets, with each move a multiresolution session solved on its coarse level,
// that level with its mesh filled in on every update (the server sends the mesh once per
// stream), at the full result's positions; full-resolution solves (ORA) carry none, nor does a
// watcher that did not ask.
class CoarsePreviewTest : public LinkUpdatesTest {
 protected:
  // Multiresolution sessions at the samples' size, and no refinement revision in between.
  void SetUp() override {
    start_server({"--refine-delay-ms", "60000", "--multires-above", "1000",
                  "--multires-coarse-vertices", "1000", "--workers", "2"});
  }
};

TEST_F(CoarsePreviewTest, WatchersGetTheCoarseLevelOfMultiresolutionMoves) {
  const Session session = create_with_handles("cylinder");
  const Client& client = *editor_;
  Result<SessionInfo> info = client.session_info(session.view());
  ASSERT_TRUE(info.ok());
  ASSERT_GT(info->vertices, 2000) << "the sample must be above the multiresolution threshold";

  WatchOptions preview;
  preview.coarse_preview = true;
  WatchStream with = client.open_watch(session.view(), {}, preview);
  WatchStream without = client.open_watch(session.view());
  for (WatchStream* stream : {&with, &without}) {
    Result<std::optional<WatchUpdate>> join = stream->next();
    ASSERT_TRUE(join.ok() && join->has_value()) << message_of(join);
    EXPECT_FALSE((*join)->coarse) << "the rest mesh was not solved on a coarse level";
  }
  std::uint64_t key = 0;
  for (int step = 1; step <= 3; ++step) {
    SCOPED_TRACE("step " + std::to_string(step));
    MoveSpec spec = bend(15.0 * step);
    spec.ora = step == 3;  // solved at full resolution: no coarse level
    Result<DeformResult> moved = client.move(session.edit(), spec);
    ASSERT_TRUE(moved.ok() && moved->positions) << message_of(moved);
    Result<std::optional<WatchUpdate>> plain = without.next();
    ASSERT_TRUE(plain.ok() && plain->has_value()) << message_of(plain);
    EXPECT_EQ((*plain)->result.revision, moved->revision);
    EXPECT_FALSE((*plain)->coarse);
    Result<std::optional<WatchUpdate>> update = with.next();
    ASSERT_TRUE(update.ok() && update->has_value()) << message_of(update);
    ASSERT_EQ((*update)->result.revision, moved->revision);
    if (step == 3) {
      EXPECT_FALSE((*update)->coarse);
      continue;
    }
    ASSERT_TRUE((*update)->coarse);
    const CoarseLevel& coarse = *(*update)->coarse;
    const Eigen::Index nc = coarse.positions.rows();
    EXPECT_GE(nc, 3);
    EXPECT_LT(nc, info->vertices / 2);
    if (step == 1) key = coarse.key;
    EXPECT_EQ(coarse.key, key);
    // The mesh is there on every update, though the server sent it with the first only.
    ASSERT_EQ(static_cast<Eigen::Index>(coarse.to_fine.size()), nc);
    ASSERT_GT(coarse.triangles.rows(), 0);
    EXPECT_GE(coarse.triangles.minCoeff(), 0);
    EXPECT_LT(coarse.triangles.maxCoeff(), nc);
    // The prolongation keeps coarse vertices where the coarse solve put them (float32).
    int mismatches = 0;
    for (Eigen::Index i = 0; i < nc; ++i) {
      const int v = coarse.to_fine[static_cast<std::size_t>(i)];
      ASSERT_GE(v, 0);
      ASSERT_LT(v, info->vertices);
      for (int c = 0; c < 3; ++c) {
        if (coarse.positions(i, c) != static_cast<double>(static_cast<float>((*moved->positions)(v, c)))) {
          ++mismatches;
        }
      }
    }
    EXPECT_EQ(mismatches, 0);
  }
}

}  // namespace
}  // namespace meshdeform::client
