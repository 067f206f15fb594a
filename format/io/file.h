// A file descriptor with full-length positional reads/writes; every failure names the
// path and strerror(errno).
#pragma once

#include <cstdint>
#include <string>

#include "format/bytes.h"
#include "format/status.h"

namespace ltb::io {

class File {
 public:
  // kWriteDirect: an existing file, write-only with O_DIRECT (writes bypass the page cache;
  // offsets, lengths and buffers must be aligned to the device's block size).
  enum class Mode { kRead, kReadWrite, kCreateExclusive, kWriteDirect };

  File() = default;
  ~File();
  File(File&& other) noexcept;
  File& operator=(File&& other) noexcept;
  File(const File&) = delete;
  File& operator=(const File&) = delete;

  static Result<File> Open(const std::string& path, Mode mode);

  Result<uint64_t> Size() const;
  // Reads exactly out.size() bytes at offset (fails on a short file).
  Status ReadAt(uint64_t offset, format::MutableByteSpan out) const;
  Status WriteAt(uint64_t offset, format::ByteSpan data) const;
  Status Truncate(uint64_t size) const;
  Status DataSync() const;
  Status Close();

  int fd() const { return fd_; }
  const std::string& path() const { return path_; }

 private:
  int fd_ = -1;
  std::string path_;
};

// fsync of the directory holding path, so a rename in it is durable.
Status SyncParentDirectory(const std::string& path);
bool PathExists(const std::string& path);

}  // namespace ltb::io
