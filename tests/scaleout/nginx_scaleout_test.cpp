// Scale-out through the real nginx (issue 6): three meshdeform-server replicas on loopback share
// one --state-dir, and nginx runs the shipped docker/nginx.conf.template (rendered with loopback
// ports) in front of them. Checks, from the replicas' own structured logs:
//   (a) every session's calls land on exactly one replica, and sessions spread over replicas;
//   (b) after SIGKILL of a replica holding sessions, every session keeps going through nginx from
//       its last acknowledged revision (exact positions), the dead replica's sessions now served
//       by a survivor that restored them from the state directory;
//   (c) meshdeform-loadtest runs through nginx without an error;
// and that a browser's gRPC-Web Watch (HTTP/1.1 listener) of a session edited over gRPC reaches
// the same replica and streams each update as it comes (proxy_buffering off).
// Skipped (GTEST_SKIP) when there is no nginx binary (/usr/sbin/nginx, or $MESHDEFORM_NGINX).
// Loopback only; every call has a deadline; every loop and wait is bounded; every child process
// (replicas, nginx master and workers, the load tester) is killed in teardown, failure or not.
#include <arpa/inet.h>
#include <fcntl.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <signal.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <map>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <set>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "client_cpp/client.h"
#include "core/io/mesh_io.h"
#include "tests/support/nginx_process.h"
#include "tests/support/server_process.h"

extern char** environ;

