#include "server/service/persistence.h"

#include "server/service/binary_codec.h"
#include "server/service/edit_history.h"

#include <dirent.h>
#include <fcntl.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <unistd.h>

#include <array>
#include <atomic>
#include <cerrno>
#include <chrono>
#include <cstring>
#include <limits>
#include <mutex>
#include <utility>

namespace meshdeform::service {
namespace {

constexpr std::string_view kMagic = "MDSTATE1";
/// Tags the edit state after the fields of the first format (which files may end without).
constexpr std::uint32_t kEditTag = 0x31544445;  // "EDT1" little-endian

Status os_error(const std::string& what, const std::string& path) {
  return Error(ErrorCode::Internal, what + " " + path + ": " + std::strerror(errno));
}

}  // namespace

std::uint32_t state_checksum(std::string_view data) {
  static const std::array<std::uint32_t, 256> table = [] {
    std::array<std::uint32_t, 256> t{};
    for (std::uint32_t i = 0; i < 256; ++i) {
      std::uint32_t c = i;
      for (int k = 0; k < 8; ++k) c = (c & 1) ? 0xEDB88320u ^ (c >> 1) : c >> 1;
      t[i] = c;
    }
    return t;
  }();
  std::uint32_t crc = 0xFFFFFFFFu;
  for (const char ch : data) crc = table[(crc ^ static_cast<unsigned char>(ch)) & 0xFFu] ^ (crc >> 8);
  return crc ^ 0xFFFFFFFFu;
}

bool is_valid_session_id(std::string_view id) {
  return id.size() == 32 && id.find_first_not_of("0123456789abcdef") == std::string_view::npos;
}

void write_session_state(BinaryWriter& w, const PersistedSession& s) {
  w.pod(static_cast<std::uint32_t>(s.groups.size()));
  for (const HandleGroup& g : s.groups) {
    w.pod(static_cast<std::uint8_t>(g.role == HandleRole::Fixed ? 0 : 1));
    w.pod(static_cast<std::uint32_t>(g.vertices.size()));
    for (int v : g.vertices) w.pod(static_cast<std::int32_t>(v));
  }
  w.matrix(s.anchors);
  w.matrix(s.targets);
  w.matrix(s.positions);
  w.pod(s.revision);
  w.pod(static_cast<std::int32_t>(s.last_method ? static_cast<int>(*s.last_method) : -1));
  w.pod(kEditTag);
  write_edit_state(w, s.edit);
}

Status read_session_state(BinaryReader& r, PersistedSession& s) {
  const auto nv = static_cast<std::int32_t>(s.rest.V.rows());
  std::uint32_t groups = 0;
  MD_RETURN_IF_ERROR(r.count(groups, "groups", 5));
  s.groups.clear();
  for (std::uint32_t g = 0; g < groups; ++g) {
    HandleGroup group;
    std::uint8_t role = 0;
    MD_RETURN_IF_ERROR(r.pod(role, "group role"));
    group.role = role == 0 ? HandleRole::Fixed : HandleRole::Handle;
    std::uint32_t size = 0;
    MD_RETURN_IF_ERROR(r.count(size, "group vertices", 4));
    for (std::uint32_t i = 0; i < size; ++i) {
      std::int32_t v = 0;
      MD_RETURN_IF_ERROR(r.pod(v, "group vertices"));
      if (v < 0 || v >= nv) {
        return r.corrupt("group " + std::to_string(g) + " vertex " + std::to_string(v) +
                         " out of range");
      }
      group.vertices.push_back(v);
    }
    s.groups.push_back(std::move(group));
  }
  MD_RETURN_IF_ERROR(r.matrix(s.anchors, "anchors"));
  MD_RETURN_IF_ERROR(r.matrix(s.targets, "targets"));
  MD_RETURN_IF_ERROR(r.matrix(s.positions, "positions"));
  MD_RETURN_IF_ERROR(r.pod(s.revision, "revision"));
  std::int32_t method = -1;
  MD_RETURN_IF_ERROR(r.pod(method, "method"));
  if (method < -1 || method > static_cast<std::int32_t>(core::Method::Laplacian)) {
    return r.corrupt("unknown method " + std::to_string(method));
  }
  s.last_method.reset();
  if (method >= 0) s.last_method = static_cast<core::Method>(method);
  std::size_t constrained = 0;
  for (const HandleGroup& g : s.groups) constrained += g.vertices.size();
  if (s.positions.rows() != nv || static_cast<std::size_t>(s.anchors.rows()) != constrained ||
      s.targets.rows() != s.anchors.rows()) {
    return r.corrupt("inconsistent sizes or values");
  }
  s.edit = EditState{};
  if (r.done()) return Status::success();  // written before the edit state existed
  std::uint32_t tag = 0;
  MD_RETURN_IF_ERROR(r.pod(tag, "edit state tag"));
  if (tag != kEditTag) return r.corrupt("unknown section after the method");
  return read_edit_state(r, s.edit, nv, static_cast<int>(s.groups.size()));
}

std::string encode_session(const PersistedSession& s) {
  BinaryWriter w;
  w.str(s.id.value);
  w.str(s.edit_token.value);
  w.str(s.view_token.value);
  w.pod(s.lambda);
  w.matrix(s.rest.V);
  w.pod(static_cast<std::uint32_t>(s.rest.F.rows()));
  for (Eigen::Index f = 0; f < s.rest.F.rows(); ++f)
    for (int k = 0; k < 3; ++k) w.pod(static_cast<std::int32_t>(s.rest.F(f, k)));
  write_session_state(w, s);

  std::string file(kMagic);
  const std::string& payload = w.bytes();
  BinaryWriter header;
  header.pod(static_cast<std::uint64_t>(payload.size()));
  file += header.bytes();
  file += payload;
  BinaryWriter trailer;
  trailer.pod(state_checksum(payload));
  file += trailer.bytes();
  return file;
}

Result<PersistedSession> decode_session(std::string_view bytes) {
  if (bytes.size() < kMagic.size() + 8 + 4 || bytes.substr(0, kMagic.size()) != kMagic) {
    return Error(ErrorCode::InvalidArgument, "not a meshdeform state file (bad magic or too short)");
  }
  std::uint64_t length = 0;
  std::memcpy(&length, bytes.data() + kMagic.size(), 8);
  const std::size_t header = kMagic.size() + 8;
  if (length != bytes.size() - header - 4) {
    return Error(ErrorCode::InvalidArgument,
                 "state file length mismatch: header says " + std::to_string(length) +
                     " payload bytes, the file holds " + std::to_string(bytes.size() - header - 4));
  }
  const std::string_view payload = bytes.substr(header, length);
  std::uint32_t stored = 0;
  std::memcpy(&stored, bytes.data() + header + length, 4);
  if (state_checksum(payload) != stored) {
    return Error(ErrorCode::InvalidArgument, "state file checksum mismatch (corrupt)");
  }

  PersistedSession s;
  BinaryReader r(payload, "state file");
  MD_RETURN_IF_ERROR(r.str(s.id.value, "session id", 64));
  MD_RETURN_IF_ERROR(r.str(s.edit_token.value, "edit token", 256));
  MD_RETURN_IF_ERROR(r.str(s.view_token.value, "view token", 256));
  MD_RETURN_IF_ERROR(r.pod(s.lambda, "lambda"));
  MD_RETURN_IF_ERROR(r.matrix(s.rest.V, "rest positions"));
  std::uint32_t faces = 0;
  MD_RETURN_IF_ERROR(r.count(faces, "faces", 12));
  s.rest.F.resize(faces, 3);
  const auto nv = static_cast<std::int32_t>(s.rest.V.rows());
  for (Eigen::Index f = 0; f < s.rest.F.rows(); ++f) {
    for (int k = 0; k < 3; ++k) {
      std::int32_t v = 0;
      MD_RETURN_IF_ERROR(r.pod(v, "faces"));
      if (v < 0 || v >= nv) {
        return r.corrupt("face " + std::to_string(f) + " references vertex " + std::to_string(v));
      }
      s.rest.F(f, k) = v;
    }
  }
  MD_RETURN_IF_ERROR(read_session_state(r, s));
  if (!r.done()) return Error(ErrorCode::InvalidArgument, "state file has trailing bytes");
  if (!is_valid_session_id(s.id.value) || !(s.lambda > 0)) {
    return Error(ErrorCode::InvalidArgument, "state file: inconsistent sizes or values");
  }
  return s;
}

/// The directory's lock: a mutex for the threads of this process (flock locks belong to the
/// open file description, which they share) and flock on `.lock` for the other processes.
struct StateDirectory::Lock {
  std::mutex mutex;
  int fd = -1;
  ~Lock() {
    if (fd >= 0) ::close(fd);
  }
};

namespace {

/// Holds the directory's lock for one check-and-change.
class DirectoryGuard {
 public:
  DirectoryGuard(std::mutex& mutex, int fd) : lock_(mutex), fd_(fd) {
    while (fd_ >= 0 && ::flock(fd_, LOCK_EX) != 0 && errno == EINTR) {
    }
  }
  ~DirectoryGuard() {
    if (fd_ >= 0) ::flock(fd_, LOCK_UN);
  }
  DirectoryGuard(const DirectoryGuard&) = delete;
  DirectoryGuard& operator=(const DirectoryGuard&) = delete;

