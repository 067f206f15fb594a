// Files that appear whole or not at all. An AtomicFile is written under PATH.partial and
// renamed over PATH by Commit(), after its data is synced; the directory is synced after the
// rename. Until then PATH keeps its old content (or does not exist); a crash leaves at most
// PATH.partial, which the next writer of PATH removes. One process writes a given PATH at a
// time: callers that may race hold the output's lock (io::LockOutput) first.
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

  // Syncs and closes the temporary file, renames it to path() and syncs the directory.
  // On failure the temporary file is removed and path() is as it was.
  Status Commit();

 private:
  void Discard();

  File file_;
  std::string path_, temp_;
};

// The whole file in one call, through an AtomicFile.
Status WriteFileAtomically(const std::string& path, format::ByteSpan bytes);
Status WriteFileAtomically(const std::string& path, const std::string& text);

}  // namespace ltb::io