namespace meshdeform {
namespace {

namespace fs = std::filesystem;
using test::find_nginx;
using test::NginxProcess;
using test::render_template;
using nlohmann::json;
using std::chrono::milliseconds;
using std::chrono::seconds;
using Clock = std::chrono::steady_clock;

constexpr int kReplicas = 3;
constexpr int kSessions = 12;

using test::read_text;

/// A loopback port that was free a moment ago (nginx binds it next; a lost race is retried).
int free_loopback_port() {
  const int fd = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
  if (fd < 0) return 0;
  sockaddr_in address{};
  address.sin_family = AF_INET;
  address.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  address.sin_port = 0;
  socklen_t length = sizeof address;
  int port = 0;
  if (::bind(fd, reinterpret_cast<sockaddr*>(&address), sizeof address) == 0 &&
      ::getsockname(fd, reinterpret_cast<sockaddr*>(&address), &length) == 0) {
    port = ntohs(address.sin_port);
  }
  ::close(fd);
  return port;
}

/// The structured log lines of one replica from byte `offset` on.
std::vector<json> log_events(const test::ServerProcess& server, std::size_t offset = 0) {
  std::vector<json> events;
  const std::string log = server.log();
  std::istringstream lines(offset < log.size() ? log.substr(offset) : std::string());
  for (std::string line; std::getline(lines, line);) {
    if (line.empty() || line.front() != '{') continue;
    json event = json::parse(line, nullptr, /*allow_exceptions=*/false);
    if (!event.is_discarded()) events.push_back(std::move(event));
  }
  return events;
}

/// Three replicas on one state directory and nginx in front, all on 127.0.0.1.
class ScaleOutTest : public ::testing::Test {
 protected:
  void SetUp() override {
    nginx_binary_ = find_nginx();
    if (nginx_binary_.empty()) {
      GTEST_SKIP() << "no nginx binary (/usr/sbin/nginx, or set MESHDEFORM_NGINX): "
                      "apt-get install nginx to run the scale-out tests";
    }
    char pattern[] = "/tmp/meshdeform-scaleout-XXXXXX";
    ASSERT_NE(::mkdtemp(pattern), nullptr);
    dir_ = pattern;
    // nginx's workers run as an unprivileged user when the test runs as root: let them in.
    fs::permissions(dir_, fs::perms::owner_all | fs::perms::group_read | fs::perms::group_exec |
                              fs::perms::others_read | fs::perms::others_exec);
    fs::create_directories(dir_ / "nginx-temp");
    const std::vector<std::string> flags = {
        "--http-listen", "127.0.0.1:0",   "--state-dir",   (dir_ / "state").string(),
        "--refine-budget", "0",           "--log-level",   "debug",
        "--workers",     "1",             "--max-sessions", "1000"};
    for (int i = 0; i < kReplicas; ++i) {
      std::string error;
      auto replica = test::ServerProcess::start(MESHDEFORM_SERVER_PATH, flags, error);
      ASSERT_NE(replica, nullptr) << error;
      ASSERT_TRUE(replica->wait_for_log("\"event\":\"http_listening\"", seconds(10)))
          << replica->log();
      for (const json& event : log_events(*replica)) {
        if (event.value("event", "") == "http_listening") http_ports_.push_back(event.value("port", 0));
      }
      ASSERT_EQ(http_ports_.size(), static_cast<std::size_t>(i + 1));
      replicas_.push_back(std::move(replica));
    }
    std::string upstream_grpc, upstream_http;
    for (int i = 0; i < kReplicas; ++i) {
      upstream_grpc += "server 127.0.0.1:" + std::to_string(replicas_[i]->port()) + "; ";
      upstream_http += "server 127.0.0.1:" + std::to_string(http_ports_[i]) + "; ";
    }
    const std::string conf_template =
        read_text(fs::path(MESHDEFORM_DOCKER_DIR) / "nginx.conf.template");
    ASSERT_FALSE(conf_template.empty()) << MESHDEFORM_DOCKER_DIR << "/nginx.conf.template";
    std::string last_error;
    for (int attempt = 0; attempt < 3 && !nginx_; ++attempt) {  // a stolen free port: retry
      grpc_port_ = free_loopback_port();
      http_port_ = free_loopback_port();
      ASSERT_GT(grpc_port_, 0);
      ASSERT_GT(http_port_, 0);
      std::string error;
      const std::optional<std::string> rendered = render_template(
          conf_template,
          {{"MESHDEFORM_GRPC_SERVERS", upstream_grpc},
           {"MESHDEFORM_HTTP_SERVERS", upstream_http},
           {"NGINX_GRPC_LISTEN", "127.0.0.1:" + std::to_string(grpc_port_)},
           {"NGINX_HTTP_LISTEN", "127.0.0.1:" + std::to_string(http_port_)},
           {"NGINX_TEMP_DIR", (dir_ / "nginx-temp").string()},
           {"NGINX_ACCESS_LOG", (dir_ / "access.log").string()},
           {"NGINX_ERROR_LOG", (dir_ / "error.log").string()}},
          error);
      ASSERT_TRUE(rendered.has_value()) << error;
      std::ofstream(dir_ / "nginx.conf") << *rendered;
      nginx_ = NginxProcess::start(nginx_binary_, dir_, dir_ / "nginx.conf",
                                   {grpc_port_, http_port_}, last_error);
    }
    ASSERT_NE(nginx_, nullptr) << last_error;
    client::ClientOptions options;
    options.target = "127.0.0.1:" + std::to_string(grpc_port_);
    options.default_timeout = seconds(20);
    Result<client::Client> connected = client::Client::connect(options);
    ASSERT_TRUE(connected.ok()) << connected.status().message();
    client_.emplace(std::move(connected).value());
  }

  void TearDown() override {
    client_.reset();
    nginx_.reset();     // before the replicas: it holds connections to them
    replicas_.clear();  // SIGTERM, SIGKILL after a bound (ServerProcess)
    if (!dir_.empty()) {
      if (HasFailure()) {
        std::cerr << "scale-out test files kept in " << dir_ << " (nginx.conf, access.log, "
                  << "error.log, state/)\n";
      } else {
        std::error_code ignored;
        fs::remove_all(dir_, ignored);
      }
    }
  }

  /// Byte offsets of every replica's log now (the start of a phase).
  std::vector<std::size_t> log_offsets() const {
    std::vector<std::size_t> offsets;
    for (const auto& replica : replicas_) offsets.push_back(replica->log().size());
    return offsets;
  }

