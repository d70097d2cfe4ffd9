#include "server/redis/redis_store.h"

#include <hiredis/hiredis.h>
#include <poll.h>
#include <openssl/err.h>
#include <openssl/ssl.h>

#include <algorithm>
#include <cerrno>
#include <charconv>
#include <condition_variable>
#include <cstring>
#include <future>
#include <limits>
#include <thread>
#include <utility>

#include "server/redis/tls_bridge.h"
#include "server/service/binary_codec.h"
#include "server/service/edit_history.h"
#include "server/service/log.h"
#include "server/service/persistence.h"
#include "server/service/tokens.h"

namespace meshdeform::redis {

using service::BinaryReader;
using service::BinaryWriter;
using service::DeformResult;
using service::BytesMemo;
using service::decode_session;
using service::EditState;
using service::encode_session;
using service::random_hex;
using service::log_event;
using service::LogFields;
using service::LogLevel;

/// Owns one redisReply.
class RedisStateStore::Reply {
 public:
  explicit Reply(redisReply* reply) : reply_(reply) {}
  Reply(Reply&& other) noexcept : reply_(std::exchange(other.reply_, nullptr)) {}
  Reply& operator=(Reply&& other) noexcept {
    std::swap(reply_, other.reply_);
    return *this;
  }
  Reply(const Reply&) = delete;
  Reply& operator=(const Reply&) = delete;
  ~Reply() {
    if (reply_ != nullptr) freeReplyObject(reply_);
  }
  const redisReply* operator->() const { return reply_; }
  const redisReply* get() const { return reply_; }

 private:
  redisReply* reply_;
};

namespace {

using Reply = RedisStateStore::Reply;

std::string key(const SessionId& id, std::string_view suffix) {
  std::string out = "md:{";
  out += id.value;
  out += "}:";
  out += suffix;
  return out;
}

std::string text(const redisReply* reply) {
  if (reply == nullptr || reply->str == nullptr) return {};
  return std::string(reply->str, reply->len);
}

bool is_error(const redisReply* reply) { return reply != nullptr && reply->type == REDIS_REPLY_ERROR; }

/// A decimal integer reply (integer or bulk string); nullopt otherwise.
std::optional<std::uint64_t> as_u64(const redisReply* reply) {
  if (reply == nullptr) return std::nullopt;
  if (reply->type == REDIS_REPLY_INTEGER) {
    if (reply->integer < 0) return std::nullopt;
    return static_cast<std::uint64_t>(reply->integer);
  }
  if (reply->type != REDIS_REPLY_STRING && reply->type != REDIS_REPLY_STATUS) return std::nullopt;
  std::uint64_t value = 0;
  const char* end = reply->str + reply->len;
  const auto [ptr, ec] = std::from_chars(reply->str, end, value);
  if (ec != std::errc() || ptr != end) return std::nullopt;
  return value;
}

// --- Scripts (indices into kScripts) ------------------------------------------------------------
enum ScriptIndex { kCreate, kAcquire, kRelease, kCommit, kLoad, kRemove, kRenew };

// KEYS: state ver rev mesh. ARGV: state bytes, ttl ms, revision, mesh bytes.
constexpr const char* kCreateScript = R"lua(
if redis.call('EXISTS', KEYS[4]) == 1 then return 0 end
redis.call('SET', KEYS[4], ARGV[4], 'PX', ARGV[2])
redis.call('SET', KEYS[1], ARGV[1], 'PX', ARGV[2])
redis.call('SET', KEYS[2], '0', 'PX', ARGV[2])
redis.call('SET', KEYS[3], ARGV[3], 'PX', ARGV[2])
return 1
)lua";

// KEYS: lease rev. ARGV: owner, lease ms. Returns {1, 0, ''} when held now, {0, pttl, revision}
// when another replica has it.
constexpr const char* kAcquireScript = R"lua(
local owner = redis.call('GET', KEYS[1])
if owner == ARGV[1] then
  redis.call('PEXPIRE', KEYS[1], ARGV[2])
  return {1, 0, ''}
end
if not owner then
  redis.call('SET', KEYS[1], ARGV[1], 'PX', ARGV[2])
  return {1, 0, ''}
end
return {0, redis.call('PTTL', KEYS[1]), redis.call('GET', KEYS[2]) or '?'}
)lua";

// KEYS: lease. ARGV: owner, lease ms. Returns 1 when renewed, 0 when the lease is not ours.
constexpr const char* kRenewScript = R"lua(
if redis.call('GET', KEYS[1]) == ARGV[1] then
  redis.call('PEXPIRE', KEYS[1], ARGV[2])
  return 1
