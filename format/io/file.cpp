#include "format/io/file.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>

#include "format/io/io_trace.h"

namespace ltb::io {

File::~File() {
  if (fd_ >= 0) ::close(fd_);
}

File::File(File&& other) noexcept : fd_(other.fd_), path_(std::move(other.path_)) { other.fd_ = -1; }

File& File::operator=(File&& other) noexcept {
  if (this != &other) {
    if (fd_ >= 0) ::close(fd_);
    fd_ = other.fd_;
    path_ = std::move(other.path_);
    other.fd_ = -1;
  }
  return *this;
}

std::string FileKind(unsigned mode) {
  switch (mode & S_IFMT) {
    case S_IFREG:
      return "a regular file";
    case S_IFDIR:
      return "a directory";
    case S_IFIFO:
      return "a FIFO (named pipe)";
    case S_IFCHR:
      return "a character device";
    case S_IFBLK:
      return "a block device";
    case S_IFSOCK:
      return "a socket";
    case S_IFLNK:
      return "a symbolic link";
  }
  return "not a regular file (file type " + std::to_string(mode & S_IFMT) + ")";
}

namespace {

constexpr const char* kOnlyRegular = "ltbake reads and writes only regular files (give the path of a file)";

Status NotRegular(const std::string& path, unsigned mode, const std::string& wanted = kOnlyRegular) {
  return InvalidArgument(path + ": is " + FileKind(mode) + ", not a regular file; " + wanted);
}

}  // namespace

Status RequireRegularFile(const std::string& path, const std::string& wanted) {
  struct stat st;
  if (::stat(path.c_str(), &st) != 0) {
    int err = errno;
    if (err == ENOENT) return NotFound(path + ": no such file" + (wanted.empty() ? "" : "; " + wanted));
    return IoError(path + ": cannot open", err);
  }
  if (!S_ISREG(st.st_mode)) return NotRegular(path, st.st_mode, wanted.empty() ? kOnlyRegular : wanted);
  return Status::Ok();
}

Result<File> File::Open(const std::string& path, Mode mode, bool inherit) {
  // O_NONBLOCK: opening a FIFO for reading would otherwise wait for a writer (forever, and
  // deaf to signals). What the path is gets checked on the descriptor (fstat, no race with
  // a rename), then the flag is cleared: regular files ignore it anyway.
  int flags = (inherit ? 0 : O_CLOEXEC) | O_NONBLOCK;
  switch (mode) {
    case Mode::kRead:
      flags |= O_RDONLY;
      break;
    case Mode::kReadWrite:
      flags |= O_RDWR;
      break;
    case Mode::kCreate:
      flags |= O_RDWR | O_CREAT;
      break;
    case Mode::kCreateExclusive:
      flags |= O_RDWR | O_CREAT | O_EXCL;
      break;
    case Mode::kWriteDirect:
      flags |= O_WRONLY | O_DIRECT;
      break;
    case Mode::kReadDirect:
      flags |= O_RDONLY | O_DIRECT;
      break;
  }
  int fd;
  do {
    fd = ::open(path.c_str(), flags, 0644);
  } while (fd < 0 && errno == EINTR);
  if (fd < 0) {
    int err = errno;
    struct stat st;
    // EISDIR (a directory opened for writing), ENXIO (a FIFO without a reader, a socket):
    // say what the path is rather than the errno.
    if ((err == EISDIR || err == ENXIO || err == EOPNOTSUPP) && ::stat(path.c_str(), &st) == 0 &&
        !S_ISREG(st.st_mode)) {
      return NotRegular(path, st.st_mode);
    }
    Status s = IoError(path + ": cannot open", err);
    if (err == ENOENT) return Status(StatusCode::kNotFound, s.message());
    return s;
  }
  struct stat st;
  if (::fstat(fd, &st) != 0) {
    int err = errno;
    ::close(fd);
    return IoError(path + ": fstat", err);
  }
  if (!S_ISREG(st.st_mode)) {
    ::close(fd);
    return NotRegular(path, st.st_mode);
  }
  int fl = ::fcntl(fd, F_GETFL);
  if (fl < 0 || ::fcntl(fd, F_SETFL, fl & ~O_NONBLOCK) != 0) {
    int err = errno;
    ::close(fd);
    return IoError(path + ": fcntl(F_SETFL)", err);
  }
  if (mode == Mode::kCreate || mode == Mode::kCreateExclusive) RecordIo({IoOp::Kind::kCreate, path, {}, 0, {}});
  File f;
  f.fd_ = fd;
  f.path_ = path;
  return f;
}

Result<uint64_t> File::Size() const {
  struct stat st;
  if (::fstat(fd_, &st) != 0) return IoError(path_ + ": fstat", errno);
  return static_cast<uint64_t>(st.st_size);
}

Status File::ReadAt(uint64_t offset, format::MutableByteSpan out) const {
  size_t done = 0;
  while (done < out.size()) {
    ssize_t n = ::pread(fd_, out.data() + done, out.size() - done, static_cast<off_t>(offset + done));
    if (n < 0) {
      if (errno == EINTR) continue;
      return IoError(path_ + ": read of " + std::to_string(out.size()) + " bytes at offset " + std::to_string(offset),
                     errno);
    }
    if (n == 0) {
      return DataLoss(path_ + ": unexpected end of file reading " + std::to_string(out.size()) + " bytes at offset " +
                      std::to_string(offset));
    }
    done += static_cast<size_t>(n);
  }
  return Status::Ok();
}

Status File::WriteAt(uint64_t offset, format::ByteSpan data) const {
  size_t done = 0;
  while (done < data.size()) {
    ssize_t n = ::pwrite(fd_, data.data() + done, data.size() - done, static_cast<off_t>(offset + done));
    if (n < 0) {
      if (errno == EINTR) continue;
      return IoError(path_ + ": write of " + std::to_string(data.size()) + " bytes at offset " + std::to_string(offset),
                     errno);
    }
    done += static_cast<size_t>(n);
  }
  if (Recording()) RecordIo({IoOp::Kind::kWrite, path_, {}, offset, std::vector<std::byte>(data.begin(), data.end())});
  return Status::Ok();
}

Status File::Truncate(uint64_t size) const {
  if (::ftruncate(fd_, static_cast<off_t>(size)) != 0) {
    return IoError(path_ + ": truncate to " + std::to_string(size) + " bytes", errno);
  }
  RecordIo({IoOp::Kind::kTruncate, path_, {}, size, {}});
  return Status::Ok();
}

Status File::DataSync() const {
  if (::fdatasync(fd_) != 0) return IoError(path_ + ": fdatasync", errno);
  RecordIo({IoOp::Kind::kSync, path_, {}, 0, {}});
  return Status::Ok();
}

Status File::Close() {
  if (fd_ < 0) return Status::Ok();
  int rc = ::close(fd_);
  fd_ = -1;
  if (rc != 0) return IoError(path_ + ": close", errno);
  return Status::Ok();
}

Status SyncParentDirectory(const std::string& path) {
  std::string dir = ".";
  size_t slash = path.find_last_of('/');
  if (slash != std::string::npos) dir = slash == 0 ? "/" : path.substr(0, slash);
  int fd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (fd < 0) return IoError(dir + ": open directory", errno);
  int rc = ::fsync(fd);
  int err = errno;
  ::close(fd);
  if (rc != 0) return IoError(dir + ": fsync directory", err);
  RecordIo({IoOp::Kind::kSyncDir, dir, {}, 0, {}});
  return Status::Ok();
}

bool PathExists(const std::string& path) {
  struct stat st;
  return ::stat(path.c_str(), &st) == 0;
}

}  // namespace ltb::io
