#include "format/chunk_codec.h"

#include <zstd.h>

#include <cstring>

namespace ltb::format {
namespace {

bool IsAllZero(ByteSpan data) {
  const std::byte* p = data.data();
  size_t n = data.size();
  size_t i = 0;
  for (; i + 8 <= n; i += 8) {
    if (LoadU64(p + i) != 0) return false;
  }
  for (; i < n; ++i)
    if (p[i] != std::byte{0}) return false;
  return true;
}

}  // namespace

EncodedChunk EncodeChunk(ByteSpan data, const EncodeOptions& options) {
  EncodedChunk c;
  c.decoded_length = data.size();
  if (options.detect_zero && IsAllZero(data)) {
    c.encoding = Encoding::kZero;
    c.payload = {};
    c.checksum = Checksum(c.payload);
    return c;
  }
  if (options.zstd) {
    size_t bound = ZSTD_compressBound(data.size());
    c.owned.resize(bound);
    size_t n = ZSTD_compress(c.owned.data(), bound, data.data(), data.size(), options.zstd_level);
    if (!ZSTD_isError(n) && static_cast<double>(n) <= (1.0 - options.min_saving) * static_cast<double>(data.size())) {
      c.owned.resize(n);
      c.owned.shrink_to_fit();
      c.encoding = Encoding::kZstd;
      c.payload = c.owned;
      c.checksum = Checksum(c.payload);
      return c;
    }
    c.owned.clear();
    c.owned.shrink_to_fit();
  }
  c.encoding = Encoding::kRaw;
  c.payload = data;
  c.checksum = Checksum(data);
  return c;
}

Status DecodeZstd(ByteSpan payload, MutableByteSpan out) {
  unsigned long long content = ZSTD_getFrameContentSize(payload.data(), payload.size());
  if (content == ZSTD_CONTENTSIZE_ERROR) return DataLoss("zstd payload is not a zstd frame");
  if (content != ZSTD_CONTENTSIZE_UNKNOWN && content != out.size()) {
    return DataLoss("zstd frame holds " + std::to_string(content) + " bytes, the chunk needs " +
                    std::to_string(out.size()));
  }
  size_t n = ZSTD_decompress(out.data(), out.size(), payload.data(), payload.size());
  if (ZSTD_isError(n)) return DataLoss(std::string("zstd decompression failed: ") + ZSTD_getErrorName(n));
  if (n != out.size()) {
    return DataLoss("zstd payload decoded to " + std::to_string(n) + " bytes, the chunk needs " +
                    std::to_string(out.size()));
  }
  return Status::Ok();
}

Status CheckChunkLengths(const FrameHeader& h, uint64_t expected_bytes) {
  if (!IsKnownEncoding(h.encoding)) {
    return Unimplemented("unknown chunk encoding " + std::to_string(h.encoding) + " (written by a newer ltbake?)");
  }
  if (h.decoded_length != expected_bytes) {
    return DataLoss("decoded length " + std::to_string(h.decoded_length) + " differs from the " +
                    std::to_string(expected_bytes) + " bytes the metadata implies");
  }
  switch (static_cast<Encoding>(h.encoding)) {
    case Encoding::kRaw:
      if (h.payload_length != expected_bytes) {
        return DataLoss("raw payload is " + std::to_string(h.payload_length) + " bytes, expected " +
                        std::to_string(expected_bytes));
      }
      break;
    case Encoding::kZero:
      if (h.payload_length != 0) {
        return DataLoss("all-zero chunk carries a " + std::to_string(h.payload_length) + "-byte payload");
      }
      break;
    case Encoding::kZstd:
      if (h.payload_length == 0) return DataLoss("zstd chunk with an empty payload");
      break;
  }
  return Status::Ok();
}

}  // namespace ltb::format