end
return 0
)lua";

// KEYS: lease. ARGV: owner.
constexpr const char* kReleaseScript = R"lua(
if redis.call('GET', KEYS[1]) == ARGV[1] then return redis.call('DEL', KEYS[1]) end
return 0
)lua";

// KEYS: state ver rev lease log mesh. ARGV: owner, base version, state bytes, ttl ms, kind,
// revision, entry bytes, log length, lease ms. Returns {code, version, revision}: 0 written, 1 lost the lease,
// 2 another write won, 3 not stored.
constexpr const char* kCommitScript = R"lua(
local ver = redis.call('GET', KEYS[2])
if not ver then return {3, '', ''} end
local rev = redis.call('GET', KEYS[3]) or '0'
if redis.call('GET', KEYS[4]) ~= ARGV[1] then return {1, ver, rev} end
if ver ~= ARGV[2] then return {2, ver, rev} end
local nv = string.format('%d', tonumber(ver) + 1)
redis.call('SET', KEYS[1], ARGV[3], 'PX', ARGV[4])
redis.call('SET', KEYS[2], nv, 'PX', ARGV[4])
redis.call('SET', KEYS[3], ARGV[6], 'PX', ARGV[4])
redis.call('XADD', KEYS[5], 'MAXLEN', ARGV[8], nv .. '-0', 'k', ARGV[5], 'r', ARGV[6],
           'd', ARGV[7])
redis.call('PEXPIRE', KEYS[5], ARGV[4])
redis.call('PEXPIRE', KEYS[6], ARGV[4])
redis.call('PEXPIRE', KEYS[4], ARGV[9])
return {0, nv, ARGV[6]}
)lua";

// KEYS: mesh state ver. Returns {mesh, state, version} (false parts when not stored).
constexpr const char* kLoadScript = R"lua(
return {redis.call('GET', KEYS[1]), redis.call('GET', KEYS[2]), redis.call('GET', KEYS[3])}
)lua";

// KEYS: state ver rev lease log mesh.
constexpr const char* kRemoveScript = R"lua(
return redis.call('DEL', KEYS[1], KEYS[2], KEYS[3], KEYS[4], KEYS[5], KEYS[6])
)lua";

const char* script_text(int index) {
  switch (index) {
    case kCreate: return kCreateScript;
    case kAcquire: return kAcquireScript;
    case kRelease: return kReleaseScript;
    case kCommit: return kCommitScript;
    case kLoad: return kLoadScript;
    case kRemove: return kRemoveScript;
    case kRenew: return kRenewScript;
  }
  return nullptr;
}
constexpr int kScriptCount = 7;

// --- Log entry bytes ------------------------------------------------------------------------------
// u8 format(1), u8 method, u8 flags (converged, refinement, built, settled), f64 rigidity, e_theta, e_phi,
// area_log_rms, solve_seconds, i32 iterations, pcg_iterations, str editor, matrix positions,
// matrix targets. Little-endian hosts only, as persistence.cpp.

std::string encode_entry(const SharedLogEntry& entry) {
  const DeformResult& r = *entry.result;
  BinaryWriter out;
  // Format 2 adds the edit state (format 1, without it, is still read).
  out.pod<std::uint8_t>(2);
  out.pod<std::uint8_t>(static_cast<std::uint8_t>(r.method));
  // (Readers before `settled` ignore its bit.)
  out.pod<std::uint8_t>(static_cast<std::uint8_t>((r.converged ? 1 : 0) | (r.refinement ? 2 : 0) |
                                                  (r.built_deformer ? 4 : 0) |
                                                  (r.settled ? 8 : 0)));
  out.pod(r.rigidity);
  out.pod(r.e_theta);
  out.pod(r.e_phi);
  out.pod(r.area_log_rms);
  out.pod(r.solve_seconds);
  out.pod<std::int32_t>(r.iterations);
  out.pod<std::int32_t>(r.pcg_iterations);
  out.str(r.editor);
  out.matrix(*r.positions);
  out.matrix(entry.targets);
  out.pod<std::uint8_t>(entry.edit ? 1 : 0);
  if (entry.edit) write_edit_state(out, *entry.edit);
  return out.take();
}

