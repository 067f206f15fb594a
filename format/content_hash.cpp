#include "format/content_hash.h"

#include <xxhash.h>

#include <algorithm>
#include <array>
#include <cstring>
#include <vector>

namespace ltb::format {
namespace {

constexpr uint64_t kK1 = 0x9E3779B97F4A7C15ull;
constexpr uint64_t kK2 = 0xC2B2AE3D27D4EB4Full;
constexpr uint64_t kK3 = 0x165667B19E3779F9ull;
constexpr uint64_t kSeed = 0x27D4EB2F165667C5ull;

inline uint64_t Fmix64(uint64_t k) {
  k ^= k >> 33;
  k *= 0xFF51AFD7ED558CCDull;
  k ^= k >> 33;
  k *= 0xC4CEB9FE1A85EC53ull;
  k ^= k >> 33;
  return k;
}

inline uint64_t RowKey(uint64_t i) { return Fmix64((i * kK1) ^ kSeed); }

// Σ h over `n` consecutive elements of one row-major line whose first element has the
// position key `pos` (RowKey(i) + j·K2); the key steps by K2. Written so that GCC
// vectorises it (the 64-bit products are emulated across lanes).
template <typename U>
uint64_t HashLine(const U* v, uint64_t n, uint64_t pos) {
  uint64_t sum = 0;
  for (uint64_t c = 0; c < n; ++c, pos += kK2) {
    uint64_t u = v[c];
    uint64_t h = Fmix64(pos ^ (u * kK3));
    sum += u != 0 ? h : 0;
  }
  return sum;
}

// HashLine in blocks, skipping blocks that are all zero: transformed and quantized
// matrices are mostly zeros, often in long runs (a block costs one OR pass to skip).
template <typename U>
uint64_t HashLineSkippingZeros(const U* v, uint64_t n, uint64_t pos) {
  constexpr uint64_t kBlock = 64;
  uint64_t sum = 0;
  for (uint64_t c = 0; c < n; c += kBlock) {
    const uint64_t m = std::min(kBlock, n - c);
    U any = 0;
    for (uint64_t k = 0; k < m; ++k) any |= v[c + k];
    if (any != 0) sum += HashLine(v + c, m, pos + c * kK2);
  }
  return sum;
}

template <typename U>
uint64_t HashRowMajor(const U* data, uint64_t row0, uint64_t rows, uint64_t col0, uint64_t cols) {
  uint64_t sum = 0;
  for (uint64_t r = 0; r < rows; ++r)
    sum += HashLineSkippingZeros(data + r * cols, cols, RowKey(row0 + r) + col0 * kK2);
  return sum;
}

// Σ h over `n` consecutive rows of one column: element t is (row0 + t, col), keys[t] = RowKey(row0 + t).
template <typename U>
uint64_t HashColumnRun(const U* v, uint64_t n, const uint64_t* keys, uint64_t cpart) {
  uint64_t sum = 0;
  for (uint64_t r = 0; r < n; ++r) {
    uint64_t u = v[r];
    uint64_t h = Fmix64((keys[r] + cpart) ^ (u * kK3));
    sum += u != 0 ? h : 0;
  }
  return sum;
}

// RowKey(row0 + r) for r < n, kept per thread: column-major chunks hold whole columns of
// the same rows, chunk after chunk, so the keys are computed once, not once per chunk.
const uint64_t* RowKeys(uint64_t row0, uint64_t n) {
  struct Cache {
    uint64_t row0 = 0;
    std::vector<uint64_t> keys;
  };
  thread_local Cache cache;
  if (cache.row0 != row0 || cache.keys.size() != n) {
    cache.keys.resize(n);
    for (uint64_t r = 0; r < n; ++r) cache.keys[r] = RowKey(row0 + r);
    cache.row0 = row0;
  }
  return cache.keys.data();
}

template <typename U>
uint64_t HashColMajor(const U* data, uint64_t row0, uint64_t rows, uint64_t col0, uint64_t cols) {
  constexpr uint64_t kTile = uint64_t{1} << 20, kBlock = 64;  // at most 8 MiB of cached keys
  uint64_t sum = 0;
  for (uint64_t t0 = 0; t0 < rows; t0 += kTile) {
    uint64_t tn = std::min(kTile, rows - t0);
    const uint64_t* keys = RowKeys(row0 + t0, tn);
    for (uint64_t c = 0; c < cols; ++c) {
      const U* col = data + c * rows + t0;
      uint64_t cpart = (col0 + c) * kK2;
      for (uint64_t b = 0; b < tn; b += kBlock) {
        const uint64_t m = std::min(kBlock, tn - b);
        U any = 0;
        for (uint64_t k = 0; k < m; ++k) any |= col[b + k];
        if (any != 0) sum += HashColumnRun(col + b, m, keys + b, cpart);
      }
    }
  }
  return sum;
}

template <typename U>
uint64_t HashTyped(const std::byte* bytes, const ArraySpec& spec, const ChunkExtent& e) {
  const U* data = reinterpret_cast<const U*>(bytes);
  if (spec.layout == Layout::kRows) return HashRowMajor(data, e.row0, e.rows, e.col0, e.cols);
  return HashColMajor(data, e.row0, e.rows, e.col0, e.cols);
}

}  // namespace

void ContentHasher::AddChunk(const ArraySpec& spec, const ChunkExtent& extent, ByteSpan decoded) {
  // Chunk payloads are 64-byte aligned (mmap) or come from vectors, so typed access is aligned.
  switch (DTypeSize(spec.dtype)) {
    case 1:
      sum_ += HashTyped<uint8_t>(decoded.data(), spec, extent);
      break;
    case 4:
      sum_ += HashTyped<uint32_t>(decoded.data(), spec, extent);
      break;
    case 8:
      sum_ += HashTyped<uint64_t>(decoded.data(), spec, extent);
      break;
  }
}

uint64_t ChunkHashSum(const ArraySpec& spec, const ChunkExtent& extent, ByteSpan decoded) {
  ContentHasher h;
  h.AddChunk(spec, extent, decoded);
  return h.sum();
}

std::string ContentHasher::Finish(const ArraySpec& spec) const {
  std::array<std::byte, 40> rec{};
  std::memcpy(rec.data(), "LTMCH1\0\0", 8);
  StoreU64(&rec[8], static_cast<uint64_t>(spec.dtype));
  StoreU64(&rec[16], spec.rows);
  StoreU64(&rec[24], spec.cols);
  StoreU64(&rec[32], sum_);
  return Hex64(XXH3_64bits(rec.data(), rec.size())).substr(2);
}

}  // namespace ltb::format