 private:
  std::lock_guard<std::mutex> lock_;
  int fd_;
};

/// The OS error of a state write: ResourceExhausted when a resource ran out (the server then
/// refuses edits until there is room), Unavailable otherwise; the message names the call.
Status write_error(const std::string& what, const std::string& path, int error) {
  const bool exhausted = error == ENOSPC || error == EDQUOT || error == EFBIG ||
                         error == EMFILE || error == ENFILE || error == ENOMEM;
  return Error(exhausted ? ErrorCode::ResourceExhausted : ErrorCode::Unavailable,
               "state directory: cannot " + what + " " + path + ": " + std::strerror(error) +
                   "; the edit is not applied");
}

FileStamp stamp_of(const struct stat& info) {
  return FileStamp{static_cast<std::uint64_t>(info.st_dev), static_cast<std::uint64_t>(info.st_ino),
                   static_cast<std::uint64_t>(info.st_size),
                   static_cast<std::int64_t>(info.st_mtim.tv_sec) * 1'000'000'000 +
                       info.st_mtim.tv_nsec};
}

/// What a directory entry that is not a regular file is, for the messages.
std::string kind_of(mode_t mode) {
  if (S_ISFIFO(mode)) return "a FIFO";
  if (S_ISLNK(mode)) return "a symbolic link (not followed)";
  if (S_ISDIR(mode)) return "a directory";
  if (S_ISCHR(mode) || S_ISBLK(mode)) return "a device";
  if (S_ISSOCK(mode)) return "a socket";
  return "not a regular file";
}

}  // namespace

StagedWrite& StagedWrite::operator=(StagedWrite&& other) noexcept {
  if (this != &other) {
    if (!temp_path_.empty()) ::unlink(temp_path_.c_str());
    id_ = std::move(other.id_);
    temp_path_ = std::exchange(other.temp_path_, std::string());
    stamp_ = other.stamp_;
  }
  return *this;
}

StagedWrite::~StagedWrite() {
  if (!temp_path_.empty()) ::unlink(temp_path_.c_str());
}

Result<StateDirectory> StateDirectory::open(std::string path, WriteFault fault,
                                            std::uint64_t max_file_bytes) {
  if (path.empty()) return Error(ErrorCode::InvalidArgument, "empty state directory path");
  if (::mkdir(path.c_str(), 0700) != 0 && errno != EEXIST) return os_error("cannot create", path);
  struct stat info {};
  if (::stat(path.c_str(), &info) != 0 || !S_ISDIR(info.st_mode)) {
    return Error(ErrorCode::Internal, "state directory " + path + " is not a directory");
  }
  if (::access(path.c_str(), W_OK | X_OK) != 0) return os_error("cannot write to", path);
  auto lock = std::make_shared<Lock>();
  const std::string lock_path = path + "/.lock";
  lock->fd = ::open(lock_path.c_str(), O_RDWR | O_CREAT | O_CLOEXEC | O_NOFOLLOW, 0600);
  if (lock->fd < 0) return os_error("cannot open", lock_path);
  return StateDirectory(std::move(path), std::move(fault), max_file_bytes, std::move(lock));
}

int StateDirectory::injected(std::string_view call) const {
  const int error = fault_ ? fault_(call) : 0;
  if (error != 0) errno = error;
  return error;
}

std::string StateDirectory::file_of(const SessionId& id) const {
  return path_ + "/" + id.value + ".state";
}

Result<StagedWrite> StateDirectory::stage(const PersistedSession& state) const {
  if (!is_valid_session_id(state.id.value)) {
    return Error(ErrorCode::InvalidArgument, "not a session id this server issues");
  }
  const std::string bytes = encode_session(state);
  // A temporary name of this process and write alone (replicas may share the directory).
  static std::atomic<std::uint64_t> serial{0};
  StagedWrite staged;
  staged.id_ = state.id;
  const std::string temp_path = file_of(state.id) + ".tmp." + std::to_string(::getpid()) + "." +
                                std::to_string(serial.fetch_add(1));
  const int fd = injected("open") != 0
                     ? -1
                     : ::open(temp_path.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0600);
  if (fd < 0) return write_error("create", temp_path, errno);
  staged.temp_path_ = temp_path;  // removed by ~StagedWrite unless published
  std::size_t written = 0;
  while (written < bytes.size()) {
    const ssize_t n = injected("write") != 0
                          ? -1
                          : ::write(fd, bytes.data() + written, bytes.size() - written);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) {
      const int error = n < 0 ? errno : ENOSPC;  // a write of 0 bytes: no room
      ::close(fd);
      return write_error("write", temp_path, error);
    }
    written += static_cast<std::size_t>(n);
  }
  // Data durable before the rename makes it visible; the directory entry durable after.
  struct stat info {};
  if (injected("fsync") != 0 || ::fsync(fd) != 0 || ::fstat(fd, &info) != 0) {
    const int error = errno;
    ::close(fd);
    return write_error("fsync", temp_path, error);
  }
  ::close(fd);
  staged.stamp_ = stamp_of(info);  // rename keeps the inode, size and mtime of the file written
  return staged;
}