Result<SharedLogEntry> decode_entry(std::string_view bytes) {
  BinaryReader in(bytes, "redis log entry");
  std::uint8_t format = 0, method = 0, flags = 0;
  auto result = std::make_shared<DeformResult>();
  std::int32_t iterations = 0, pcg = 0;
  Positions positions, targets;
  MD_RETURN_IF_ERROR(in.pod(format, "format"));
  if (format != 1 && format != 2) return in.corrupt("unknown format " + std::to_string(format));
  MD_RETURN_IF_ERROR(in.pod(method, "method"));
  MD_RETURN_IF_ERROR(in.pod(flags, "flags"));
  MD_RETURN_IF_ERROR(in.pod(result->rigidity, "rigidity"));
  MD_RETURN_IF_ERROR(in.pod(result->e_theta, "e_theta"));
  MD_RETURN_IF_ERROR(in.pod(result->e_phi, "e_phi"));
  MD_RETURN_IF_ERROR(in.pod(result->area_log_rms, "area"));
  MD_RETURN_IF_ERROR(in.pod(result->solve_seconds, "solve seconds"));
  MD_RETURN_IF_ERROR(in.pod(iterations, "iterations"));
  MD_RETURN_IF_ERROR(in.pod(pcg, "pcg iterations"));
  MD_RETURN_IF_ERROR(in.str(result->editor, "editor", 256));
  MD_RETURN_IF_ERROR(in.matrix(positions, "positions"));
  MD_RETURN_IF_ERROR(in.matrix(targets, "targets"));
  std::optional<EditState> edit;
  if (format == 2) {
    std::uint8_t has_edit = 0;
    MD_RETURN_IF_ERROR(in.pod(has_edit, "edit state"));
    if (has_edit != 0) {
      // Group indices are checked by the reader against its groups (Session applies the entry).
      edit.emplace();
      MD_RETURN_IF_ERROR(read_edit_state(in, *edit, static_cast<int>(positions.rows()),
                                         std::numeric_limits<int>::max()));
    }
  }
  if (!in.done()) return in.corrupt("trailing bytes");
  if (method > static_cast<std::uint8_t>(core::Method::Laplacian)) {
    return in.corrupt("unknown method " + std::to_string(method));
  }
  result->method = static_cast<core::Method>(method);
  result->converged = (flags & 1) != 0;
  result->refinement = (flags & 2) != 0;
  result->built_deformer = (flags & 4) != 0;
  result->settled = (flags & 8) != 0;
  result->iterations = iterations;
  result->pcg_iterations = pcg;
  result->positions = std::make_shared<const Positions>(std::move(positions));
  result->changed_positions.resize(0, 3);
  SharedLogEntry entry;
  entry.result = std::move(result);
  entry.targets = std::move(targets);
  entry.edit = std::move(edit);
  return entry;
}

// --- The changing part of a session's state (md:{id}:state) -------------------------------------
// The rest mesh, the tokens and lambda never change: they are stored once (md:{id}:mesh, the
// persistence.h file format) and a commit writes only this: "MDDYN1", then the fields of
// write_session_state (persistence.h), the same bytes the state file holds for them.

constexpr std::string_view kDynamicMagic = "MDDYN1";

std::string encode_dynamic(const PersistedSession& state) {
  BinaryWriter out;
  write_session_state(out, state);
  return std::string(kDynamicMagic) + out.take();
}

/// Overlays the changing part onto `state` (decoded from the mesh key) and checks the sizes.
Status decode_dynamic(std::string_view bytes, PersistedSession& state) {
  const std::string source = "stored state of session " + state.id.value;
  if (!bytes.starts_with(kDynamicMagic)) {
    return Error(ErrorCode::InvalidArgument, source + " is corrupt (magic)");
  }
  BinaryReader in(bytes.substr(kDynamicMagic.size()), source);
  MD_RETURN_IF_ERROR(read_session_state(in, state));
  if (!in.done()) return in.corrupt("trailing bytes");
  return Status::success();
}

Status store_error(std::string_view what) {
  return Error(ErrorCode::Internal, "state store (redis): " + std::string(what));
}

// Redis cannot be reached or talked to now (connection refused, reset, timeout, refused
// login): UNAVAILABLE to the client, which may retry, instead of an internal fault.
Status store_unavailable(std::string_view what) {
  return Error(ErrorCode::Unavailable, "state store (redis): " + std::string(what));
}


}  // namespace

