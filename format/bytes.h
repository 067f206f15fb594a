// Little-endian field access and overflow-checked arithmetic for on-disk structures.
#pragma once

#include <cstddef>
#include <cstdint>
#include <cstring>
#include <span>
#include <string>
#include <vector>

namespace ltb::format {

using ByteSpan = std::span<const std::byte>;
using MutableByteSpan = std::span<std::byte>;

// The bytes of a contiguous array of trivially copyable values.
template <typename T>
ByteSpan BytesOf(std::span<const T> values) {
  return std::as_bytes(values);
}
template <typename T>
ByteSpan BytesOf(const std::vector<T>& values) {
  return std::as_bytes(std::span<const T>(values));
}

inline uint16_t LoadU16(const std::byte* p) {
  uint16_t v;
  std::memcpy(&v, p, sizeof v);
  return v;  // ltbake targets little-endian hosts (checked at configure time)
}
inline uint32_t LoadU32(const std::byte* p) {
  uint32_t v;
  std::memcpy(&v, p, sizeof v);
  return v;
}
inline uint64_t LoadU64(const std::byte* p) {
  uint64_t v;
  std::memcpy(&v, p, sizeof v);
  return v;
}
inline void StoreU16(std::byte* p, uint16_t v) { std::memcpy(p, &v, sizeof v); }
inline void StoreU32(std::byte* p, uint32_t v) { std::memcpy(p, &v, sizeof v); }
inline void StoreU64(std::byte* p, uint64_t v) { std::memcpy(p, &v, sizeof v); }

// a + b and a * b, false on unsigned overflow.
inline bool AddOverflows(uint64_t a, uint64_t b, uint64_t* out) { return __builtin_add_overflow(a, b, out); }
inline bool MulOverflows(uint64_t a, uint64_t b, uint64_t* out) { return __builtin_mul_overflow(a, b, out); }

inline uint64_t AlignUp(uint64_t v, uint64_t alignment) { return (v + alignment - 1) / alignment * alignment; }

inline std::string Hex64(uint64_t v) {
  static const char* digits = "0123456789abcdef";
  std::string s = "0x0000000000000000";
  for (int i = 0; i < 16; ++i) s[17 - i] = digits[(v >> (4 * i)) & 0xF];
  return s;
}

// XXH3-64 of a byte span (the checksum used throughout the container).
uint64_t Checksum(ByteSpan bytes);

}  // namespace ltb::format
