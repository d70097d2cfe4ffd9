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
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "core/deformer.h"
#include "core/mesh_data.h"
#include "core/status.h"
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

/// A directory of session files `<id>.state`.
class StateDirectory {
 public:
  /// Creates the directory (mode 0700) if needed and checks that it is writable.
  /// @return the directory; InvalidArgument for an empty path; Internal naming the path and the
  ///         OS error when it cannot be created or written.
  [[nodiscard]] static Result<StateDirectory> open(std::string path);

  /// Atomically replaces the session's file (through a temporary file of its own, so that
  /// replicas sharing the directory never write into each other's).
  /// @return the stamp of the file written; Internal naming the OS error.
  [[nodiscard]] Result<FileStamp> write(const PersistedSession& state) const;
  /// @param[out] stamp  if not null, the stamp of the very file read.
  /// @return the state; NotFound when there is no file (or the id is not one of ours);
  ///         InvalidArgument when the file is corrupt (see decode_session).
  [[nodiscard]] Result<PersistedSession> read(const SessionId& id, FileStamp* stamp = nullptr) const;
  /// The stamp of the session's file now; nullopt without a file.
  std::optional<FileStamp> stamp(const SessionId& id) const;
  /// Seconds since the file was last written; nullopt without a file.
  std::optional<double> age_seconds(const SessionId& id) const;
  /// Removes the session's file (missing is fine).
  void remove(const SessionId& id) const;
  /// Ids of the session files present.
  std::vector<SessionId> list() const;
  const std::string& path() const { return path_; }

 private:
  explicit StateDirectory(std::string path) : path_(std::move(path)) {}
  std::string file_of(const SessionId& id) const;
  std::string path_;
};

}  // namespace meshdeform::service