Result<RedisConfig> parse_redis_url(std::string_view url) {
  RedisConfig config;
  std::string_view scheme = "redis://";
  if (url.starts_with("rediss://")) {
    config.tls = true;
    scheme = "rediss://";
  }
  if (!url.starts_with(scheme)) {
    return Error(ErrorCode::InvalidArgument,
                 "--redis wants redis://host[:port][/db] or rediss://host[:port][/db] (TLS), not '" +
                     std::string(url.substr(0, 64)) + "'");
  }
  std::string_view rest = url.substr(scheme.size());
  if (const std::size_t at = rest.rfind('@'); at != std::string_view::npos) {
    const std::string_view user = rest.substr(0, at);
    if (user.find(':') != std::string_view::npos) {
      return Error(ErrorCode::InvalidArgument,
                   "--redis: no password in the URL (it would show in the process list); use "
                   "--redis-password-file or MESHDEFORM_REDIS_PASSWORD");
    }
    config.username = std::string(user);
    rest = rest.substr(at + 1);
  }
  std::string_view hostport = rest;
  if (const std::size_t slash = rest.find('/'); slash != std::string_view::npos) {
    hostport = rest.substr(0, slash);
    const std::string_view db = rest.substr(slash + 1);
    if (!db.empty()) {
      const auto [end, ec] = std::from_chars(db.data(), db.data() + db.size(), config.database);
      if (ec != std::errc() || end != db.data() + db.size() || config.database < 0) {
        return Error(ErrorCode::InvalidArgument,
                     "--redis: bad database number '" + std::string(db.substr(0, 16)) + "'");
      }
    }
  }
  if (const std::size_t colon = hostport.rfind(':');
      colon != std::string_view::npos && hostport.find(']') == std::string_view::npos) {
    const std::string_view port = hostport.substr(colon + 1);
    const auto [end, ec] = std::from_chars(port.data(), port.data() + port.size(), config.port);
    if (ec != std::errc() || end != port.data() + port.size() || config.port < 1 ||
        config.port > 65535) {
      return Error(ErrorCode::InvalidArgument,
                   "--redis: bad port '" + std::string(port.substr(0, 16)) + "'");
    }
    hostport = hostport.substr(0, colon);
  }
  if (hostport.empty()) return Error(ErrorCode::InvalidArgument, "--redis: no host in the URL");
  config.host = std::string(hostport);
  return config;
}

RedisStateStore::RedisStateStore(RedisConfig config)
    : config_(std::move(config)), owner_(random_hex(16)) {}

RedisStateStore::~RedisStateStore() {
  renewer_ = std::jthread();  // stop and join before the pool goes
  {
    std::lock_guard lock(pool_mutex_);
    for (redisContext* context : idle_) redisFree(context);  // rediss://: its relay sees EOF
    idle_.clear();
  }
  {
    std::lock_guard lock(relays_mutex_);
    for (Relay& relay : relays_) relay.thread.request_stop();
    relays_.clear();  // joins (each notices the stop within 250 ms)
  }
  if (tls_context_ != nullptr) SSL_CTX_free(tls_context_);
}

Result<int> RedisStateStore::connect_tls() {
  auto done = std::make_shared<std::atomic<bool>>(false);
  std::promise<TlsOpened> promise;
  std::future<TlsOpened> future = promise.get_future();
  {
    std::lock_guard lock(relays_mutex_);
    // Relays whose connection was closed have ended: join them now.
    relays_.remove_if([](const Relay& relay) { return relay.done->load(); });
    relays_.push_back(Relay{std::jthread(tls_connection, tls_context_, config_.host, config_.port,
                                         config_.io_timeout, std::move(promise), done),
                            done});
  }
  TlsOpened opened = future.get();  // bounded: the connect and handshake have io_timeout each
  if (opened.fd < 0) return Error(ErrorCode::Unavailable, std::move(opened.error));
  return opened.fd;
}

