#include "format/io/atomic_file.h"

#include <sys/stat.h>

#include <cerrno>
#include <climits>
#include <cstdio>
#include <cstdlib>
#include <utility>

#include "format/io/io_trace.h"

namespace ltb::io {

namespace {

constexpr const char* kReplaceOnly =
    "ltbake writes its outputs only as regular files and replaces nothing else (remove it, or name another output "
    "path)";

}  // namespace

Result<std::string> ReplaceableOutput(const std::string& path) {
  struct stat st;
  if (::lstat(path.c_str(), &st) != 0) {
    if (errno == ENOENT) return path;
    return IoError(path + ": cannot stat the output path", errno);
  }
  if (S_ISREG(st.st_mode)) return path;
  if (!S_ISLNK(st.st_mode)) {
    return InvalidArgument(path + ": is " + FileKind(st.st_mode) + ", not a regular file; " + kReplaceOnly);
  }
  char resolved[PATH_MAX];
  if (::realpath(path.c_str(), resolved) == nullptr) {
    int err = errno;
    if (err == ENOENT) {
      return InvalidArgument(path + ": is a symbolic link to a file that does not exist; " + kReplaceOnly);
    }
    return IoError(path + ": cannot resolve the symbolic link", err);
  }
  const std::string target = resolved;
  if (::stat(target.c_str(), &st) != 0) return IoError(path + ": cannot stat " + target, errno);
  if (!S_ISREG(st.st_mode)) {
    return InvalidArgument(path + ": is a symbolic link to " + target + ", which is " + FileKind(st.st_mode) +
                           ", not a regular file; " + kReplaceOnly);
  }
  return target;
}

Result<AtomicFile> AtomicFile::Create(const std::string& path) {
  AtomicFile f;
  f.path_ = path;
  LTB_ASSIGN_OR_RETURN(f.target_, ReplaceableOutput(path));
  f.temp_ = f.target_ + ".partial";
  if (std::remove(f.temp_.c_str()) != 0) {
    if (errno != ENOENT) return IoError(f.temp_ + ": cannot remove the partial file a killed writer left", errno);
  } else {
    RecordIo({IoOp::Kind::kRemove, f.temp_, {}, 0, {}});
  }
  LTB_ASSIGN_OR_RETURN(f.file_, File::Open(f.temp_, File::Mode::kCreateExclusive));
  return f;
}

AtomicFile::AtomicFile(AtomicFile&& other) noexcept
    : file_(std::move(other.file_)),
      path_(std::move(other.path_)),
      target_(std::move(other.target_)),
      temp_(std::move(other.temp_)) {
  other.temp_.clear();
}

AtomicFile& AtomicFile::operator=(AtomicFile&& other) noexcept {
  if (this != &other) {
    Discard();
    file_ = std::move(other.file_);
    path_ = std::move(other.path_);
    target_ = std::move(other.target_);
    temp_ = std::move(other.temp_);
    other.temp_.clear();
  }
  return *this;
}

AtomicFile::~AtomicFile() { Discard(); }

void AtomicFile::Discard() {
  if (temp_.empty()) return;
  (void)file_.Close();
  if (std::remove(temp_.c_str()) == 0) RecordIo({IoOp::Kind::kRemove, temp_, {}, 0, {}});
  temp_.clear();
}

Status AtomicFile::Commit() {
  if (temp_.empty()) return FailedPrecondition(path_ + ": AtomicFile committed twice or never created");
  Status s = BarrierSkipped(kBarrierAtomicDataSync) ? Status::Ok() : file_.DataSync();
  if (s.ok()) s = file_.Close();
  // Again right before the rename: what was at path may have changed while the data was
  // written (a FIFO made there, a link pointed elsewhere).
  if (s.ok()) {
    auto target = ReplaceableOutput(path_);
    if (!target.ok()) {
      s = target.status();
    } else if (*target != target_) {
      s = FailedPrecondition(path_ + ": now points to " + *target + ", not to " + target_ +
                             " as when this output was started; nothing was replaced (run the command again)");
    }
  }
  if (s.ok() && std::rename(temp_.c_str(), target_.c_str()) != 0) {
    s = IoError(target_ + ": rename from " + temp_, errno);
  } else if (s.ok()) {
    RecordIo({IoOp::Kind::kRename, temp_, target_, 0, {}});
  }
  if (!s.ok()) {
    Discard();
    return s;
  }
  temp_.clear();
  return BarrierSkipped(kBarrierAtomicDirSync) ? Status::Ok() : SyncParentDirectory(target_);
}

Status WriteFileAtomically(const std::string& path, format::ByteSpan bytes) {
  LTB_ASSIGN_OR_RETURN(AtomicFile f, AtomicFile::Create(path));
  LTB_RETURN_IF_ERROR(f.file().WriteAt(0, bytes));
  return f.Commit();
}

Status WriteFileAtomically(const std::string& path, const std::string& text) {
  return WriteFileAtomically(path, format::ByteSpan(reinterpret_cast<const std::byte*>(text.data()), text.size()));
}

}  // namespace ltb::io