Status StateDirectory::publish(StagedWrite staged, const std::optional<FileStamp>& expected,
                               std::optional<FileStamp>& stamp) const {
  const std::string final_path = file_of(staged.id_);
  {
    const DirectoryGuard guard(lock_->mutex, lock_->fd);
    struct stat info {};
    const bool exists = ::lstat(final_path.c_str(), &info) == 0;
    if (expected) {
      if (!exists) {
        return Error(ErrorCode::NotFound, "session " + staged.id_.value.substr(0, 8) +
                                              "... was closed or expired (its state file is gone)");
      }
      if (!S_ISREG(info.st_mode) || stamp_of(info) != *expected) {
        return Error(ErrorCode::Aborted, "session " + staged.id_.value.substr(0, 8) +
                                             "... was changed by another replica; retry the call");
      }
    } else if (exists) {
      return Error(ErrorCode::Aborted,
                   "session " + staged.id_.value.substr(0, 8) + "... already has a state file");
    }
    if (injected("rename") != 0 || ::rename(staged.temp_path_.c_str(), final_path.c_str()) != 0) {
      return write_error("rename onto", final_path, errno);
    }
    staged.temp_path_.clear();  // it is the session's file now
    stamp = staged.stamp_;
  }
  const int dir = ::open(path_.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (dir < 0) return write_error("open", path_, errno);
  const bool synced = injected("fsync_dir") == 0 && ::fsync(dir) == 0;
  const int error = errno;
  ::close(dir);
  if (!synced) return write_error("fsync", path_, error);
  return Status::success();
}

std::optional<FileStamp> StateDirectory::stamp(const SessionId& id) const {
  if (!is_valid_session_id(id.value)) return std::nullopt;
  struct stat info {};
  if (::lstat(file_of(id).c_str(), &info) != 0) return std::nullopt;
  return stamp_of(info);
}

Result<PersistedSession> StateDirectory::read(const SessionId& id, FileStamp* stamp) const {
  if (!is_valid_session_id(id.value)) return Error(ErrorCode::NotFound, "no such session file");
  const std::string path = file_of(id);
  // Never follow a link, never block on a FIFO (O_NONBLOCK), read only a regular file.
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC | O_NOFOLLOW | O_NONBLOCK);
  if (fd < 0) {
    if (errno == ENOENT) return Error(ErrorCode::NotFound, "no such session file");
    if (errno == ELOOP) {
      return Error(ErrorCode::InvalidArgument,
                   "state file " + path + " is a symbolic link (not followed)");
    }
    return Error(ErrorCode::Unavailable,
                 "state directory: cannot open " + path + ": " + std::strerror(errno));
  }
  struct stat info {};
  if (::fstat(fd, &info) != 0) {
    const int error = errno;
    ::close(fd);
    return Error(ErrorCode::Unavailable,
                 "state directory: cannot stat " + path + ": " + std::strerror(error));
  }
  if (!S_ISREG(info.st_mode)) {
    ::close(fd);
    return Error(ErrorCode::InvalidArgument,
                 "state file " + path + " is " + kind_of(info.st_mode) + ", not read");
  }
  if (static_cast<std::uint64_t>(info.st_size) > max_file_bytes_) {
    ::close(fd);
    return Error(ErrorCode::InvalidArgument,
                 "state file " + path + " has " + std::to_string(info.st_size) +
                     " bytes, more than the " + std::to_string(max_file_bytes_) + " allowed");
  }
  if (stamp != nullptr) *stamp = stamp_of(info);
  // At most the size seen (plus one byte, to notice a file that grew meanwhile).
  std::string bytes;
  const std::size_t want = static_cast<std::size_t>(info.st_size) + 1;
  bytes.resize(want);
  std::size_t got = 0;
  while (got < want) {
    const ssize_t n = ::read(fd, bytes.data() + got, want - got);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) break;
    got += static_cast<std::size_t>(n);
  }
  ::close(fd);
  bytes.resize(got);
  Result<PersistedSession> state = decode_session(bytes);
  if (state.ok() && state->id.value != id.value) {
    return Error(ErrorCode::InvalidArgument, "state file " + path + " holds another session");
  }
  return state;
}