Result<std::unique_ptr<RedisStateStore>> RedisStateStore::connect(RedisConfig config) {
  std::unique_ptr<RedisStateStore> store(new RedisStateStore(std::move(config)));
  if (store->config_.tls) {
    SSL_CTX* context = SSL_CTX_new(TLS_client_method());
    if (context == nullptr) return Error(ErrorCode::Internal, "redis: cannot create a TLS context");
    store->tls_context_ = context;
    SSL_CTX_set_min_proto_version(context, TLS1_2_VERSION);
    SSL_CTX_set_verify(context, SSL_VERIFY_PEER, nullptr);
    const std::string& ca = store->config_.tls_ca_file;
    ERR_clear_error();
    if (!ca.empty() ? SSL_CTX_load_verify_locations(context, ca.c_str(), nullptr) != 1
                    : SSL_CTX_set_default_verify_paths(context) != 1) {
      const char* reason = ERR_reason_error_string(ERR_get_error());
      return Error(ErrorCode::InvalidArgument,
                   (ca.empty() ? std::string("cannot load the system's CA certificates")
                               : "cannot read the Redis CA file " + ca) +
                       ": " + (reason != nullptr ? reason : "unknown error"));
    }
  }
  // take() connects and authenticates: its errors are the startup errors. A Redis that is still
  // loading its data set (a restart) answers LOADING: wait for it, bounded.
  Result<redisContext*> context = store->take();
  for (int i = 0; i < 120 && !context.ok() &&
                  context.status().message().find("LOADING") != std::string::npos;
       ++i) {
    std::this_thread::sleep_for(std::chrono::milliseconds(500));
    context = store->take();
  }
  if (!context.ok()) return context.status();
  store->give_back(*context);
  store->script_sha_.resize(kScriptCount);
  for (int i = 0; i < kScriptCount; ++i) {
    MD_ASSIGN_OR_RETURN(Reply reply, store->run({"SCRIPT", "LOAD", script_text(i)}));
    if (reply->type != REDIS_REPLY_STRING) {
      return Error(ErrorCode::InvalidArgument,
                   "redis at " + store->config_.host + ":" + std::to_string(store->config_.port) +
                       " refused SCRIPT LOAD: " + text(reply.get()));
    }
    store->script_sha_[static_cast<std::size_t>(i)] = text(reply.get());
  }
  RedisStateStore* raw = store.get();
  store->renewer_ = std::jthread([raw](std::stop_token stop) { raw->renew_loop(stop); });
  return store;
}

Result<redisContext*> RedisStateStore::take() {
  for (;;) {
    redisContext* context = nullptr;
    {
      std::lock_guard lock(pool_mutex_);
      if (idle_.empty()) break;
      context = idle_.back();
      idle_.pop_back();
    }
    // An idle connection has nothing to read: readable means the server closed it (a restart, a
    // timeout, a failover). Drop it rather than fail the next command on it.
    pollfd p{context->fd, POLLIN, 0};
    if (::poll(&p, 1, 0) == 0) return context;
    redisFree(context);
  }
  const std::string where = "redis at " + config_.host + ":" + std::to_string(config_.port);
  timeval timeout{};
  timeout.tv_sec = static_cast<decltype(timeout.tv_sec)>(config_.io_timeout.count() / 1000);
  timeout.tv_usec = static_cast<decltype(timeout.tv_usec)>((config_.io_timeout.count() % 1000) * 1000);
  redisContext* context = nullptr;
  if (config_.tls) {
    // hiredis 0.14 has no TLS: it talks to a socketpair whose other end a relay thread bridges
    // to the TLS connection.
    MD_ASSIGN_OR_RETURN(const int fd, connect_tls());
    context = redisConnectFd(fd);
    if (context == nullptr) ::close(fd);
  } else {
    context = redisConnectWithTimeout(config_.host.c_str(), config_.port, timeout);
  }
  if (context == nullptr) return Error(ErrorCode::Unavailable, where + ": out of memory");
  if (context->err != 0) {
    std::string message = where + " is unreachable: " + context->errstr;
    redisFree(context);
    return Error(ErrorCode::Unavailable, std::move(message));
  }
  redisSetTimeout(context, timeout);
  auto command = [&](const std::vector<std::string>& args) -> Result<Reply> {
    std::vector<const char*> argv;
    std::vector<std::size_t> lengths;
    for (const std::string& a : args) {
      argv.push_back(a.data());
      lengths.push_back(a.size());
    }
    auto* reply = static_cast<redisReply*>(redisCommandArgv(
        context, static_cast<int>(argv.size()), argv.data(), lengths.data()));
    if (reply == nullptr) {
      return Error(ErrorCode::Unavailable, where + ": " + context->errstr);
    }
    return Reply(reply);
  };
  auto fail = [&](std::string message) -> Status {
    redisFree(context);
    return Error(ErrorCode::Unavailable, std::move(message));
  };
  if (!config_.password.empty()) {
    std::vector<std::string> auth = {"AUTH"};
    if (!config_.username.empty()) auth.push_back(config_.username);
    auth.push_back(config_.password);
    Result<Reply> reply = command(auth);
    if (!reply.ok()) return fail(reply.status().message());
    if (is_error(reply->get())) {
      return fail(where + " refused the password (--redis-password-file / "
                          "MESHDEFORM_REDIS_PASSWORD): " + text(reply->get()));
    }
  }
  if (config_.database != 0) {
    Result<Reply> reply = command({"SELECT", std::to_string(config_.database)});
    if (!reply.ok()) return fail(reply.status().message());
    if (is_error(reply->get())) {
      return fail(where + " refused database " + std::to_string(config_.database) + ": " +
                  text(reply->get()));
    }
  }
  Result<Reply> pong = command({"PING"});
  if (!pong.ok()) return fail(pong.status().message());
  if (is_error(pong->get())) {
    // NOAUTH: the server wants a password and none was given.
    const std::string refusal = text(pong->get());
    return fail(where + " refused PING: " + refusal +
                (config_.password.empty() && refusal.starts_with("NOAUTH")
                     ? " (give the password with --redis-password-file or "
                       "MESHDEFORM_REDIS_PASSWORD)"
                     : ""));
  }
  return context;
}

