// Files that appear whole or not at all. An AtomicFile is written under PATH.partial and
// renamed over PATH by Commit(), after its data is synced; the directory is synced after the
// rename. Until then PATH keeps its old content (or does not exist); a crash leaves at most
// PATH.partial, which the next writer of PATH removes. One process writes a given PATH at a
// time: callers that may race hold the output's lock (io::LockOutput) first.
//
// What may be replaced: nothing (PATH does not exist) or a regular file. A directory, FIFO,
// device or socket at PATH is refused (kInvalidArgument naming the path and what it is), so
// `-o /dev/full` never turns a device node into a file. A symbolic link is followed: the
// regular file it points to is replaced (written beside it, as TARGET.partial) and the link
// stays; a link to a missing file or to anything but a regular file is refused. The check is
// made when the file is created and again right before the rename.
#pragma once

#include <string>

#include "format/bytes.h"
#include "format/io/file.h"
#include "format/status.h"

namespace ltb::io {

class AtomicFile {
 public:
  // Creates PATH.partial (a stale one from a killed writer is removed first).
  static Result<AtomicFile> Create(const std::string& path);

  AtomicFile() = default;
  AtomicFile(AtomicFile&& other) noexcept;
  AtomicFile& operator=(AtomicFile&& other) noexcept;
  AtomicFile(const AtomicFile&) = delete;
  AtomicFile& operator=(const AtomicFile&) = delete;
  // Removes the temporary file unless Commit() succeeded.
  ~AtomicFile();

  // The temporary file: write through it, or let a library write to temp_path() (the data
  // of that path is synced through this descriptor, the same file, at Commit).
  const File& file() const { return file_; }
  const std::string& temp_path() const { return temp_; }
  const std::string& path() const { return path_; }
  // The file that Commit() replaces: path(), or the regular file a symbolic link there
  // points to.
  const std::string& target() const { return target_; }

  // Syncs and closes the temporary file, renames it to path() and syncs the directory.
  // On failure the temporary file is removed and path() is as it was.
  Status Commit();

 private:
  void Discard();

  File file_;
  std::string path_, target_, temp_;
};

// Where an output written by rename may go: path itself when it does not exist or is a
// regular file; the regular file a symbolic link at path resolves to; otherwise
// kInvalidArgument "PATH: is a character device, not a regular file; ..." (the error names
// the link's target too).
Result<std::string> ReplaceableOutput(const std::string& path);

// The whole file in one call, through an AtomicFile.
Status WriteFileAtomically(const std::string& path, format::ByteSpan bytes);
Status WriteFileAtomically(const std::string& path, const std::string& text);

}  // namespace ltb::io
