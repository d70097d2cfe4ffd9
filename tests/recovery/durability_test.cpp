// Durability and fairness through the real binary (issue 40): what an adversarial client or a
// short machine does to meshdeform-server, and what must hold anyway:
//  - a server short of file descriptors refuses edits rather than acknowledging ones it cannot
//    write: every acknowledged revision survives SIGKILL and a restart;
//  - a close during a drag is final: the running solve stops, nothing after the close is
//    acknowledged, and the session comes back neither from its file nor after a restart;
//  - a server never takes its own writes for another replica's (a watch lives as long as its
//    session, however fast the drag and however many readers look up the session meanwhile);
//  - start-up reads only regular files from the state directory (a FIFO, a device or a link is
//    skipped and reported, never opened in a way that blocks);
//  - silent sockets from one address neither lock other clients out of either port nor stay
//    open past a short deadline.
// Loopback only (the floods come from other 127.0.0.0/8 addresses than the probes); every call
// has a deadline; every loop is bounded in count and time; no wall-clock thresholds.
#include <gtest/gtest.h>
#include <grpcpp/grpcpp.h>
#include <arpa/inet.h>
#include <dirent.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <signal.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <filesystem>
#include <fstream>
#include <mutex>
#include <optional>
#include <random>
#include <regex>
#include <string>
#include <thread>
#include <vector>

#include "meshdeform/v1/deformation.grpc.pb.h"
#include "tests/support/grpc_calls.h"
#include "tests/support/server_process.h"