  /// Replica index -> number of "rpc" lines naming `session` since `offsets`.
  std::map<int, int> calls_by_replica(const std::string& session,
                                      const std::vector<std::size_t>& offsets) const {
    std::map<int, int> counts;
    for (int i = 0; i < kReplicas; ++i) {
      for (const json& event : log_events(*replicas_[i], offsets[i])) {
        if (event.value("event", "") == "rpc" && event.value("session", "") == session) {
          ++counts[i];
        }
      }
    }
    return counts;
  }

  /// Waits (at most 10 s) until `expected` rpc lines naming `session` were logged since
  /// `offsets` (the server logs a call just before answering it; our reader may lag).
  std::map<int, int> wait_calls(const std::string& session, const std::vector<std::size_t>& offsets,
                                int expected) const {
    std::map<int, int> counts;
    const auto deadline = Clock::now() + seconds(10);
    do {
      counts = calls_by_replica(session, offsets);
      int total = 0;
      for (const auto& [replica, n] : counts) total += n;
      if (total >= expected) break;
      std::this_thread::sleep_for(milliseconds(10));
    } while (Clock::now() < deadline);
    return counts;
  }

  int count_events(int replica, const std::string& event_name, const std::string& method,
                   std::size_t offset = 0) const {
    int n = 0;
    for (const json& event : log_events(*replicas_[replica], offset)) {
      if (event.value("event", "") == event_name &&
          (method.empty() || event.value("method", "") == method)) {
        ++n;
      }
    }
    return n;
  }

