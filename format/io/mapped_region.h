// A read-only mapping of a byte range of a file. The range need not be page-aligned;
// the mapping is, and data() points at the requested offset. Unmapping drops the pages
// from the process (they stay in the page cache), so RSS while streaming a large file
// through chunk-sized mappings stays at a few chunks.
#pragma once

#include <cstdint>

#include "format/bytes.h"
#include "format/status.h"

namespace ltb::io {

class MappedRegion {
 public:
  MappedRegion() = default;
  ~MappedRegion();
  MappedRegion(MappedRegion&& other) noexcept;
  MappedRegion& operator=(MappedRegion&& other) noexcept;
  MappedRegion(const MappedRegion&) = delete;
  MappedRegion& operator=(const MappedRegion&) = delete;

  // The caller has checked offset + length <= file size.
  static Result<MappedRegion> Map(int fd, uint64_t offset, uint64_t length, bool sequential);

  format::ByteSpan bytes() const { return {data_, length_}; }

 private:
  void Reset();
  void* base_ = nullptr;
  size_t base_length_ = 0;
  const std::byte* data_ = nullptr;
  size_t length_ = 0;
};

}  // namespace ltb::io
