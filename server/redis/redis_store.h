#pragma once
/// @file redis_store.h
/// SharedStateStore on Redis (issue 16), through Debian's hiredis (synchronous API, a small pool
/// of connections).
///
/// Keys, all hash-tagged with the session id so that a session's keys share one Redis Cluster
/// slot (the scripts touch several): `md:{<id>}:mesh` (encode_session bytes written at creation:
/// the rest mesh, tokens and lambda never change), `md:{<id>}:state` (the changing part: handle
/// groups, anchors, targets, positions, revision, method), `md:{<id>}:ver`
/// (write version), `md:{<id>}:rev` (revision), `md:{<id>}:lease` (the owning replica's id,
/// SET NX PX), `md:{<id>}:log` (a stream; entry id `<version>-0`, trimmed to the newest
/// RedisConfig::log_length entries: a replica further behind loads the whole state). State keys
/// expire idle_ttl after the last write.
///
/// Writes are Lua scripts (EVALSHA, EVAL when the server does not have them cached): the
/// compare-and-set of a commit checks the lease and the version and writes the state, the
/// version, the revision and the log entry in one atomic step.
///
/// TLS (rediss://): Debian 12's hiredis 0.14 has no TLS support, so each pooled connection to a
/// rediss:// server is a TCP connection wrapped in OpenSSL (tls_bridge.h: peer and host name
/// verified, the handshake done before the connection is pooled, so its errors are connect()'s),
/// bridged to hiredis through a socketpair (redisConnectFd) by a relay thread that the store
/// owns: the relay ends when hiredis closes its end (redisFree) and at the latest when the store
/// is destroyed.

#include <atomic>
#include <chrono>
#include <list>
#include <memory>
#include <mutex>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include "server/service/shared_store.h"

struct redisContext;
struct ssl_ctx_st;  // OpenSSL's SSL_CTX

/// The Redis session store, a library of its own (meshdeform::redis: hiredis, OpenSSL): the
/// service builds and runs without it.
namespace meshdeform::redis {

using service::PersistedSession;
using service::SessionId;
using service::SharedLogEntry;
using service::SharedState;
using service::SharedStateStore;

/// Where and how to reach Redis.
struct RedisConfig {
  std::string host = "127.0.0.1";
  int port = 6379;
  int database = 0;
  std::string username;  ///< Redis 6 ACL user (empty: the default user)
  std::string password;  ///< empty: no AUTH
  std::chrono::milliseconds io_timeout{2000};  ///< connect and per-command timeout
  std::chrono::milliseconds lease{5000};       ///< lease duration (renewed while in use)
  std::chrono::seconds idle_ttl{30 * 60};      ///< state keys expire this long after a write
  /// Log entries kept per session. Each holds the revision's positions (24 bytes per vertex), so
  /// this bounds Redis memory per session; a replica or watcher further behind than this reloads
  /// the whole state (watchers then get a snapshot).
  int log_length = 32;
  /// rediss://: TLS to Redis (the server's certificate and host name are verified).
  bool tls = false;
  /// PEM CA certificates the server's certificate must chain to (empty: the system's CAs).
  std::string tls_ca_file;
};

/// Parses `redis://[user@]host[:port][/db]` and `rediss://...` (TLS; `tls` set).
/// @return the config (other fields default); InvalidArgument naming what is wrong, including a
///         password in the URL (it would be visible in the process list: use a file or the
///         environment).
[[nodiscard]] Result<RedisConfig> parse_redis_url(std::string_view url);

class RedisStateStore final : public SharedStateStore {
 public:
  /// Connects, authenticates, selects the database, checks it answers PING and loads the scripts.
  /// @return the store; Unavailable naming the host for an unreachable server, a failed TLS
  ///         handshake (OpenSSL's reason, e.g. certificate verify failed), a refused password or
  ///         a bad database (the server's own message included); InvalidArgument for an
  ///         unreadable tls_ca_file.
  [[nodiscard]] static Result<std::unique_ptr<RedisStateStore>> connect(RedisConfig config);
  ~RedisStateStore() override;

  Status create(const PersistedSession& state) override;
  Result<SharedState> load(const SessionId& id) override;
  Result<std::optional<std::uint64_t>> version(const SessionId& id) override;
  Result<std::vector<SharedLogEntry>> read_log(const SessionId& id, std::uint64_t after,
                                               int max) override;
  Status acquire_lease(const SessionId& id, std::chrono::milliseconds wait,
                       std::stop_token stop = {}) override;
  void release_lease(const SessionId& id) override;
  Status commit(const PersistedSession& state, std::uint64_t base_version,
                SharedLogEntry entry) override;
  void remove(const SessionId& id) override;
  std::chrono::milliseconds lease_wait() const override { return config_.lease * 2; }

  /// This replica's lease owner id (random, per process).
  const std::string& owner() const { return owner_; }

  class Reply;  // a redisReply owner (redis_store.cpp)

 private:
  explicit RedisStateStore(RedisConfig config);
  /// A connected, authenticated context (from the pool or new).
  Result<redisContext*> take();
  void give_back(redisContext* context);
  /// Runs one command; an `idempotent` one once more on a new connection after an I/O error.
  /// @return the reply (a Redis error reply is returned as a reply); Internal naming the I/O
  ///         error (the connection is then dropped).
  Result<Reply> run(const std::vector<std::string>& args, bool idempotent = true);
  /// EVALSHA of script `index`, EVAL when the server lacks it. @return as run(); a Redis error
  ///         reply is returned as Internal naming it.
  Result<Reply> script(int index, const std::vector<std::string>& keys,
                       const std::vector<std::string>& args);
  /// Renews the held leases every lease/3 until stopped.
  void renew_loop(std::stop_token stop);
  /// rediss://: a TCP connection to the server, TLS handshake (verified), and a relay thread
  /// between it and one end of a socketpair. @return the other end (for redisConnectFd);
  ///         Unavailable naming host, port and OpenSSL's reason.
  Result<int> connect_tls();

  struct Relay {
    std::jthread thread;
    std::shared_ptr<std::atomic<bool>> done;
  };

  RedisConfig config_;
  std::string owner_;
  std::vector<std::string> script_sha_;
  std::mutex pool_mutex_;
  std::vector<redisContext*> idle_;
  std::mutex leases_mutex_;
  std::set<std::string> held_;  ///< ids whose lease this replica holds (renewed)
  ssl_ctx_st* tls_context_ = nullptr;  ///< rediss:// only (freed after the relays end)
  std::mutex relays_mutex_;
  std::list<Relay> relays_;  ///< rediss:// relay threads (joined in the destructor)
  std::jthread renewer_;        // last: stopped and joined first
};

}  // namespace meshdeform::redis