  std::string nginx_binary_;
  fs::path dir_;
  std::vector<std::unique_ptr<test::ServerProcess>> replicas_;
  std::vector<int> http_ports_;
  int grpc_port_ = 0;
  int http_port_ = 0;
  std::unique_ptr<NginxProcess> nginx_;
  std::optional<client::Client> client_;
};

/// One session driven through nginx, with what it was last acknowledged.
struct Tracked {
  client::Session session;
  int creator = -1;  ///< the replica CreateSession ran on
  int owner = -1;    ///< the replica its per-session calls went to
  std::uint64_t revision = 0;
  Positions positions;
  int calls = 0;  ///< per-session calls made (each logs one "rpc" line naming the session)
};

client::MoveSpec drag(int step, int salt) {
  client::MoveSpec spec;
  client::GroupMove move;
  move.group = 1;
  move.translation = Eigen::Vector3d(0.01 * salt, 0, 0.004 * step);
  spec.moves.push_back(move);
  spec.max_iterations = 1;
  spec.full_positions = true;
  spec.editor = "scaleout-test";
  return spec;
}

/// Moves `t` once through nginx and checks that the revision follows the acknowledged one.
void move_once(const client::Client& client, Tracked& t, int step, int salt) {
  Result<client::DeformResult> moved = client.move(t.session.edit(), drag(step, salt));
  ++t.calls;
  ASSERT_TRUE(moved.ok()) << t.session.id << ": " << moved.status().message();
  EXPECT_EQ(moved->revision, t.revision + 1) << t.session.id;
  ASSERT_TRUE(moved->positions.has_value());
  t.revision = moved->revision;
  t.positions = *moved->positions;
}

/// The mesh the server holds now (OBJ keeps doubles exactly) equals the acknowledged positions.
void expect_acknowledged_state(const client::Client& client, Tracked& t) {
  Result<client::SessionInfo> info = client.session_info(t.session.view());
  ++t.calls;
  ASSERT_TRUE(info.ok()) << t.session.id << ": " << info.status().message();
  EXPECT_EQ(info->revision, t.revision) << t.session.id;
  Result<std::string> obj = client.get_mesh(t.session.view(), io::MeshFormat::Obj);
  ++t.calls;
  ASSERT_TRUE(obj.ok()) << t.session.id << ": " << obj.status().message();
  Result<MeshData> mesh = io::read_mesh_from_memory(*obj, io::MeshFormat::Obj);
  ASSERT_TRUE(mesh.ok()) << mesh.status().message();
  ASSERT_EQ(mesh->V.rows(), t.positions.rows());
  EXPECT_TRUE(mesh->V == t.positions) << t.session.id << " positions differ from the last "
                                      << "acknowledged revision " << t.revision;
}

TEST_F(ScaleOutTest, SessionsStickToOneReplicaSurviveItsDeathAndCarryLoad) {
  const client::Client& client = *client_;

  // ---- (a) sessions through nginx, each pinned to one replica ------------------------------
  // CreateSession has no session id to hash, so it runs on any replica, which keeps a copy in
  // memory; the session's later calls go to the replica its id hashes to. Should the session
  // fail over onto its creator, the creator must see that its copy is stale (the state file is
  // newer) and restore the newer state: such sessions are part of every check below.
  std::vector<Tracked> sessions;
  int cross_created = 0;
  for (int attempt = 0; attempt < kSessions; ++attempt) {
    const std::vector<std::size_t> before = log_offsets();
    Result<client::Session> created = client.create_session_from_sample("cylinder_small");
    ASSERT_TRUE(created.ok()) << created.status().message();
    Tracked t;
    t.session = *created;
    Result<client::SessionInfo> handled =
        client.set_handles(t.session.edit(), t.session.suggested_groups);
    ASSERT_TRUE(handled.ok()) << handled.status().message();
    t.calls = 1;
    const std::map<int, int> calls = wait_calls(t.session.id, before, 1);
    ASSERT_EQ(calls.size(), 1u) << t.session.id;
    t.owner = calls.begin()->first;
    const auto creator_deadline = Clock::now() + seconds(10);
    while (t.creator < 0 && Clock::now() < creator_deadline) {
      for (int i = 0; i < kReplicas; ++i) {
        if (count_events(i, "rpc", "CreateSession", before[i]) > 0) t.creator = i;
      }
      if (t.creator < 0) std::this_thread::sleep_for(milliseconds(10));
    }
    ASSERT_GE(t.creator, 0) << "no replica logged the CreateSession";
    if (t.creator != t.owner) ++cross_created;
    sessions.push_back(std::move(t));
  }
  std::cout << "sessions: " << sessions.size() << ", created on another replica than the one "
            << "serving them: " << cross_created << "\n";

  for (int step = 1; step <= 3; ++step) {
    for (int s = 0; s < kSessions; ++s) {
      ASSERT_NO_FATAL_FAILURE(move_once(client, sessions[s], step, s));
    }
  }
  std::map<int, int> sessions_per_replica;
  const std::vector<std::size_t> from_start(kReplicas, 0);
  for (Tracked& t : sessions) {
    const std::map<int, int> calls = wait_calls(t.session.id, from_start, t.calls);
    ASSERT_EQ(calls.size(), 1u) << "session " << t.session.id << " was served by "
                                << calls.size() << " replicas";
    EXPECT_EQ(calls.begin()->first, t.owner);
    EXPECT_EQ(calls.begin()->second, t.calls);
    ++sessions_per_replica[t.owner];
  }
  for (const auto& [replica, n] : sessions_per_replica) {
    std::cout << "replica " << replica << " (port " << replicas_[replica]->port()
              << "): " << n << " sessions\n";
  }
  ASSERT_GE(sessions_per_replica.size(), 2u) << "all sessions hashed onto one replica";

  // ---- (b) SIGKILL the replica holding the most sessions ----------------------------------
  int victim = sessions_per_replica.begin()->first;
  for (const auto& [replica, n] : sessions_per_replica) {
    if (n > sessions_per_replica[victim]) victim = replica;
  }
  const std::vector<std::size_t> before_kill = log_offsets();
  const std::optional<int> killed = replicas_[victim]->stop(SIGKILL, seconds(20));
  ASSERT_TRUE(killed.has_value());
  EXPECT_TRUE(WIFSIGNALED(*killed) && WTERMSIG(*killed) == SIGKILL);
  std::cout << "killed replica " << victim << " holding " << sessions_per_replica[victim]
            << " sessions\n";
  // nginx drops its idle keep-alive connections to the dead replica when it reads their EOF. A
  // call that it wrote onto one of them before that would fail (UNAVAILABLE: nginx does not
  // re-send a POST an upstream may have received); a real client retries such a call. Give the
  // workers a moment so that the checks below see the steady state after the failure.
  std::this_thread::sleep_for(milliseconds(300));

  std::vector<int> calls_before_kill;
  for (Tracked& t : sessions) {
    calls_before_kill.push_back(t.calls);
    ASSERT_NO_FATAL_FAILURE(expect_acknowledged_state(client, t));
  }
  for (int step = 4; step <= 6; ++step) {
    for (int s = 0; s < kSessions; ++s) {
      ASSERT_NO_FATAL_FAILURE(move_once(client, sessions[s], step, s));
    }
  }
  for (std::size_t s = 0; s < sessions.size(); ++s) {
    Tracked& t = sessions[s];
    ASSERT_NO_FATAL_FAILURE(expect_acknowledged_state(client, t));
    const int after_kill = t.calls - calls_before_kill[s];
    const std::map<int, int> calls = wait_calls(t.session.id, before_kill, after_kill);
    ASSERT_EQ(calls.size(), 1u) << "session " << t.session.id << " was served by "
                                << calls.size() << " replicas after the kill";
    const int server = calls.begin()->first;
    EXPECT_EQ(calls.begin()->second, after_kill);
    if (t.owner == victim) {
      EXPECT_NE(server, victim);
      // The survivor restored it from the shared state directory (dropping its own stale copy
      // first if it was the session's creator).
      bool restored = false;
      for (const json& event : log_events(*replicas_[server], before_kill[server])) {
        restored = restored || (event.value("event", "") == "session_restored" &&
                                event.value("session", "") == t.session.id);
      }
      EXPECT_TRUE(restored) << t.session.id << " on replica " << server;
    } else {
      EXPECT_EQ(server, t.owner) << "a live replica's session moved";
    }
  }

  // ---- (c) the load tester through nginx, with one replica down --------------------------
  {
    const fs::path report = dir_ / "loadtest.json";
    std::vector<std::string> words = {MESHDEFORM_LOADTEST_PATH,
                                      "--server",     "127.0.0.1:" + std::to_string(grpc_port_),
                                      "--sessions",   "4",
                                      "--sample",     "cylinder_small",
                                      "--rate",       "5",
                                      "--iterations", "1",
                                      "--watchers",   "1",
                                      "--duration",   "5",
                                      "--json",       report.string(),
                                      "--fail-on-errors"};
    const std::string out = (dir_ / "loadtest.out").string();
    test::ChildStreams streams;
    streams.stdout_path = out;
    streams.stderr_path = (dir_ / "loadtest.err").string();
    std::string error;
    std::optional<test::ChildProcess> child = test::ChildProcess::spawn(words, streams, error);
    ASSERT_TRUE(child.has_value()) << "cannot spawn " << MESHDEFORM_LOADTEST_PATH << ": " << error;
    // Bounded: a 5 s run; the generous bound only catches a hang (then the child is killed).
    const std::optional<int> status = child->wait(seconds(300));
    ASSERT_TRUE(status.has_value()) << "the load tester did not finish in 300 s";
    ASSERT_TRUE(WIFEXITED(*status) && WEXITSTATUS(*status) == 0)
        << read_text(out) << read_text(dir_ / "loadtest.err");
    const json result = json::parse(read_text(report), nullptr, false);
    ASSERT_FALSE(result.is_discarded()) << read_text(out);
    EXPECT_EQ(result["setup"]["sessions_ok"].get<int>(), 4);
    EXPECT_GT(result["moves"]["ok"].get<int>(), 0);
    EXPECT_EQ(result["moves"]["failed"].get<int>(), 0) << result["moves"]["errors_by_code"].dump();
    EXPECT_EQ(result["watchers"]["streams"].get<int>(), 4);
    std::cout << "loadtest through nginx: " << result["moves"]["ok"].get<int>() << " moves, "
              << result["moves"]["per_second_total"].get<double>() << " moves/s, p50 "
              << result["moves"]["latency_ms"]["p50"].get<double>() << " ms; watchers ended: "
              << result["watchers"]["end_status"].dump() << "\n";
  }
}

/// A browser's gRPC-Web Watch over the HTTP/1.1 listener, read off a raw socket: the chunked
/// response decoded into gRPC-Web frames as bytes arrive.
class GrpcWebStream {
 public:
  explicit GrpcWebStream(int port) : fd_(::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0)) {
    sockaddr_in address{};
    address.sin_family = AF_INET;
    address.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    address.sin_port = htons(static_cast<std::uint16_t>(port));
    connected_ = fd_ >= 0 &&
                 ::connect(fd_, reinterpret_cast<sockaddr*>(&address), sizeof address) == 0;
  }
  ~GrpcWebStream() {
    if (fd_ >= 0) ::close(fd_);
  }
  bool connected() const { return connected_; }

