// NumPy .npy header codec (format versions 1.0, 2.0 and 3.0). Byte spans only.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "format/bytes.h"
#include "format/status.h"

namespace ltb::format {

struct NpyHeader {
  std::string descr;  // e.g. "<f4"
  bool fortran_order = false;
  std::vector<uint64_t> shape;
  uint64_t data_offset = 0;  // where the array data starts
  uint64_t itemsize = 0;     // from descr
};

inline constexpr uint64_t kMaxNpyHeaderBytes = 1 << 16;

// Parses the header at the start of `bytes` (pass at least the first 12 bytes; the
// result's data_offset says how many the whole header needs). When bytes is too short
// for the header text, fails with an InvalidArgument naming the needed size.
//
// The header text is read as NumPy reads it (numpy.lib.format: ast.literal_eval of a
// Python dict literal) by a parser of that literal syntax — strings with prefixes, escapes
// and implicit concatenation, integers, True/False/None, tuples, lists, dicts, comments —
// never by searching the text. Everything NumPy refuses is refused: a version other than
// 1.0/2.0/3.0, a NUL byte, invalid UTF-8 in 3.0, anything but a dict with exactly the keys
// 'descr', 'fortran_order' and 'shape', a 'fortran_order' that is not a bool, a 'shape'
// that is not a tuple of integers. Also refused, though NumPy would read them: a key given
// twice (NumPy keeps the last), negative, bool or > 2^64 - 1 dimensions. Python 2 'L'
// suffixes on integers are accepted in 1.0 and 2.0 headers, as NumPy does.
Result<NpyHeader> ParseNpyHeader(ByteSpan bytes);
// Bytes of array data the header declares: the product of the shape and the item size
// (itemsize must be known), refused when it passes 2^64 (the message names the shape).
Result<uint64_t> NpyDataBytes(const NpyHeader& header);
// Bytes needed to parse the header, from its first 10 or 12 bytes.
Result<uint64_t> NpyHeaderLength(ByteSpan first12);
// A version 1.0 (or 2.0 if needed) header for a C-order array of this shape and descr.
std::vector<std::byte> EncodeNpyHeader(const std::string& descr, const std::vector<uint64_t>& shape);

}  // namespace ltb::format
