#include "format/io/mapped_region.h"

#include <sys/mman.h>
#include <unistd.h>

#include <cerrno>

namespace ltb::io {

MappedRegion::~MappedRegion() { Reset(); }

MappedRegion::MappedRegion(MappedRegion&& other) noexcept
    : base_(other.base_), base_length_(other.base_length_), data_(other.data_), length_(other.length_) {
  other.base_ = nullptr;
  other.base_length_ = 0;
  other.data_ = nullptr;
  other.length_ = 0;
}

MappedRegion& MappedRegion::operator=(MappedRegion&& other) noexcept {
  if (this != &other) {
    Reset();
    std::swap(base_, other.base_);
    std::swap(base_length_, other.base_length_);
    std::swap(data_, other.data_);
    std::swap(length_, other.length_);
  }
  return *this;
}

void MappedRegion::Reset() {
  if (base_ != nullptr) ::munmap(base_, base_length_);
  base_ = nullptr;
  base_length_ = 0;
  data_ = nullptr;
  length_ = 0;
}

Result<MappedRegion> MappedRegion::Map(int fd, uint64_t offset, uint64_t length, bool sequential) {
  MappedRegion r;
  if (length == 0) return r;
  static const uint64_t page = static_cast<uint64_t>(::sysconf(_SC_PAGESIZE));
  uint64_t aligned = offset / page * page;
  uint64_t skip = offset - aligned;
  void* p = ::mmap(nullptr, skip + length, PROT_READ, MAP_SHARED, fd, static_cast<off_t>(aligned));
  if (p == MAP_FAILED) {
    return IoError("mmap of " + std::to_string(length) + " bytes at offset " + std::to_string(offset), errno);
  }
  if (sequential) ::madvise(p, skip + length, MADV_WILLNEED);  // start readahead of the whole range
  r.base_ = p;
  r.base_length_ = skip + length;
  r.data_ = static_cast<const std::byte*>(p) + skip;
  r.length_ = length;
  return r;
}

}  // namespace ltb::io
