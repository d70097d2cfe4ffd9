#pragma once
/// @file persistence.h
/// Session state on disk (issue 6): one file per session in a state directory, written
/// atomically (temporary file, fsync, rename, fsync of the directory) after every committed
/// revision and every SetHandles, before the edit is acknowledged. A file holds everything needed
/// to resume: the rest mesh, the lambda, both tokens, the handle groups with their anchors and
/// targets, the current positions, the revision and the last method. Factorizations are not
/// stored: they are rebuilt on the first move after a restore.
///
/// Format: "MDSTATE1", u64 payload length, payload (little-endian fields), CRC-32 of the
/// payload. A short, oversized or mismatching file is reported as corrupt, never trusted.
/// Files are created with mode 0600 (they hold the session's tokens); the directory with 0700.

#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "core/methods/deformer.h"
#include "core/mesh/mesh_data.h"
#include "core/base/status.h"
#include "server/service/types.h"

namespace meshdeform::service {

/// Everything a session needs to resume.
struct PersistedSession {
  SessionId id;
  Token edit_token;
  Token view_token;
  double lambda = 100;
  MeshData rest;
  std::vector<HandleGroup> groups;
  Positions anchors;    ///< #C x 3, rows in ascending vertex order of the groups' union
  Positions targets;    ///< #C x 3
  Positions positions;  ///< #V x 3 at `revision`
  std::uint64_t revision = 0;
  std::optional<core::Method> last_method;
  EditState edit;  ///< settings and undo history (issue 17)
};

class BinaryWriter;
class BinaryReader;

/// The part of a session's state that edits change (groups with their vertices, anchors,
/// targets, positions, revision, last method, edit settings and history): written the same way
/// into the state file and into the Redis store's state key. Format: u32 group count, per group
/// u8 role (0 fixed) and u32 size and i32 vertices; matrices anchors, targets, positions; u64
/// revision; i32 method (-1 none); then the tag "EDT1" and the edit state (edit_history.h). Bytes
/// written before the edit state existed end after the method and read as an empty history.
void write_session_state(BinaryWriter& out, const PersistedSession& state);
/// Reads that part into `state`, whose rest mesh must already be set (vertex indices and sizes
/// are checked against it). @return InvalidArgument naming the field when corrupt.
[[nodiscard]] Status read_session_state(BinaryReader& in, PersistedSession& state);

/// The checksum a state file ends with: CRC-32 (IEEE 802.3) of its payload.
std::uint32_t state_checksum(std::string_view payload);

/// Serialises a session state (the file's bytes, header and checksum included).
std::string encode_session(const PersistedSession& state);
/// Parses and checks a file's bytes.
/// @return the state; InvalidArgument naming what is wrong (bad magic, length, checksum,
///         truncated field, counts out of range, an index out of range).
[[nodiscard]] Result<PersistedSession> decode_session(std::string_view bytes);

/// True for the ids this server issues (32 lower-case hex digits): only those name files.
bool is_valid_session_id(std::string_view id);

/// One version of a state file: every atomic replace (a rename of a new file) gives a new inode,
/// so a replica can tell whether a file is still the one it wrote or read.
struct FileStamp {
  std::uint64_t device = 0;
  std::uint64_t inode = 0;
  std::uint64_t size = 0;
  std::int64_t mtime_ns = 0;
  bool operator==(const FileStamp&) const = default;
};

/// Consulted before each system call that writes a state file, with the call's name ("open",
/// "write", "fsync", "rename", "fsync_dir"); a non-zero errno fails that call (tests: a full
/// disk, no descriptors). Empty: no faults.
using WriteFault = std::function<int(std::string_view call)>;

/// A session's next state written and fsync'd under a temporary name, not yet visible
/// (StateDirectory::stage). Destroying it unpublished removes the temporary file.
class StagedWrite {
 public:
  StagedWrite() = default;
  StagedWrite(StagedWrite&& other) noexcept { *this = std::move(other); }
  StagedWrite& operator=(StagedWrite&& other) noexcept;
  StagedWrite(const StagedWrite&) = delete;
  StagedWrite& operator=(const StagedWrite&) = delete;
  ~StagedWrite();

