// Chunk payload encodings: raw, all-zero (no payload) and zstd. Pure byte-span codecs.
#pragma once

#include <cstdint>
#include <vector>

#include "format/bytes.h"
#include "format/layout.h"
#include "format/status.h"

namespace ltb::format {

struct EncodeOptions {
  bool detect_zero = true;  // store an all-zero chunk as kZero (no payload)
  bool zstd = false;        // try zstd; kept only when it saves at least min_saving
  int zstd_level = 1;
  double min_saving = 0.10;
};

struct EncodedChunk {
  Encoding encoding = Encoding::kRaw;
  uint64_t decoded_length = 0;
  std::vector<std::byte> owned;  // compressed bytes (kZstd)
  ByteSpan payload;              // what is stored: owned, the caller's data (kRaw), or empty
  uint64_t checksum = 0;         // XXH3-64 of payload
};

// For kRaw the result refers to `data`, which must outlive it.
EncodedChunk EncodeChunk(ByteSpan data, const EncodeOptions& options);

// Decodes a kZstd payload into `out`, whose size is the expected decoded length.
Status DecodeZstd(ByteSpan payload, MutableByteSpan out);

// Checks that a frame's encoding and lengths agree with the chunk size the metadata
// expects (before anything is allocated from those lengths).
Status CheckChunkLengths(const FrameHeader& h, uint64_t expected_bytes);

}  // namespace ltb::format
