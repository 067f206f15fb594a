// Chunk payload encodings: raw, all-zero (no payload), zstd, sparse, sparse+zstd and coded
// sparse (format/coded_codec.h).
// Pure byte-span codecs. Byte layouts: docs/FORMAT.md "Frames".
#pragma once

#include <cstdint>
#include <span>
#include <vector>

#include "format/array_spec.h"
#include "format/bytes.h"
#include "format/coded_codec.h"
#include "format/layout.h"
#include "format/status.h"

namespace ltb::format {

struct EncodeOptions {
  bool detect_zero = true;  // store an all-zero chunk as kZero (no payload)
  bool zstd = false;        // try zstd; kept only when it saves at least min_saving
  int zstd_level = 1;
  double min_saving = 0.10;
  // Also try kSparse (and kSparseZstd when zstd is set); the smallest candidate that saves
  // at least min_saving over raw is kept. Needs `dtype`, the chunk's element type.
  bool sparse = false;
  DType dtype = DType::kF32;
  // With sparse and dtype i32, also try kCoded (format 1.2) with images `coded_width` wide
  // (0: one image row per line). It needs the chunk's line length: ContainerWriter::Put
  // sets `line_length` from the array (the rows of a `cols` chunk, the columns of a `rows`
  // chunk); EncodeChunk skips kCoded when it is 0, or when coded_width is above it.
  bool coded = false;
  uint64_t coded_width = 0;
  uint64_t line_length = 0;
};

struct EncodedChunk {
  Encoding encoding = Encoding::kRaw;
  uint64_t decoded_length = 0;
  DType dtype = DType::kF32;     // EncodeOptions::dtype; the sparse payloads depend on it
  uint64_t line_length = 0;      // EncodeOptions::line_length; a kCoded payload depends on it
  std::vector<std::byte> owned;  // encoded bytes (kZstd, kSparse, kSparseZstd, kCoded)
  ByteSpan payload;              // what is stored: owned, the caller's data (kRaw), or empty
  uint64_t checksum = 0;         // XXH3-64 of payload
};

// For kRaw the result refers to `data`, which must outlive it. Deterministic: the same
// data and options give the same bytes. With options.sparse, a chunk that is not a whole
// number of options.dtype elements or holds more than kMaxSparseElements is encoded as if
// sparse were off (ContainerWriter::Put refuses the latter with kInvalidArgument).
EncodedChunk EncodeChunk(ByteSpan data, const EncodeOptions& options);

// The decoded size of one zstd frame, streamed through a fixed window (no allocation from
// the payload's claims); more than `cap` bytes, a truncated frame or trailing bytes are
// kDataLoss.
Result<uint64_t> ZstdDecodedSize(ByteSpan payload, uint64_t cap);

// Decodes a kZstd payload into `out`, whose size is the expected decoded length.
Status DecodeZstd(ByteSpan payload, MutableByteSpan out);

// Checks that a frame's encoding and lengths agree with the chunk size the metadata
// expects (before anything is allocated from those lengths).
Status CheckChunkLengths(const FrameHeader& h, uint64_t expected_bytes);

// ---- Sparse chunks (format 1.1) ----
//
// kSparse payload: LEB128 varint n (elements stored), then n varint gaps
// idx[k] - idx[k-1] - 1 (idx[-1] = -1), where idx is the element's position in the chunk's
// storage order, strictly increasing; then the n values: f32/f64 raw little-endian bytes,
// i32 zigzag varints, u8/u32/u64 varints. Exactly the elements whose bit pattern is not
// all zero are stored (so -0.0 is). Varints are canonical (no redundant 0x80 groups).
// kSparseZstd: that payload as one zstd frame.

// Sparse indices are 32-bit: the sparse encodings hold chunks of at most this many elements.
inline constexpr uint64_t kMaxSparseElements = 0xFFFFFFFFull;

// The line length of a kCoded chunk: its rows in a `cols` array (one line per column), its
// columns in a `rows` array (one line per row).
inline uint64_t CodedLineLength(Layout layout, const ChunkExtent& e) {
  return layout == Layout::kCols ? e.rows : e.cols;
}

// Whether a chunk of this dtype and shape may be kCoded: i32, lines of at most
// kMaxCodedLine elements, at most kMaxSparseElements elements. kDataLoss naming what is
// wrong otherwise (readers check it before allocating anything for the chunk).
Status CheckCodedChunkShape(DType dtype, uint64_t line_length, uint64_t elements);

// The stored (nonzero) elements of one chunk.
struct SparseChunk {
  ChunkExtent extent;
  DType dtype = DType::kF32;
  std::vector<uint32_t> index;    // positions in the chunk's storage order, strictly increasing
                                  // (kRows: r * cols + c; kCols: c * rows + r)
  std::vector<std::byte> values;  // index.size() × DTypeSize(dtype) bytes, little-endian

  template <typename T>
  std::span<const T> as() const {
    return {reinterpret_cast<const T*>(values.data()), values.size() / sizeof(T)};
  }
};

// The kSparse payload of a dense chunk (its bytes in storage order). `dense` must be a
// whole number of `dtype` elements, at most kMaxSparseElements of them; otherwise the
// result is empty, which is never a valid payload.
std::vector<std::byte> EncodeSparsePayload(ByteSpan dense, DType dtype);

// Decode a kSparse payload of a chunk of `elements` elements (or, for the Zstd variants, a
// kSparseZstd payload, decompressed through a fixed window). Every malformation — a bad or
// non-canonical varint, n above the element count, an index out of range or not
// increasing, a stored value whose bits are zero, missing or trailing bytes, a zstd error —
// is kDataLoss naming what is wrong; so is a chunk of more than kMaxSparseElements.
// Nothing is allocated from n before it is checked against the element count and the
// payload size. DecodeSparsePayload fills out->index, out->values and out->dtype (not
// out->extent).
Status DecodeSparsePayload(ByteSpan payload, DType dtype, uint64_t elements, SparseChunk* out);
Status DecodeSparseZstdPayload(ByteSpan payload, DType dtype, uint64_t elements, SparseChunk* out);
// Writes the dense chunk into `dense_out` (its size fixes the element count; on failure its
// content is unspecified).
Status DecodeSparseInto(ByteSpan payload, DType dtype, MutableByteSpan dense_out);
Status DecodeSparseZstdInto(ByteSpan payload, DType dtype, MutableByteSpan dense_out);
// Validates a kSparse or kSparseZstd payload without materializing anything (memory: a
// fixed zstd window).
Status CheckSparsePayload(Encoding encoding, ByteSpan payload, DType dtype, uint64_t elements);

// The stored elements of a dense chunk (what decoding its kSparse payload gives).
// kInvalidArgument when it is not a whole number of elements or has more than
// kMaxSparseElements. Fills index, values and dtype.
Status SparseFromDense(ByteSpan dense, DType dtype, SparseChunk* out);

}  // namespace ltb::format
