// content_hash: a fingerprint of an array's logical content (shape, dtype and every
// element's bits at its (row, col)), independent of chunk order, chunk size, layout and
// encoding. Defined in docs/FORMAT.md "content_hash" so other tools can recompute it:
//   h(i,j,u) = 0 if u == 0, else fmix64((fmix64(i*K1 ^ S) + j*K2) ^ (u*K3))   (mod 2^64)
//   sum = Σ h over all elements (mod 2^64)
//   content_hash = XXH3-64 of the 40-byte record "LTMCH1\0\0", dtype code, rows, cols, sum
// where u is the element's bit pattern zero-extended to 64 bits. Zero elements contribute
// nothing, so all-zero chunks cost nothing to hash.
#pragma once

#include <cstdint>
#include <string>

#include "format/array_spec.h"
#include "format/bytes.h"

namespace ltb::format {

class ContentHasher {
 public:
  // Adds the decoded bytes of one chunk (in the array's layout).
  void AddChunk(const ArraySpec& spec, const ChunkExtent& extent, ByteSpan decoded);
  void Merge(const ContentHasher& other) { sum_ += other.sum_; }
  // Adds a partial sum from another hasher's sum() (sums are combined modulo 2^64).
  void AddSum(uint64_t partial) { sum_ += partial; }
  uint64_t sum() const { return sum_; }
  // 16 lowercase hex digits.
  std::string Finish(const ArraySpec& spec) const;

 private:
  uint64_t sum_ = 0;
};

// The content_hash sum of one chunk's decoded bytes (what AddChunk adds).
uint64_t ChunkHashSum(const ArraySpec& spec, const ChunkExtent& extent, ByteSpan decoded);

}  // namespace ltb::format