namespace meshdeform {
namespace {

namespace fs = std::filesystem;
using std::chrono::milliseconds;
using std::chrono::seconds;
using test::bound;

fs::path fresh_dir(const std::string& what) {
  std::random_device random;
  return fs::temp_directory_path() /
         ("meshdeform-" + what + "-" + std::to_string(random()) + std::to_string(random()));
}

std::unique_ptr<v1::DeformationService::Stub> connect(const test::ServerProcess& server) {
  grpc::ChannelArguments args;
  args.SetMaxReceiveMessageSize(64 << 20);
  return v1::DeformationService::NewStub(
      grpc::CreateCustomChannel(server.address(), grpc::InsecureChannelCredentials(), args));
}

/// A TCP connection from `source` (an address of 127.0.0.0/8) to 127.0.0.1:`port`, or -1.
int connect_from(const std::string& source, int port) {
  const int fd = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
  if (fd < 0) return -1;
  sockaddr_in local{};
  local.sin_family = AF_INET;
  ::inet_pton(AF_INET, source.c_str(), &local.sin_addr);
  sockaddr_in remote{};
  remote.sin_family = AF_INET;
  remote.sin_port = htons(static_cast<std::uint16_t>(port));
  ::inet_pton(AF_INET, "127.0.0.1", &remote.sin_addr);
  if (::bind(fd, reinterpret_cast<sockaddr*>(&local), sizeof local) != 0 ||
      ::connect(fd, reinterpret_cast<sockaddr*>(&remote), sizeof remote) != 0) {
    ::close(fd);
    return -1;
  }
  return fd;
}

/// Open sockets that say nothing; closed when destroyed.
struct SilentSockets {
  std::vector<int> fds;
  ~SilentSockets() {
    for (const int fd : fds) ::close(fd);
  }
  void open(const std::string& source, int port, int count) {
    for (int i = 0; i < count; ++i) {
      const int fd = connect_from(source, port);
      if (fd >= 0) fds.push_back(fd);
    }
  }
  /// How many the server has closed: what it sent (a gRPC server's SETTINGS) is read and
  /// dropped, then a read sees the end of the stream or a reset.
  int closed_by_server() const {
    int closed = 0;
    char buffer[4096];
    for (const int fd : fds) {
      while (true) {
        const ssize_t n = ::recv(fd, buffer, sizeof buffer, MSG_DONTWAIT);
        if (n > 0) continue;
        if (n == 0 || (errno != EAGAIN && errno != EWOULDBLOCK && errno != EINTR)) ++closed;
        break;
      }
    }
    return closed;
  }
};

/// One HTTP/1.1 request from `source`; the status code and body, or nullopt when the server does
/// not answer within `timeout` (refused, reset or silent).
std::optional<std::pair<int, std::string>> http_get(const std::string& source, int port,
                                                    const std::string& path,
                                                    seconds timeout = seconds(10)) {
  const int fd = connect_from(source, port);
  if (fd < 0) return std::nullopt;
  timeval tv{static_cast<time_t>(timeout.count()), 0};
  ::setsockopt(fd, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof tv);
  ::setsockopt(fd, SOL_SOCKET, SO_SNDTIMEO, &tv, sizeof tv);
  const std::string request =
      "GET " + path + " HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n";
  if (::send(fd, request.data(), request.size(), MSG_NOSIGNAL) !=
      static_cast<ssize_t>(request.size())) {
    ::close(fd);
    return std::nullopt;
  }
  std::string response;
  char buffer[4096];
  while (true) {
    const ssize_t n = ::recv(fd, buffer, sizeof buffer, 0);
    if (n <= 0) break;
    response.append(buffer, static_cast<std::size_t>(n));
  }
  ::close(fd);
  std::smatch match;
  if (!std::regex_search(response, match, std::regex(R"(^HTTP/1\.[01] ([0-9]{3}))"))) {
    return std::nullopt;
  }
  const std::size_t body = response.find("\r\n\r\n");
  return std::make_pair(std::stoi(match[1].str()),
                        body == std::string::npos ? std::string() : response.substr(body + 4));
}

/// The value of one sample of /metrics (the first line starting with `name`), or -1.
double metric(const std::string& text, const std::string& name) {
  std::size_t at = 0;
  while ((at = text.find(name, at)) != std::string::npos) {
    if ((at == 0 || text[at - 1] == '\n') &&
        (text[at + name.size()] == ' ' || text[at + name.size()] == '{')) {
      const std::size_t space = text.find(' ', at + name.size());
      return std::stod(text.substr(space + 1, text.find('\n', space) - space - 1));
    }
    at += name.size();
  }
  return -1;
}

/// Open descriptors of process `pid` (from /proc), or -1.
int open_descriptors(int pid) {
  DIR* dir = ::opendir(("/proc/" + std::to_string(pid) + "/fd").c_str());
  if (dir == nullptr) return -1;
  int count = 0;
  while (::readdir(dir) != nullptr) ++count;
  ::closedir(dir);
  return count - 2;
}

/// Waits (bounded) until the server's descriptor count has not changed for a second: it has
/// accepted (or refused) everything a flood queued.
void wait_until_descriptors_settle(int pid) {
  int last = -2, same = 0;
  for (int i = 0; i < 200 && same < 5; ++i) {
    std::this_thread::sleep_for(milliseconds(200));
    const int now = open_descriptors(pid);
    same = now == last ? same + 1 : 0;
    last = now;
  }
}

grpc::Status get_info(v1::DeformationService::Stub& stub, const std::string& id,
                      const std::string& token, v1::GetSessionInfoResponse* info) {
  v1::GetSessionInfoRequest request;
  request.set_session_id(id);
  request.set_token(token);
  grpc::ClientContext context;
  bound(context);
  return stub.GetSessionInfo(&context, request, info);
}

// The server runs at a 256-descriptor limit and 400 idle connections arrive from 20 addresses
// while a client drags: whatever the server does (refuse the connections, or refuse the moves it
// cannot write), every revision it acknowledged is on disk when it is killed.
TEST(DurabilityTest, DescriptorShortageNeverLosesAnAcknowledgedRevision) {
  const fs::path dir = fresh_dir("fds");
  const std::vector<std::string> flags = {"--state-dir", dir.string(), "--refine-budget", "0"};
  std::string error;
  auto server = test::ServerProcess::start(MESHDEFORM_SERVER_PATH, flags, error, seconds(30),
                                           /*max_open_files=*/256);
  ASSERT_NE(server, nullptr) << error;
  auto stub = connect(*server);
  v1::CreateSessionResponse created;
  ASSERT_TRUE(test::create_sample_with_handles(*stub, "cylinder_small", &created).ok());

  SilentSockets idle;
  for (int a = 0; a < 20; ++a) idle.open("127.0.0." + std::to_string(10 + a), server->port(), 20);
  ASSERT_GE(idle.fds.size(), 300u);
  wait_until_descriptors_settle(server->pid());

  std::uint64_t acked = 0;
  int acked_moves = 0, refused_moves = 0;
  for (int i = 1; i <= 40; ++i) {
    v1::MoveHandlesResponse response;
    grpc::ClientContext context;
    bound(context, seconds(30));
    const grpc::Status status =
        stub->MoveHandles(&context, test::lift_move(created.session_id(), created.edit_token(), i),
                          &response);
    if (status.ok()) {
      acked = std::max(acked, response.result().revision());
      ++acked_moves;
    } else {
      ++refused_moves;
      // Refused for want of resources, never for a reason that hides a loss.
      EXPECT_TRUE(status.error_code() == grpc::StatusCode::RESOURCE_EXHAUSTED ||
                  status.error_code() == grpc::StatusCode::UNAVAILABLE)
          << status.error_code() << " " << status.error_message();
    }
  }
  ASSERT_GT(acked_moves + refused_moves, 0);
  ASSERT_TRUE(server->stop(SIGKILL, seconds(20)).has_value());
  server.reset();

  auto restarted = test::ServerProcess::start(MESHDEFORM_SERVER_PATH, flags, error);
  ASSERT_NE(restarted, nullptr) << error;
  auto stub2 = connect(*restarted);
  v1::GetSessionInfoResponse info;
  const grpc::Status status =
      get_info(*stub2, created.session_id(), created.view_token(), &info);
  ASSERT_TRUE(status.ok()) << status.error_message() << "\n" << restarted->log();
  EXPECT_GE(info.info().revision(), acked)
      << acked_moves << " moves acknowledged (up to revision " << acked << "), " << refused_moves
      << " refused; the restarted server holds revision " << info.info().revision();
  restarted.reset();
  std::error_code ignored;
  fs::remove_all(dir, ignored);
}

// Closing a session while its editor drags: the session is gone for good (no file in the state
// directory, NOT_FOUND now and after a restart), and a long solve running at the close stops
// without being acknowledged. Rounds alternate fast moves (one iteration: a close often lands
// while a revision is being written) and long ones (seconds of solving: the close lands in one).
TEST(DurabilityTest, CloseDuringADragIsFinal) {
  const fs::path dir = fresh_dir("close");
  const std::vector<std::string> flags = {"--state-dir", dir.string(), "--refine-budget", "0"};
  std::string error;
  auto server = test::ServerProcess::start(MESHDEFORM_SERVER_PATH, flags, error);
  ASSERT_NE(server, nullptr) << error;
  auto stub = connect(*server);
  std::vector<std::pair<std::string, std::string>> closed_ids;

  for (int round = 0; round < 6; ++round) {
    const bool is_long = round % 2 == 1;
    v1::CreateSessionResponse created;
    ASSERT_TRUE(test::create_sample_with_handles(*stub, "cylinder_small", &created).ok());
    std::atomic<int> acked{0};
    std::atomic<bool> close_sent{false};
    std::mutex mutex;
    std::vector<grpc::StatusCode> after_close;  // statuses of moves answered after the close
    std::jthread editor([&] {
      for (int i = 1; i <= 2000; ++i) {  // bounded; ends at the first refusal
        v1::MoveHandlesRequest move =
            test::lift_move(created.session_id(), created.edit_token(), i);
        move.set_full_positions(false);
        if (is_long && i > 1) {
          // After a quick first move, a second or more of solving: the close lands in it.
          move.set_max_iterations(1000);
          move.set_tolerance(0);
        }
        v1::MoveHandlesResponse response;
        grpc::ClientContext context;
        bound(context, seconds(600));
        const grpc::Status status = stub->MoveHandles(&context, move, &response);
        if (close_sent.load()) {
          const std::lock_guard lock(mutex);
          after_close.push_back(status.error_code());
        }
        if (!status.ok()) return;
        acked.fetch_add(1);
      }
    });
    const int before = is_long ? 1 : 20 + 7 * round;
    for (int i = 0; i < 60000 && acked.load() < before; ++i) {  // bounded: 60 s to 10 min
      std::this_thread::sleep_for(milliseconds(is_long ? 10 : 1));
    }
    ASSERT_GE(acked.load(), before);
    close_sent.store(true);
    v1::CloseSessionRequest close;
    close.set_session_id(created.session_id());
    close.set_token(created.edit_token());
    v1::CloseSessionResponse closed;
    grpc::ClientContext context;
    bound(context);
    ASSERT_TRUE(stub->CloseSession(&context, close, &closed).ok());
    editor.join();
    if (is_long) {
      // The move that was solving when the close came is not acknowledged.
      const std::lock_guard lock(mutex);
      ASSERT_FALSE(after_close.empty());
      for (const grpc::StatusCode code : after_close) {
        EXPECT_NE(code, grpc::StatusCode::OK) << "a move was acknowledged after the close";
      }
    }
    v1::GetSessionInfoResponse info;
    EXPECT_EQ(get_info(*stub, created.session_id(), created.view_token(), &info).error_code(),
              grpc::StatusCode::NOT_FOUND)
        << "round " << round << ": the closed session is back at revision "
        << info.info().revision();
    EXPECT_FALSE(fs::exists(dir / (created.session_id() + ".state"))) << "round " << round;
    closed_ids.emplace_back(created.session_id(), created.view_token());
  }
  ASSERT_TRUE(server->stop(SIGKILL, seconds(20)).has_value());
  server.reset();
  auto restarted = test::ServerProcess::start(MESHDEFORM_SERVER_PATH, flags, error);
  ASSERT_NE(restarted, nullptr) << error;
  auto stub2 = connect(*restarted);
  for (const auto& [id, token] : closed_ids) {
    v1::GetSessionInfoResponse info;
    EXPECT_EQ(get_info(*stub2, id, token, &info).error_code(), grpc::StatusCode::NOT_FOUND);
  }
  restarted.reset();
  std::error_code ignored;
  fs::remove_all(dir, ignored);
}

// One server on a state directory, a watcher, a fast drag and a reader looking the session up
// all the while: the server never drops its own session as a stale copy, and the watch ends
// (OK) only when the session is closed.
TEST(DurabilityTest, AWatchLivesAsLongAsItsSessionOnAStateDirectory) {
  const fs::path dir = fresh_dir("watch");
  std::string error;
  auto server = test::ServerProcess::start(
      MESHDEFORM_SERVER_PATH,
      {"--state-dir", dir.string(), "--refine-budget", "0", "--http-listen", "127.0.0.1:0"},
      error);
  ASSERT_NE(server, nullptr) << error;
  const int http_port = server->http_port();
  ASSERT_GT(http_port, 0);
  auto stub = connect(*server);
  v1::CreateSessionResponse created;
  ASSERT_TRUE(test::create_sample_with_handles(*stub, "cylinder_small", &created).ok());

  std::atomic<std::uint64_t> watched{0};
  std::atomic<bool> watch_ended{false};
  std::atomic<bool> close_sent{false};
  std::atomic<bool> ended_before_close{false};
  grpc::ClientContext watch_context;
  bound(watch_context, seconds(600));
  grpc::Status watch_status;
  std::jthread watcher([&] {
    v1::WatchRequest request;
    request.set_session_id(created.session_id());
    request.set_token(created.view_token());
    auto reader = stub->Watch(&watch_context, request);
    v1::DeformUpdate update;
    while (reader->Read(&update)) watched.store(update.result().revision());
    ended_before_close.store(!close_sent.load());
    watch_status = reader->Finish();
    watch_ended.store(true);
  });
  std::atomic<bool> dragging{true};
  std::jthread reader([&] {
    for (int i = 0; i < 20000 && dragging.load(); ++i) {  // bounded
      v1::GetSessionInfoResponse info;
      (void)get_info(*stub, created.session_id(), created.view_token(), &info);
    }
  });
  std::uint64_t last = 0;
  for (int i = 1; i <= 300 && !watch_ended.load(); ++i) {
    v1::MoveHandlesRequest move = test::lift_move(created.session_id(), created.edit_token(), i);
    move.set_full_positions(false);
    v1::MoveHandlesResponse response;
    grpc::ClientContext context;
    bound(context);
    const grpc::Status status = stub->MoveHandles(&context, move, &response);
    ASSERT_TRUE(status.ok()) << status.error_message();
    last = response.result().revision();
  }
  dragging.store(false);
  reader.join();
  for (int i = 0; i < 3000 && watched.load() < last && !watch_ended.load(); ++i) {
    std::this_thread::sleep_for(milliseconds(10));
  }
  EXPECT_FALSE(watch_ended.load()) << "the watch ended while the session lived: "
                                   << watch_status.error_code() << " "
                                   << watch_status.error_message();
  EXPECT_EQ(watched.load(), last);
  const auto metrics = http_get("127.0.0.1", http_port, "/metrics");
  ASSERT_TRUE(metrics.has_value());
  EXPECT_EQ(metric(metrics->second, "meshdeform_stale_copies_dropped_total"), 0);
  EXPECT_EQ(metric(metrics->second, "meshdeform_state_write_failures_total"), 0);

  close_sent.store(true);
  v1::CloseSessionRequest close;
  close.set_session_id(created.session_id());
  close.set_token(created.edit_token());
  v1::CloseSessionResponse closed;
  grpc::ClientContext context;
  bound(context);
  ASSERT_TRUE(stub->CloseSession(&context, close, &closed).ok());
  for (int i = 0; i < 3000 && !watch_ended.load(); ++i) std::this_thread::sleep_for(milliseconds(10));
  if (!watch_ended.load()) watch_context.TryCancel();
  watcher.join();
  EXPECT_FALSE(ended_before_close.load());
  EXPECT_TRUE(watch_status.ok()) << watch_status.error_message();
  server.reset();
  std::error_code ignored;
  fs::remove_all(dir, ignored);
}

// Start-up lists the state directory: a FIFO named like a session file (which blocks a plain
// open), a link to /dev/zero (endless), a link out of the directory and a directory are skipped
// and reported one by one; the good session file beside them still restores.
TEST(DurabilityTest, StartUpReadsOnlyRegularFilesOfTheStateDirectory) {
  const fs::path dir = fresh_dir("startup");
  const fs::path outside = fresh_dir("outside");
  std::string error;
  std::string good_id, good_token;
  {
    auto server = test::ServerProcess::start(
        MESHDEFORM_SERVER_PATH, {"--state-dir", dir.string(), "--refine-budget", "0"}, error);
    ASSERT_NE(server, nullptr) << error;
    auto stub = connect(*server);
    v1::CreateSessionResponse created;
    ASSERT_TRUE(test::create_sample_with_handles(*stub, "cylinder_small", &created).ok());
    good_id = created.session_id();
    good_token = created.view_token();
  }
  const std::string fifo = std::string(32, 'a'), zero = std::string(32, 'b'),
                    link_out = std::string(32, 'c'), subdir = std::string(32, 'd');
  ASSERT_EQ(::mkfifo((dir / (fifo + ".state")).c_str(), 0600), 0);
  fs::create_symlink("/dev/zero", dir / (zero + ".state"));
  fs::create_directories(outside);
  fs::copy_file(dir / (good_id + ".state"), outside / "copy.state");
  fs::create_symlink(outside / "copy.state", dir / (link_out + ".state"));
  fs::create_directories(dir / (subdir + ".state"));

  auto server = test::ServerProcess::start(
      MESHDEFORM_SERVER_PATH, {"--state-dir", dir.string(), "--refine-budget", "0"}, error,
      seconds(60));
  ASSERT_NE(server, nullptr) << error;
  for (const std::string& id : {fifo, zero, link_out, subdir}) {
    EXPECT_TRUE(server->wait_for_log("\"file\":\"" + id + ".state\"", seconds(10)))
        << id << " not reported:\n" << server->log();
  }
  EXPECT_NE(server->log().find("state_file_skipped"), std::string::npos);
  auto stub = connect(*server);
  v1::GetSessionInfoResponse info;
  EXPECT_TRUE(get_info(*stub, good_id, good_token, &info).ok());
  server.reset();
  std::error_code ignored;
  fs::remove_all(dir, ignored);
  fs::remove_all(outside, ignored);
}

// 1100 silent sockets from one address on the HTTP port and 200 on the gRPC port: another
// client's /healthz and gRPC calls are served at once, and the silent sockets are closed (the
// ones over the per-address cap at once, the rest at the header deadline).
TEST(DurabilityTest, SilentSocketsFromOneAddressDoNotLockOthersOut) {
  std::string error;
  auto server = test::ServerProcess::start(
      MESHDEFORM_SERVER_PATH, {"--refine-budget", "0", "--http-listen", "127.0.0.1:0"}, error);
  ASSERT_NE(server, nullptr) << error;
  const int http_port = server->http_port();
  ASSERT_GT(http_port, 0);

  SilentSockets http_flood, grpc_flood;
  http_flood.open("127.0.0.3", http_port, 1100);
  grpc_flood.open("127.0.0.3", server->port(), 200);
  ASSERT_GE(http_flood.fds.size(), 1000u);
  ASSERT_GE(grpc_flood.fds.size(), 150u);

  const auto health = http_get("127.0.0.1", http_port, "/healthz");
  ASSERT_TRUE(health.has_value()) << "/healthz did not answer beside the silent sockets";
  EXPECT_EQ(health->first, 200);
  auto stub = connect(*server);
  v1::CreateSessionResponse created;
  const grpc::Status status = test::create_sample_with_handles(*stub, "cylinder_small", &created);
  EXPECT_TRUE(status.ok()) << status.error_message();

  // Every silent socket is closed within a generous bound (the header deadline is seconds).
  int http_closed = 0, grpc_closed = 0;
  for (int i = 0; i < 900; ++i) {
    http_closed = http_flood.closed_by_server();
    grpc_closed = grpc_flood.closed_by_server();
    if (http_closed == static_cast<int>(http_flood.fds.size()) &&
        grpc_closed == static_cast<int>(grpc_flood.fds.size())) {
      break;
    }
    std::this_thread::sleep_for(milliseconds(100));
  }
  EXPECT_EQ(http_closed, static_cast<int>(http_flood.fds.size()));
  EXPECT_EQ(grpc_closed, static_cast<int>(grpc_flood.fds.size()));
  const auto metrics = http_get("127.0.0.1", http_port, "/metrics");
  ASSERT_TRUE(metrics.has_value());
  EXPECT_GT(metric(metrics->second, "meshdeform_connections_refused_total"), 0)
      << metrics->second;
}

}  // namespace
}  // namespace meshdeform