 private:
  friend class StateDirectory;
  SessionId id_;
  std::string temp_path_;  ///< empty once published or discarded
  FileStamp stamp_;        ///< what the file will be once renamed (rename keeps it)
};

/// A file of the state directory that start-up did not read, and why.
struct SkippedStateFile {
  std::string file;    ///< its name in the directory
  std::string reason;  ///< "a FIFO", "a symbolic link (not followed)", "larger than ..."
};

/// A directory of session files `<id>.state`, shared by every replica started on it.
///
/// What it promises (docs/architecture.md, "Reliability: what each store promises"): an edit is acknowledged only after its
/// state file is on disk: written to a temporary file, fsync'd, renamed over the session's file
/// and the directory fsync'd. Each rename is a compare-and-set between the processes sharing the
/// directory: it happens only if the session's file is still the one the writing copy last wrote
/// or read (an advisory lock on `.lock` in the directory, plus a mutex within the process,
/// serialises the check and the rename), so a stale copy cannot overwrite a newer revision and
/// nothing can recreate a closed session's file. Only regular files of bounded size are read.
class StateDirectory {
 public:
  /// Creates the directory (mode 0700) if needed, checks that it is writable and opens its lock
  /// file. `max_file_bytes` bounds what read() accepts.
  /// @return the directory; InvalidArgument for an empty path; Internal naming the path and the
  ///         OS error when it cannot be created or written.
  [[nodiscard]] static Result<StateDirectory> open(std::string path, WriteFault fault = {},
                                                   std::uint64_t max_file_bytes = kDefaultMaxFileBytes);
  /// read()'s default bound: 1 GiB.
  static constexpr std::uint64_t kDefaultMaxFileBytes = std::uint64_t{1} << 30;

  /// Writes the state to a temporary file of this process (replicas sharing the directory never
  /// write into each other's) and fsyncs it: the slow part, under no lock.
  /// @return the staged file; ResourceExhausted when the disk or the descriptors run out
  ///         (ENOSPC, EDQUOT, EFBIG, EMFILE, ENFILE, ENOMEM), Unavailable for other OS errors,
  ///         both naming the call, the path and the error.
  [[nodiscard]] Result<StagedWrite> stage(const PersistedSession& state) const;
  /// Makes a staged file the session's file, if the file there now is `expected` (nullopt: there
  /// must be none, a new session), and fsyncs the directory.
  /// @param[out] stamp  the new file's stamp once renamed, also when only the directory's fsync
  ///                    failed (the file is then visible but perhaps not durable).
  /// @return success; Aborted when the file is another than `expected` (another process changed
  ///         it: this copy is stale); NotFound when `expected` is set and the file is gone
  ///         (closed or expired elsewhere); ResourceExhausted / Unavailable as stage().
  [[nodiscard]] Status publish(StagedWrite staged, const std::optional<FileStamp>& expected,
                               std::optional<FileStamp>& stamp) const;
  /// @param[out] stamp  if not null, the stamp of the very file read.
  /// @return the state; NotFound when there is no file (or the id is not one of ours);
  ///         InvalidArgument when the file is not a regular file (a FIFO, a device, a symbolic
  ///         link: never followed), is larger than max_file_bytes, or is corrupt (see
  ///         decode_session); Unavailable for other OS errors.
  [[nodiscard]] Result<PersistedSession> read(const SessionId& id, FileStamp* stamp = nullptr) const;
  /// The stamp of the session's file now; nullopt without a file.
  std::optional<FileStamp> stamp(const SessionId& id) const;
  /// Seconds since the file was last written; nullopt without a file.
  std::optional<double> age_seconds(const SessionId& id) const;
  /// Removes the session's file (missing is fine) under the directory's lock: a publish that
  /// expected it fails from then on.
  void remove(const SessionId& id) const;
  /// Removes the session's file only if it is still `expected` (expiry: a file another replica
  /// rewrote meanwhile stays). @return whether it was removed.
  bool remove_if(const SessionId& id, const FileStamp& expected) const;
  /// Ids of the session files present (regular files named `<id>.state`).
  std::vector<SessionId> list() const;
  /// As list(), with the files named like session files that are not regular files of bounded
  /// size, and why (start-up reports them).
  std::vector<SessionId> scan(std::vector<SkippedStateFile>& skipped) const;
  const std::string& path() const { return path_; }
  std::uint64_t max_file_bytes() const { return max_file_bytes_; }

 private:
  struct Lock;
  StateDirectory(std::string path, WriteFault fault, std::uint64_t max_file_bytes,
                 std::shared_ptr<Lock> lock)
      : path_(std::move(path)),
        fault_(std::move(fault)),
        max_file_bytes_(max_file_bytes),
        lock_(std::move(lock)) {}
  std::string file_of(const SessionId& id) const;
  /// The injected errno of `call` (0 without a fault hook), also left in errno.
  int injected(std::string_view call) const;
  std::string path_;
  WriteFault fault_;
  std::uint64_t max_file_bytes_ = kDefaultMaxFileBytes;
  std::shared_ptr<Lock> lock_;  ///< the directory's lock (shared by copies of this object)
};

}  // namespace meshdeform::service
