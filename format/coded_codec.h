// Coded sparse chunks (encoding 5, format 1.2): the nonzero elements of an i32 chunk,
// coded with a binary adaptive range coder and a context model made for quantized wavelet
// coefficients in Mallat layout. Byte layout, coder and contexts: docs/FORMAT.md "Coded
// sparse payloads (encoding 5, format 1.2)".
//
// The chunk is a sequence of lines of L elements (a column of a `cols` chunk, a row of a
// `rows` chunk); each line is read as a W × ceil(L/W) image in row order (W is stored in
// the payload; it only shapes the contexts, so any 1 <= W <= L decodes).
#pragma once

#include <cstdint>
#include <vector>

#include "format/bytes.h"
#include "format/status.h"

namespace ltb::format {

struct SparseChunk;

// The model byte this build writes and reads.
inline constexpr uint8_t kCodedModel = 1;
// Longest line a coded chunk may have (the decoder keeps two lines of state, 1 byte per
// element each, and a line of values for ReadSparse).
inline constexpr uint64_t kMaxCodedLine = uint64_t{1} << 24;

// The encoding-5 payload of a dense i32 chunk (`dense`: its bytes in storage order, a whole
// number of lines of `line_length` elements) read as images `width` wide. Empty (never a
// valid payload) when the shape does not allow it: dense not a whole number of lines,
// line_length 0 or above kMaxCodedLine, more than kMaxSparseElements elements, width 0 or
// above line_length. Deterministic.
std::vector<std::byte> EncodeCodedPayload(ByteSpan dense, uint64_t line_length, uint64_t width);

// Decodes a payload into the dense chunk `dense_out` (its size fixes the element count; on
// failure its content is unspecified). Every malformation — a model byte other than
// kCodedModel, a bad varint, W = 0 or W > L, a coder that does not end exactly at the end
// of the payload, a flag that promises a nonzero element that does not come, a magnitude
// that does not fit i32 — is kDataLoss. The work is bounded by the element count; nothing
// is allocated from the payload's claims.
Status DecodeCodedInto(ByteSpan payload, uint64_t line_length, MutableByteSpan dense_out);
// The same, into the stored elements (out->index, out->values, out->dtype = i32; not
// out->extent).
Status DecodeCodedPayload(ByteSpan payload, uint64_t line_length, uint64_t elements, SparseChunk* out);
// Validates a payload without materializing the chunk (memory: two lines of state).
Status CheckCodedPayload(ByteSpan payload, uint64_t line_length, uint64_t elements);

}  // namespace ltb::format
