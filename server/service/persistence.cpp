#include "server/service/persistence.h"

#include "server/service/binary_codec.h"
#include "server/service/edit_history.h"

#include <dirent.h>
#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <array>
#include <atomic>
#include <cerrno>
#include <chrono>
#include <cstring>
#include <limits>

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

Result<StateDirectory> StateDirectory::open(std::string path) {
  if (path.empty()) return Error(ErrorCode::InvalidArgument, "empty state directory path");
  if (::mkdir(path.c_str(), 0700) != 0 && errno != EEXIST) return os_error("cannot create", path);
  struct stat info {};
  if (::stat(path.c_str(), &info) != 0 || !S_ISDIR(info.st_mode)) {
    return Error(ErrorCode::Internal, "state directory " + path + " is not a directory");
  }
  if (::access(path.c_str(), W_OK | X_OK) != 0) return os_error("cannot write to", path);
  return StateDirectory(std::move(path));
}

std::string StateDirectory::file_of(const SessionId& id) const {
  return path_ + "/" + id.value + ".state";
}

namespace {
FileStamp stamp_of(const struct stat& info) {
  return FileStamp{static_cast<std::uint64_t>(info.st_dev), static_cast<std::uint64_t>(info.st_ino),
                   static_cast<std::uint64_t>(info.st_size),
                   static_cast<std::int64_t>(info.st_mtim.tv_sec) * 1'000'000'000 +
                       info.st_mtim.tv_nsec};
}
}  // namespace

Result<FileStamp> StateDirectory::write(const PersistedSession& state) const {
  if (!is_valid_session_id(state.id.value)) {
    return Error(ErrorCode::InvalidArgument, "not a session id this server issues");
  }
  const std::string bytes = encode_session(state);
  const std::string final_path = file_of(state.id);
  // A temporary name of this process and write alone (replicas may share the directory).
  static std::atomic<std::uint64_t> serial{0};
  const std::string temp_path = final_path + ".tmp." + std::to_string(::getpid()) + "." +
                                std::to_string(serial.fetch_add(1));
  const int fd = ::open(temp_path.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0600);
  if (fd < 0) return os_error("cannot create", temp_path);
  std::size_t written = 0;
  while (written < bytes.size()) {
    const ssize_t n = ::write(fd, bytes.data() + written, bytes.size() - written);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) {
      const Status error = os_error("cannot write", temp_path);
      ::close(fd);
      ::unlink(temp_path.c_str());
      return error;
    }
    written += static_cast<std::size_t>(n);
  }
  // Data durable before the rename makes it visible; the directory entry durable after.
  struct stat info {};
  if (::fsync(fd) != 0 || ::fstat(fd, &info) != 0) {
    const Status error = os_error("cannot fsync", temp_path);
    ::close(fd);
    ::unlink(temp_path.c_str());
    return error;
  }
  ::close(fd);
  if (::rename(temp_path.c_str(), final_path.c_str()) != 0) {
    const Status error = os_error("cannot rename onto", final_path);
    ::unlink(temp_path.c_str());
    return error;
  }
  const int dir = ::open(path_.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (dir >= 0) {
    ::fsync(dir);
    ::close(dir);
  }
  return stamp_of(info);  // rename keeps the inode, size and mtime of the file written
}

std::optional<FileStamp> StateDirectory::stamp(const SessionId& id) const {
  if (!is_valid_session_id(id.value)) return std::nullopt;
  struct stat info {};
  if (::stat(file_of(id).c_str(), &info) != 0) return std::nullopt;
  return stamp_of(info);
}

Result<PersistedSession> StateDirectory::read(const SessionId& id, FileStamp* stamp) const {
  if (!is_valid_session_id(id.value)) return Error(ErrorCode::NotFound, "no such session file");
  const std::string path = file_of(id);
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) {
    if (errno == ENOENT) return Error(ErrorCode::NotFound, "no such session file");
    return os_error("cannot open", path);
  }
  if (stamp != nullptr) {
    struct stat info {};
    if (::fstat(fd, &info) == 0) *stamp = stamp_of(info);
  }
  std::string bytes;
  char buffer[1 << 16];
  while (true) {
    const ssize_t n = ::read(fd, buffer, sizeof buffer);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) break;
    bytes.append(buffer, static_cast<std::size_t>(n));
  }
  ::close(fd);
  Result<PersistedSession> state = decode_session(bytes);
  if (state.ok() && state->id.value != id.value) {
    return Error(ErrorCode::InvalidArgument, "state file " + path + " holds another session");
  }
  return state;
}

std::optional<double> StateDirectory::age_seconds(const SessionId& id) const {
  if (!is_valid_session_id(id.value)) return std::nullopt;
  struct stat info {};
  if (::stat(file_of(id).c_str(), &info) != 0) return std::nullopt;
  timespec now{};
  clock_gettime(CLOCK_REALTIME, &now);
  return static_cast<double>(now.tv_sec - info.st_mtim.tv_sec) +
         1e-9 * static_cast<double>(now.tv_nsec - info.st_mtim.tv_nsec);
}

void StateDirectory::remove(const SessionId& id) const {
  if (is_valid_session_id(id.value)) ::unlink(file_of(id).c_str());
}

std::vector<SessionId> StateDirectory::list() const {
  std::vector<SessionId> ids;
  DIR* dir = ::opendir(path_.c_str());
  if (dir == nullptr) return ids;
  while (const dirent* entry = ::readdir(dir)) {
    const std::string_view name = entry->d_name;
    constexpr std::string_view kSuffix = ".state";
    if (name.size() == 32 + kSuffix.size() && name.ends_with(kSuffix) &&
        is_valid_session_id(name.substr(0, 32))) {
      ids.push_back(SessionId{std::string(name.substr(0, 32))});
    }
  }
  ::closedir(dir);
  return ids;
}

}  // namespace meshdeform::service