std::optional<double> StateDirectory::age_seconds(const SessionId& id) const {
  if (!is_valid_session_id(id.value)) return std::nullopt;
  struct stat info {};
  if (::lstat(file_of(id).c_str(), &info) != 0) return std::nullopt;
  timespec now{};
  clock_gettime(CLOCK_REALTIME, &now);
  return static_cast<double>(now.tv_sec - info.st_mtim.tv_sec) +
         1e-9 * static_cast<double>(now.tv_nsec - info.st_mtim.tv_nsec);
}

void StateDirectory::remove(const SessionId& id) const {
  if (!is_valid_session_id(id.value)) return;
  const DirectoryGuard guard(lock_->mutex, lock_->fd);
  ::unlink(file_of(id).c_str());
}

bool StateDirectory::remove_if(const SessionId& id, const FileStamp& expected) const {
  if (!is_valid_session_id(id.value)) return false;
  const DirectoryGuard guard(lock_->mutex, lock_->fd);
  struct stat info {};
  if (::lstat(file_of(id).c_str(), &info) != 0 || stamp_of(info) != expected) return false;
  return ::unlink(file_of(id).c_str()) == 0;
}

std::vector<SessionId> StateDirectory::scan(std::vector<SkippedStateFile>& skipped) const {
  std::vector<SessionId> ids;
  DIR* dir = ::opendir(path_.c_str());
  if (dir == nullptr) return ids;
  while (const dirent* entry = ::readdir(dir)) {
    const std::string_view name = entry->d_name;
    constexpr std::string_view kSuffix = ".state";
    if (name.size() != 32 + kSuffix.size() || !name.ends_with(kSuffix) ||
        !is_valid_session_id(name.substr(0, 32))) {
      continue;
    }
    struct stat info {};
    if (::fstatat(::dirfd(dir), entry->d_name, &info, AT_SYMLINK_NOFOLLOW) != 0) continue;
    if (!S_ISREG(info.st_mode)) {
      skipped.push_back({std::string(name), kind_of(info.st_mode)});
    } else if (static_cast<std::uint64_t>(info.st_size) > max_file_bytes_) {
      skipped.push_back({std::string(name), "larger than " + std::to_string(max_file_bytes_) +
                                                " bytes (" + std::to_string(info.st_size) + ")"});
    } else {
      ids.push_back(SessionId{std::string(name.substr(0, 32))});
    }
  }
  ::closedir(dir);
  return ids;
}

std::vector<SessionId> StateDirectory::list() const {
  std::vector<SkippedStateFile> ignored;
  return scan(ignored);
}

}  // namespace meshdeform::service
