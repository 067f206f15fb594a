#include "format/io/atomic_file.h"

#include <cerrno>
#include <cstdio>
#include <utility>

namespace ltb::io {

Result<AtomicFile> AtomicFile::Create(const std::string& path) {
  AtomicFile f;
  f.path_ = path;
  f.temp_ = path + ".partial";
  if (std::remove(f.temp_.c_str()) != 0 && errno != ENOENT) {
    return IoError(f.temp_ + ": cannot remove the partial file a killed writer left", errno);
  }
  LTB_ASSIGN_OR_RETURN(f.file_, File::Open(f.temp_, File::Mode::kCreateExclusive));
  return f;
}

AtomicFile::AtomicFile(AtomicFile&& other) noexcept
    : file_(std::move(other.file_)), path_(std::move(other.path_)), temp_(std::move(other.temp_)) {
  other.temp_.clear();
}

AtomicFile& AtomicFile::operator=(AtomicFile&& other) noexcept {
  if (this != &other) {
    Discard();
    file_ = std::move(other.file_);
    path_ = std::move(other.path_);
    temp_ = std::move(other.temp_);
    other.temp_.clear();
  }
  return *this;
}

AtomicFile::~AtomicFile() { Discard(); }

void AtomicFile::Discard() {
  if (temp_.empty()) return;
  (void)file_.Close();
  std::remove(temp_.c_str());
  temp_.clear();
}

Status AtomicFile::Commit() {
  if (temp_.empty()) return FailedPrecondition(path_ + ": AtomicFile committed twice or never created");
  Status s = file_.DataSync();
  if (s.ok()) s = file_.Close();
  if (s.ok() && std::rename(temp_.c_str(), path_.c_str()) != 0) s = IoError(path_ + ": rename from " + temp_, errno);
  if (!s.ok()) {
    Discard();
    return s;
  }
  temp_.clear();
  return SyncParentDirectory(path_);
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