void RedisStateStore::give_back(redisContext* context) {
  std::lock_guard lock(pool_mutex_);
  idle_.push_back(context);
}

Result<Reply> RedisStateStore::run(const std::vector<std::string>& args, bool idempotent) {
  std::vector<const char*> argv;
  std::vector<std::size_t> lengths;
  argv.reserve(args.size());
  lengths.reserve(args.size());
  for (const std::string& a : args) {
    argv.push_back(a.data());
    lengths.push_back(a.size());
  }
  // An idempotent command is sent once more on a new connection after an I/O error; a write
  // that is not (a commit) is not: whether it was applied is unknown, the caller is told so.
  for (int attempt = 0;; ++attempt) {
    Result<redisContext*> taken = take();
    if (!taken.ok()) return store_unavailable(taken.status().message());
    redisContext* context = *taken;
    auto* reply = static_cast<redisReply*>(
        redisCommandArgv(context, static_cast<int>(argv.size()), argv.data(), lengths.data()));
    if (reply != nullptr) {
      give_back(context);
      return Reply(reply);
    }
    // The connection is in an unknown state (timeout mid-reply, reset): never reuse it.
    Status error = store_unavailable(std::string(args.empty() ? "" : args[0]) + ": " + context->errstr +
                               (idempotent ? "" : " (the write may or may not have been applied)"));
    redisFree(context);
    if (!idempotent || attempt > 0) return error;
  }
}

Result<Reply> RedisStateStore::script(int index, const std::vector<std::string>& keys,
                                      const std::vector<std::string>& args) {
  std::vector<std::string> command = {"EVALSHA", script_sha_[static_cast<std::size_t>(index)],
                                      std::to_string(keys.size())};
  command.insert(command.end(), keys.begin(), keys.end());
  command.insert(command.end(), args.begin(), args.end());
  const bool idempotent = index != kCommit && index != kCreate;
  MD_ASSIGN_OR_RETURN(Reply reply, run(command, idempotent));
  if (is_error(reply.get()) && text(reply.get()).starts_with("NOSCRIPT")) {
    // A restarted server or another Cluster node: send the script itself (it is cached again).
    // NOSCRIPT means it did not run, so this is no second attempt of a write.
    command[0] = "EVAL";
    command[1] = script_text(index);
    MD_ASSIGN_OR_RETURN(reply, run(command, idempotent));
  }
  if (is_error(reply.get())) return store_error(text(reply.get()));
  return reply;
}

Status RedisStateStore::create(const PersistedSession& state) {
  const std::string ttl = std::to_string(std::chrono::milliseconds(config_.idle_ttl).count());
  MD_ASSIGN_OR_RETURN(Reply reply,
                      script(kCreate,
                             {key(state.id, "state"), key(state.id, "ver"), key(state.id, "rev"),
                              key(state.id, "mesh")},
                             {encode_dynamic(state), ttl, std::to_string(state.revision),
                              encode_session(state)}));
  if (reply->type != REDIS_REPLY_INTEGER) return store_error("unexpected reply to create");
  if (reply->integer == 0) {
    return Error(ErrorCode::Aborted, "session " + state.id.value + " already exists");
  }
  return Status::success();
}