  bool send_all(const std::string& bytes) {
    std::size_t sent = 0;
    while (sent < bytes.size()) {
      const ssize_t n = ::send(fd_, bytes.data() + sent, bytes.size() - sent, MSG_NOSIGNAL);
      if (n <= 0) return false;
      sent += static_cast<std::size_t>(n);
    }
    return true;
  }

  /// Reads until `frames` complete data frames arrived, the stream ended or `timeout` passed.
  /// @return the number of complete data frames so far.
  int wait_data_frames(int frames, milliseconds timeout) {
    const auto deadline = Clock::now() + timeout;
    while (data_frames_ < frames && !ended_ && Clock::now() < deadline) {
      timeval wait{0, 50'000};
      ::setsockopt(fd_, SOL_SOCKET, SO_RCVTIMEO, &wait, sizeof wait);
      char buffer[65536];
      const ssize_t n = ::recv(fd_, buffer, sizeof buffer, 0);
      if (n == 0) ended_ = true;
      if (n > 0) {
        raw_.append(buffer, static_cast<std::size_t>(n));
        decode();
      }
    }
    return data_frames_;
  }
  bool saw_trailer() const { return trailer_; }
  const std::string& head() const { return head_; }

 private:
  void decode() {
    if (head_.empty()) {
      const std::size_t end = raw_.find("\r\n\r\n");
      if (end == std::string::npos) return;
      head_ = raw_.substr(0, end + 4);
      raw_.erase(0, end + 4);
    }
    while (true) {  // chunked transfer coding -> body_
      const std::size_t line = raw_.find("\r\n");
      if (line == std::string::npos) break;
      const std::size_t size = std::stoul(raw_.substr(0, line), nullptr, 16);
      if (size == 0) {
        ended_ = true;
        break;
      }
      if (raw_.size() < line + 2 + size + 2) break;
      body_.append(raw_, line + 2, size);
      raw_.erase(0, line + 2 + size + 2);
    }
    while (body_.size() >= 5) {  // gRPC-Web frames: flag, u32 big-endian length, payload
      const std::size_t length = (std::size_t{static_cast<unsigned char>(body_[1])} << 24) |
                                 (std::size_t{static_cast<unsigned char>(body_[2])} << 16) |
                                 (std::size_t{static_cast<unsigned char>(body_[3])} << 8) |
                                 std::size_t{static_cast<unsigned char>(body_[4])};
      if (body_.size() < 5 + length) break;
      if ((static_cast<unsigned char>(body_[0]) & 0x80) != 0) {
        trailer_ = true;
      } else {
        ++data_frames_;
      }
      body_.erase(0, 5 + length);
    }
  }

  int fd_ = -1;
  bool connected_ = false;
  std::string raw_, head_, body_;
  int data_frames_ = 0;
  bool trailer_ = false;
  bool ended_ = false;
};

/// A WatchRequest {session_id = 1, token = 2} as one gRPC-Web frame (both fields < 128 bytes).
std::string watch_request_frame(const std::string& session_id, const std::string& token) {
  std::string message;
  message += '\x0a';
  message += static_cast<char>(session_id.size());
  message += session_id;
  message += '\x12';
  message += static_cast<char>(token.size());
  message += token;
  std::string frame(5, '\0');
  frame[4] = static_cast<char>(message.size());
  return frame + message;
}

// The browser path: a session's gRPC-Web calls (HTTP/1.1 listener) reach the same replica as
// its gRPC calls (otherwise the browser watches a copy that never changes), and nginx hands each
// Watch chunk on as it arrives (proxy_buffering off), not when the stream ends. Several sessions,
// so that a routing mismatch cannot pass by luck (each would with probability 1/3).
TEST_F(ScaleOutTest, GrpcWebWatchOfAGrpcEditedSessionStreamsThroughNginx) {
  const client::Client& client = *client_;
  for (int s = 0; s < 5; ++s) {
    Result<client::Session> created = client.create_session_from_sample("cylinder_small");
    ASSERT_TRUE(created.ok()) << created.status().message();
    ASSERT_TRUE(client.set_handles(created->edit(), created->suggested_groups).ok());
    ASSERT_LT(created->id.size(), 128u);
    ASSERT_LT(created->view_token.size(), 128u);

    GrpcWebStream stream(http_port_);
    ASSERT_TRUE(stream.connected());
    const std::string body = watch_request_frame(created->id, created->view_token);
    ASSERT_TRUE(stream.send_all("POST /meshdeform.v1.DeformationService/Watch HTTP/1.1\r\n"
                                "Host: 127.0.0.1\r\n"
                                "Content-Type: application/grpc-web+proto\r\n"
                                "X-Grpc-Web: 1\r\n"
                                "x-session-id: " + created->id + "\r\n"
                                "Content-Length: " + std::to_string(body.size()) + "\r\n\r\n" +
                                body));
    ASSERT_EQ(stream.wait_data_frames(1, seconds(10)), 1) << "no join snapshot; " << stream.head();
    EXPECT_NE(stream.head().find(" 200 "), std::string::npos) << stream.head();
    for (int step = 1; step <= 2; ++step) {
      Result<client::DeformResult> moved = client.move(created->edit(), drag(step, s));
      ASSERT_TRUE(moved.ok()) << moved.status().message();
      // The stream is still open (no trailer): each update arrives on its own, promptly.
      ASSERT_EQ(stream.wait_data_frames(1 + step, seconds(5)), 1 + step)
          << "session " << s << " step " << step << ": the gRPC-Web Watch did not get the "
          << "revision committed over gRPC";
      EXPECT_FALSE(stream.saw_trailer());
    }
  }
}

// The stale-copy hazard of lazy restore: a session created on replica C is edited on its owner
// O (C != O); O and the third replica die, so nginx sends the session to C, which still holds
// its revision-0 copy in memory. C must notice that the state file is newer than its copy and
// serve (and continue from) the last acknowledged revision.
TEST_F(ScaleOutTest, FailoverOntoAReplicaWithAStaleCopyKeepsTheRevision) {
  const client::Client& client = *client_;
  std::optional<Tracked> found;
  for (int attempt = 0; attempt < 40 && !found; ++attempt) {
    const std::vector<std::size_t> before = log_offsets();
    Result<client::Session> created = client.create_session_from_sample("cylinder_small");
    ASSERT_TRUE(created.ok()) << created.status().message();
    Tracked t;
    t.session = *created;
    ASSERT_TRUE(client.set_handles(t.session.edit(), t.session.suggested_groups).ok());
    const std::map<int, int> calls = wait_calls(t.session.id, before, 1);
    ASSERT_EQ(calls.size(), 1u);
    t.owner = calls.begin()->first;
    for (int i = 0; i < kReplicas; ++i) {
      if (count_events(i, "rpc", "CreateSession", before[i]) > 0) t.creator = i;
    }
    if (t.creator >= 0 && t.creator != t.owner) found = std::move(t);
  }
  ASSERT_TRUE(found.has_value());
  Tracked& t = *found;
  for (int step = 1; step <= 3; ++step) ASSERT_NO_FATAL_FAILURE(move_once(client, t, step, 0));
  for (int i = 0; i < kReplicas; ++i) {
    if (i != t.creator) {
      ASSERT_TRUE(replicas_[i]->stop(SIGKILL, seconds(20)).has_value());
    }
  }
  ASSERT_NO_FATAL_FAILURE(expect_acknowledged_state(client, t));
}

}  // namespace
}  // namespace meshdeform
