// A file descriptor with full-length positional reads/writes; every failure names the
// path and strerror(errno). Only regular files open: a directory, FIFO, device or socket is
// refused up front (kInvalidArgument naming the path and what it is), without blocking.
#pragma once

#include <cstdint>
#include <string>

#include "format/bytes.h"
#include "format/status.h"

namespace ltb::io {

class File {
 public:
  // kCreate: read-write, created when missing (lock files). kWriteDirect: an existing file,
  // write-only with O_DIRECT (writes bypass the page cache; offsets, lengths and buffers
  // must be aligned to the device's block size). kReadDirect: read-only with O_DIRECT (the
  // same alignment rules; reads bypass, and do not evict, the page cache).
  enum class Mode { kRead, kReadWrite, kCreate, kCreateExclusive, kWriteDirect, kReadDirect };

  File() = default;
  ~File();
  File(File&& other) noexcept;
  File& operator=(File&& other) noexcept;
  File(const File&) = delete;
  File& operator=(const File&) = delete;

  // Fails with kNotFound when the path does not exist, kInvalidArgument when it is not a
  // regular file (a FIFO is opened non-blocking to find out: no wait for a writer).
  // `inherit`: the descriptor stays open across exec (no O_CLOEXEC).
  static Result<File> Open(const std::string& path, Mode mode, bool inherit = false);

  Result<uint64_t> Size() const;
  // Reads exactly out.size() bytes at offset (fails on a short file).
  Status ReadAt(uint64_t offset, format::MutableByteSpan out) const;
  Status WriteAt(uint64_t offset, format::ByteSpan data) const;
  Status Truncate(uint64_t size) const;
  Status DataSync() const;
  Status Close();

  int fd() const { return fd_; }
  // Gives up the descriptor (the caller closes it); the File is closed afterwards.
  int Release() {
    int fd = fd_;
    fd_ = -1;
    return fd;
  }
  const std::string& path() const { return path_; }

 private:
  int fd_ = -1;
  std::string path_;
};

// "a directory", "a FIFO (named pipe)", "a character device", ... for a st_mode.
std::string FileKind(unsigned mode);
// For readers that open files through another library (std::ifstream, OpenEXR, Draco) or
// that want to refuse a path before any work: Ok for a regular file (symbolic links
// followed); kNotFound "PATH: no such file", or kInvalidArgument "PATH: is a FIFO (named
// pipe), not a regular file", otherwise, each followed by `wanted` ("name a .exr or .hdr
// image file") when given. Never blocks.
Status RequireRegularFile(const std::string& path, const std::string& wanted = "");

// fsync of the directory holding path, so a rename in it is durable.
Status SyncParentDirectory(const std::string& path);
bool PathExists(const std::string& path);

}  // namespace ltb::io