Result<SharedState> RedisStateStore::load(const SessionId& id) {
  MD_ASSIGN_OR_RETURN(Reply reply,
                      script(kLoad, {key(id, "mesh"), key(id, "state"), key(id, "ver")}, {}));
  if (reply->type != REDIS_REPLY_ARRAY) return store_error("unexpected reply to load");
  if (reply->elements < 3 || reply->element[0]->type != REDIS_REPLY_STRING ||
      reply->element[1]->type != REDIS_REPLY_STRING) {
    return Error(ErrorCode::NotFound, "session " + id.value + " is not stored");
  }
  const std::optional<std::uint64_t> version = as_u64(reply->element[2]);
  if (!version) return store_error("session " + id.value + " has no valid version");
  const redisReply* mesh = reply->element[0];
  MD_ASSIGN_OR_RETURN(PersistedSession state,
                      decode_session(std::string_view(mesh->str, mesh->len)));
  if (state.id.value != id.value) {
    return Error(ErrorCode::InvalidArgument, "stored state of " + id.value + " names another id");
  }
  const redisReply* dynamic = reply->element[1];
  MD_RETURN_IF_ERROR(decode_dynamic(std::string_view(dynamic->str, dynamic->len), state));
  return SharedState{std::move(state), *version};
}

Result<std::optional<std::uint64_t>> RedisStateStore::version(const SessionId& id) {
  MD_ASSIGN_OR_RETURN(Reply reply, run({"GET", key(id, "ver")}));
  if (is_error(reply.get())) return store_error(text(reply.get()));
  if (reply->type == REDIS_REPLY_NIL) return std::optional<std::uint64_t>{};
  const std::optional<std::uint64_t> version = as_u64(reply.get());
  if (!version) return store_error("session " + id.value + " has no valid version");
  return version;
}

Result<std::vector<SharedLogEntry>> RedisStateStore::read_log(const SessionId& id,
                                                              std::uint64_t after, int max) {
  MD_ASSIGN_OR_RETURN(Reply reply, run({"XRANGE", key(id, "log"), std::to_string(after + 1) + "-0",
                                        "+", "COUNT", std::to_string(std::max(max, 1))}));
  if (is_error(reply.get())) return store_error(text(reply.get()));
  if (reply->type != REDIS_REPLY_ARRAY) return store_error("unexpected reply to XRANGE");
  std::vector<SharedLogEntry> entries;
  for (std::size_t i = 0; i < reply->elements; ++i) {
    const redisReply* item = reply->element[i];
    if (item->type != REDIS_REPLY_ARRAY || item->elements != 2) {
      return store_error("unexpected log entry");
    }
    const std::string stream_id = text(item->element[0]);
    std::uint64_t version = 0;
    const auto [end, ec] = std::from_chars(stream_id.data(), stream_id.data() + stream_id.size(), version);
    if (ec != std::errc()) return store_error("bad log entry id " + stream_id);
    const redisReply* fields = item->element[1];
    std::string kind, data;
    std::optional<std::uint64_t> revision;
    for (std::size_t f = 0; f + 1 < fields->elements; f += 2) {
      const std::string name = text(fields->element[f]);
      if (name == "k") kind = text(fields->element[f + 1]);
      if (name == "r") revision = as_u64(fields->element[f + 1]);
      if (name == "d") data = text(fields->element[f + 1]);
    }
    if (!revision) return store_error("log entry " + stream_id + " has no revision");
    SharedLogEntry entry;
    if (kind == "m") {
      MD_ASSIGN_OR_RETURN(entry, decode_entry(data));
    }
    entry.version = version;
    entry.revision = *revision;
    if (entry.result) {
      auto result = std::make_shared<DeformResult>(*entry.result);
      result->encoded = std::make_shared<BytesMemo>();
      result->revision = *revision;
      entry.result = std::move(result);
    }
    entries.push_back(std::move(entry));
  }
  return entries;
}

Status RedisStateStore::acquire_lease(const SessionId& id, std::chrono::milliseconds wait,
                                      std::stop_token stop) {
  const auto start = std::chrono::steady_clock::now();
  const std::string ms = std::to_string(config_.lease.count());
  std::chrono::milliseconds pause(2);
  for (;;) {
    MD_ASSIGN_OR_RETURN(Reply reply,
                        script(kAcquire, {key(id, "lease"), key(id, "rev")}, {owner_, ms}));
    if (reply->type != REDIS_REPLY_ARRAY || reply->elements != 3) {
      return store_error("unexpected reply to the lease script");
    }
    if (reply->element[0]->integer == 1) {
      std::lock_guard lock(leases_mutex_);
      held_.insert(id.value);
      return Status::success();
    }
    const long long remaining = reply->element[1]->integer;
    const auto waited = std::chrono::steady_clock::now() - start;
    if (waited >= wait || stop.stop_requested()) {
      return Error(ErrorCode::Aborted,
                   "session " + id.value.substr(0, 8) +
                       "... is being edited through another replica (revision " +
                       text(reply->element[2]) + " is current; its lease ends in " +
                       std::to_string(std::max(remaining, 0LL)) + " ms); retry the call");
    }
    std::this_thread::sleep_for(pause);
    pause = std::min(pause * 2, std::chrono::milliseconds(50));
  }
}

