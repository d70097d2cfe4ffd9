// Session state files (server/service/persistence.h): format round trip and corruption
// detection, and a service restarted on the same state directory resuming every session at its
// last committed revision.
#include "server/service/persistence.h"

#include <gtest/gtest.h>
#include <sys/stat.h>
#include <utime.h>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <random>
#include <string>

#include "core/io/mesh_io.h"
#include "server/service/deformation_service.h"
#include "tests/support/mesh_factories.h"

namespace meshdeform::service {
namespace {

namespace fs = std::filesystem;

/// A fresh empty directory under the system temp dir, removed at the end of the test.
class TempDir {
 public:
  TempDir() {
    std::random_device random;
    path_ = fs::temp_directory_path() / ("meshdeform-state-" + std::to_string(random()) +
                                         std::to_string(random()));
    fs::create_directories(path_);
  }
  ~TempDir() {
    std::error_code ignored;
    fs::remove_all(path_, ignored);
  }
  std::string str() const { return path_.string(); }
  fs::path file_of(const SessionId& id) const { return path_ / (id.value + ".state"); }

 private:
  fs::path path_;
};

PersistedSession small_state() {
  PersistedSession s;
  s.id = SessionId{"0123456789abcdef0123456789abcdef"};
  s.edit_token = Token{std::string(64, 'e')};
  s.view_token = Token{std::string(64, 'v')};
  s.lambda = 50;
  s.rest = test::make_grid(3, 0.1);
  s.groups = {HandleGroup{HandleRole::Fixed, {0, 1}}, HandleGroup{HandleRole::Handle, {14, 15}}};
  s.anchors = Positions(4, 3);
  s.anchors << 0, 0, 0, 1, 0, 0, 2, 3, 0, 3, 3, 0;
  s.targets = s.anchors;
  s.targets(2, 2) = 0.5;
  s.positions = s.rest.V;
  s.positions(14, 2) = 0.25;
  s.revision = 17;
  s.last_method = core::Method::Arap;
  return s;
}

ServiceOptions options_with(const std::string& dir) {
  ServiceOptions options;
  options.workers = 2;
  options.state_dir = dir;
  return options;
}

MoveRequest lift(double z) {
  MoveRequest move;
  GroupMove g;
  g.group = 1;
  g.translation = Eigen::Vector3d(0, 0, z);
  move.moves.push_back(g);
  return move;
}

Positions positions_at(DeformationService& service, const CreatedSession& created) {
  Result<std::string> obj =
      service.get_mesh(created.id, created.view_token, io::MeshFormat::Obj);
  EXPECT_TRUE(obj.ok()) << obj.status().to_string();
  Result<io::LoadedMesh> mesh = io::load_mesh_from_memory(obj.ok() ? *obj : "", io::MeshFormat::Obj);
  EXPECT_TRUE(mesh.ok());
  return mesh.ok() ? mesh->mesh.V : Positions();
}

TEST(PersistenceFormatTest, RoundTripsExactly) {
  const PersistedSession s = small_state();
  Result<PersistedSession> back = decode_session(encode_session(s));
  ASSERT_TRUE(back.ok()) << back.status().to_string();
  EXPECT_EQ(back->id.value, s.id.value);
  EXPECT_EQ(back->edit_token.value, s.edit_token.value);
  EXPECT_EQ(back->view_token.value, s.view_token.value);
  EXPECT_EQ(back->lambda, s.lambda);
  EXPECT_EQ(back->rest.V, s.rest.V);
  EXPECT_EQ(back->rest.F, s.rest.F);
  ASSERT_EQ(back->groups.size(), 2u);
  EXPECT_EQ(back->groups[1].vertices, s.groups[1].vertices);
  EXPECT_EQ(back->groups[0].role, HandleRole::Fixed);
  EXPECT_EQ(back->anchors, s.anchors);
  EXPECT_EQ(back->targets, s.targets);
  EXPECT_EQ(back->positions, s.positions);
  EXPECT_EQ(back->revision, 17u);
  EXPECT_EQ(back->last_method, core::Method::Arap);
}

TEST(PersistenceFormatTest, EveryTruncationAndEveryFlippedByteIsDetected) {
  const std::string bytes = encode_session(small_state());
  for (std::size_t n = 0; n < bytes.size(); ++n) {
    EXPECT_FALSE(decode_session(std::string_view(bytes).substr(0, n)).ok()) << "prefix " << n;
  }
  for (std::size_t i = 0; i < bytes.size(); ++i) {
    std::string flipped = bytes;
    flipped[i] = static_cast<char>(flipped[i] ^ 0x10);
    EXPECT_FALSE(decode_session(flipped).ok()) << "byte " << i;
  }
  EXPECT_FALSE(decode_session(bytes + "x").ok());
}

TEST(PersistenceTest, RestartResumesAtTheLastCommittedRevision) {
  TempDir dir;
  CreatedSession created;
  Positions last;
  std::vector<HandleGroup> groups;
  {
    DeformationService service(options_with(dir.str()));
    CreateSessionRequest request;
    request.sample = "cylinder_small";
    Result<CreatedSession> made = service.create_session(request);
    ASSERT_TRUE(made.ok());
    created = *made;
    groups = created.suggested_groups;
    ASSERT_TRUE(service.set_handles(created.id, created.edit_token,
                                    SetHandlesRequest{groups, core::Method::ScaleAware})
                    .ok());
    for (int step = 1; step <= 3; ++step) {
      Result<DeformResult> moved = service.move_handles(created.id, created.edit_token, lift(0.1 * step));
      ASSERT_TRUE(moved.ok()) << moved.status().to_string();
      last = *moved->positions;
    }
    EXPECT_EQ(service.stats().persist_failures, 0u);
  }
  struct stat file_info {};
  ASSERT_EQ(stat(dir.file_of(created.id).c_str(), &file_info), 0);
  EXPECT_EQ(file_info.st_mode & 0777, 0600u) << "state files hold tokens";

  DeformationService restarted(options_with(dir.str()));
  EXPECT_EQ(restarted.stats().sessions, 0u);  // loaded on first use
  EXPECT_EQ(restarted.session_info(created.id, Token{"wrong"}).status().code(),
            ErrorCode::PermissionDenied);
  Result<SessionInfo> info = restarted.session_info(created.id, created.view_token);
  ASSERT_TRUE(info.ok()) << info.status().to_string();
  EXPECT_EQ(info->revision, 3u);
  ASSERT_EQ(info->groups.size(), groups.size());
  EXPECT_EQ(info->groups[1].vertices, groups[1].vertices);
  EXPECT_EQ(info->last_method, core::Method::ScaleAware);
  EXPECT_EQ(positions_at(restarted, created), last);  // OBJ keeps full double precision
  EXPECT_EQ(restarted.stats().sessions_restored, 1u);
  // Editing goes on: the factorization is rebuilt, the revision continues.
  Result<DeformResult> moved = restarted.move_handles(created.id, created.edit_token, lift(0.4));
  ASSERT_TRUE(moved.ok()) << moved.status().to_string();
  EXPECT_EQ(moved->revision, 4u);
  EXPECT_TRUE(moved->built_deformer);
  // Closing removes the file.
  ASSERT_TRUE(restarted.close_session(created.id, created.edit_token).ok());
  EXPECT_FALSE(fs::exists(dir.file_of(created.id)));
}

TEST(PersistenceTest, CorruptAndExpiredFilesAreReportedAndSkipped) {
  TempDir dir;
  std::vector<CreatedSession> sessions;
  {
    DeformationService service(options_with(dir.str()));
    for (int i = 0; i < 4; ++i) {
      CreateSessionRequest request;
      request.sample = "bar_small";
      Result<CreatedSession> made = service.create_session(request);
      ASSERT_TRUE(made.ok());
      sessions.push_back(*made);
    }
  }
  // 0: truncated, 1: one byte flipped, 2: garbage; 3 stays good.
  fs::resize_file(dir.file_of(sessions[0].id), fs::file_size(dir.file_of(sessions[0].id)) / 2);
  {
    std::fstream file(dir.file_of(sessions[1].id), std::ios::in | std::ios::out | std::ios::binary);
    file.seekp(100);
    file.put('\x7f');
  }
  {
    std::ofstream file(dir.file_of(sessions[2].id), std::ios::binary | std::ios::trunc);
    file << "not a state file";
  }
  {
    DeformationService restarted(options_with(dir.str()));
    EXPECT_EQ(restarted.stats().state_files_corrupt, 3u);
    for (int i = 0; i < 3; ++i) {
      EXPECT_EQ(restarted.session_info(sessions[i].id, sessions[i].view_token).status().code(),
                ErrorCode::NotFound)
          << i;
    }
    EXPECT_TRUE(restarted.session_info(sessions[3].id, sessions[3].view_token).ok());
  }
  // A file older than the idle TTL is an expired session: not restored, removed.
  ServiceOptions short_ttl = options_with(dir.str());
  short_ttl.idle_ttl = std::chrono::seconds(60);
  const std::string old_file = dir.file_of(sessions[3].id).string();
  utimbuf old_times{std::time(nullptr) - 3600, std::time(nullptr) - 3600};
  ASSERT_EQ(utime(old_file.c_str(), &old_times), 0);
  DeformationService later(short_ttl);
  EXPECT_EQ(later.session_info(sessions[3].id, sessions[3].view_token).status().code(),
            ErrorCode::NotFound);
  EXPECT_FALSE(fs::exists(old_file));
  // Ids that are not ours never name a file.
  EXPECT_EQ(later.session_info(SessionId{"../../etc/passwd"}, Token{"x"}).status().code(),
            ErrorCode::NotFound);
}

TEST(PersistenceTest, UnusableStateDirectoryIsAClearError) {
  TempDir dir;
  const std::string file = dir.str() + "/plain-file";
  std::ofstream(file) << "x";
  Result<StateDirectory> opened = StateDirectory::open(file);
  ASSERT_FALSE(opened.ok());
  EXPECT_NE(opened.status().message().find(file), std::string::npos);
  EXPECT_FALSE(StateDirectory::open("").ok());
}

TEST(PersistenceTest, ReplicasSharingTheDirectoryNeverServeAStaleCopy) {
  // Two services on one state directory play two replicas behind a balancer: A creates and
  // edits, the session fails over to B, B edits, then it comes back to A, which still holds its
  // old copy in memory. A must serve (and continue) B's newer revision, never its own stale one.
  TempDir dir;
  DeformationService a(options_with(dir.str()));
  DeformationService b(options_with(dir.str()));
  CreateSessionRequest request;
  request.sample = "cylinder_small";
  Result<CreatedSession> made = a.create_session(request);
  ASSERT_TRUE(made.ok());
  const CreatedSession created = *made;
  ASSERT_TRUE(a.set_handles(created.id, created.edit_token,
                            SetHandlesRequest{created.suggested_groups, core::Method::ScaleAware})
                  .ok());
  ASSERT_TRUE(a.move_handles(created.id, created.edit_token, lift(0.1)).ok());

  Result<DeformResult> on_b = b.move_handles(created.id, created.edit_token, lift(0.2));
  ASSERT_TRUE(on_b.ok()) << on_b.status().to_string();
  EXPECT_EQ(on_b->revision, 2u);
  on_b = b.move_handles(created.id, created.edit_token, lift(0.3));
  ASSERT_TRUE(on_b.ok());
  EXPECT_EQ(on_b->revision, 3u);

  // Back on A: reads and edits see B's revision 3.
  Result<SessionInfo> info = a.session_info(created.id, created.view_token);
  ASSERT_TRUE(info.ok()) << info.status().to_string();
  EXPECT_EQ(info->revision, 3u);
  EXPECT_EQ(positions_at(a, created), *on_b->positions);
  EXPECT_EQ(a.stats().stale_copies_dropped, 1u);
  Result<DeformResult> on_a = a.move_handles(created.id, created.edit_token, lift(0.4));
  ASSERT_TRUE(on_a.ok()) << on_a.status().to_string();
  EXPECT_EQ(on_a->revision, 4u);

  // B's copy is stale now; closing it on A removes the file, and B answers NotFound.
  ASSERT_TRUE(a.close_session(created.id, created.edit_token).ok());
  EXPECT_EQ(b.session_info(created.id, created.view_token).status().code(), ErrorCode::NotFound);
  EXPECT_EQ(b.move_handles(created.id, created.edit_token, lift(0.5)).status().code(),
            ErrorCode::NotFound);
}

}  // namespace
}  // namespace meshdeform::service
