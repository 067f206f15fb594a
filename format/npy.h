// NumPy .npy header codec (format versions 1.0, 2.0 and 3.0). Byte spans only.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "format/bytes.h"
#include "format/status.h"

namespace ltb::format {

struct NpyHeader {
  std::string descr;           // e.g. "<f4"
  bool fortran_order = false;
  std::vector<uint64_t> shape;
  uint64_t data_offset = 0;    // where the array data starts
  uint64_t itemsize = 0;       // from descr
};

inline constexpr uint64_t kMaxNpyHeaderBytes = 1 << 16;

// Parses the header at the start of `bytes` (pass at least the first 12 bytes; the
// result's data_offset says how many the whole header needs). When bytes is too short
// for the header text, fails with kOutOfRange-like InvalidArgument naming the needed size.
Result<NpyHeader> ParseNpyHeader(ByteSpan bytes);
// Bytes needed to parse the header, from its first 10 or 12 bytes.
Result<uint64_t> NpyHeaderLength(ByteSpan first12);
// A version 1.0 (or 2.0 if needed) header for a C-order array of this shape and descr.
std::vector<std::byte> EncodeNpyHeader(const std::string& descr, const std::vector<uint64_t>& shape);

}  // namespace ltb::format