void RedisStateStore::release_lease(const SessionId& id) {
  {
    std::lock_guard lock(leases_mutex_);
    held_.erase(id.value);
  }
  const Result<Reply> reply = script(kRelease, {key(id, "lease")}, {owner_});
  if (!reply.ok()) {
    log_event(LogLevel::Warn, "lease_release_failed",
              LogFields().add("session", id.value).add("message", reply.status().message()));
  }
}

Status RedisStateStore::commit(const PersistedSession& state, std::uint64_t base_version,
                               SharedLogEntry entry) {
  const std::string ttl = std::to_string(std::chrono::milliseconds(config_.idle_ttl).count());
  const SessionId& id = state.id;
  MD_ASSIGN_OR_RETURN(
      Reply reply,
      script(kCommit,
             {key(id, "state"), key(id, "ver"), key(id, "rev"), key(id, "lease"), key(id, "log"),
              key(id, "mesh")},
             {owner_, std::to_string(base_version), encode_dynamic(state), ttl,
              entry.result ? "m" : "h", std::to_string(state.revision),
              entry.result ? encode_entry(entry) : std::string(), std::to_string(config_.log_length),
              std::to_string(config_.lease.count())}));
  if (reply->type != REDIS_REPLY_ARRAY || reply->elements != 3) {
    return store_error("unexpected reply to the commit script");
  }
  const long long code = reply->element[0]->integer;
  const std::string stored_revision = text(reply->element[2]);
  switch (code) {
    case 0:
      return Status::success();
    case 1:
      return Error(ErrorCode::Aborted, "session " + id.value.substr(0, 8) +
                                           "... lost its lease to another replica (revision " +
                                           stored_revision + " is current); retry the call");
    case 2:
      return Error(ErrorCode::Aborted, "session " + id.value.substr(0, 8) +
                                           "... was changed by another replica (revision " +
                                           stored_revision + " is current); retry the call");
    case 3:
      return Error(ErrorCode::NotFound,
                   "session " + id.value.substr(0, 8) + "... was closed or expired");
    default:
      return store_error("unexpected commit result " + std::to_string(code));
  }
}

void RedisStateStore::remove(const SessionId& id) {
  {
    std::lock_guard lock(leases_mutex_);
    held_.erase(id.value);
  }
  const Result<Reply> reply = script(
      kRemove,
      {key(id, "state"), key(id, "ver"), key(id, "rev"), key(id, "lease"), key(id, "log"),
       key(id, "mesh")},
      {});
  if (!reply.ok()) {
    log_event(LogLevel::Warn, "state_remove_failed",
              LogFields().add("session", id.value).add("message", reply.status().message()));
  }
}

void RedisStateStore::renew_loop(std::stop_token stop) {
  std::mutex mutex;
  std::condition_variable_any cv;
  const auto period = std::max(config_.lease / 3, std::chrono::milliseconds(10));
  const std::string ms = std::to_string(config_.lease.count());
  while (!stop.stop_requested()) {
    {
      std::unique_lock lock(mutex);
      cv.wait_for(lock, stop, period, [] { return false; });
    }
    if (stop.stop_requested()) return;
    std::vector<std::string> ids;
    {
      std::lock_guard lock(leases_mutex_);
      ids.assign(held_.begin(), held_.end());
    }
    for (const std::string& id : ids) {
      // Renew only what is still ours: a lease another replica took is not taken back here (the
      // commit script refuses this replica's writes until an edit acquires it again).
      const Result<Reply> reply = script(kRenew, {key(SessionId{id}, "lease")}, {owner_, ms});
      if (reply.ok() && reply.value()->type == REDIS_REPLY_INTEGER &&
          reply.value()->integer == 0) {
        std::lock_guard lock(leases_mutex_);
        held_.erase(id);
        log_event(LogLevel::Warn, "lease_lost", LogFields().add("session", id));
      }
    }
  }
}

}  // namespace meshdeform::redis
