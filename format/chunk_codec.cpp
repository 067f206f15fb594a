#include "format/chunk_codec.h"

#include <zstd.h>

#include <algorithm>
#include <cstring>
#include <memory>
#include <optional>

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

// Compresses into a buffer each thread keeps (left uninitialised, so only the pages zstd
// writes are touched), then copies the frame out at its size. A zero-filled vector of
// ZSTD_compressBound bytes per call cost a page fault and a clear per 4 KiB of the input
// (32 MiB per chunk in column-transform: a fifth of its time).
std::optional<std::vector<std::byte>> CompressZstd(ByteSpan data, int level) {
  thread_local std::unique_ptr<std::byte[]> buffer;
  thread_local size_t capacity = 0;
  const size_t bound = ZSTD_compressBound(data.size());
  if (capacity < bound) {
    buffer.reset(new std::byte[bound]);
    capacity = bound;
  }
  size_t n = ZSTD_compress(buffer.get(), bound, data.data(), data.size(), level);
  if (ZSTD_isError(n)) return std::nullopt;
  return std::vector<std::byte>(buffer.get(), buffer.get() + n);
}

// ---- Sparse payloads ----

void AppendVarint(std::vector<std::byte>& out, uint64_t v) {
  while (v >= 0x80) {
    out.push_back(static_cast<std::byte>((v & 0x7F) | 0x80));
    v >>= 7;
  }
  out.push_back(static_cast<std::byte>(v));
}

uint64_t ZigZag32(uint64_t bits) {
  uint32_t u = static_cast<uint32_t>(bits);
  return static_cast<uint32_t>((u << 1) ^ (0u - (u >> 31)));
}
uint64_t UnZigZag32(uint64_t z) {
  uint32_t u = static_cast<uint32_t>(z);
  return static_cast<uint32_t>((u >> 1) ^ (0u - (u & 1)));
}

bool ValuesAreVarints(DType t) { return t != DType::kF32 && t != DType::kF64; }

// Largest value a stored varint may carry for this dtype (zigzag-encoded for i32).
uint64_t MaxVarintValue(DType t) {
  switch (t) {
    case DType::kU8:
      return 0xFF;
    case DType::kI32:
    case DType::kU32:
      return 0xFFFFFFFFull;
    default:
      return ~uint64_t{0};
  }
}

// The element's bit pattern, zero-extended (little-endian host).
uint64_t LoadBits(const std::byte* p, uint64_t size) {
  switch (size) {
    case 1:
      return static_cast<uint8_t>(*p);
    case 4:
      return LoadU32(p);
    default:
      return LoadU64(p);
  }
}
void StoreBits(std::byte* p, uint64_t size, uint64_t bits) { std::memcpy(p, &bits, size); }

// Calls f(i, bits) for every element whose bit pattern is not zero, in storage order.
template <typename F>
void ForEachNonzero(ByteSpan dense, uint64_t size, F&& f) {
  const std::byte* p = dense.data();
  const uint64_t elements = dense.size() / size, per_word = 8 / size;
  for (uint64_t i = 0; i < elements;) {
    if ((i + per_word) * size <= dense.size() && LoadU64(p + i * size) == 0) {
      i += per_word;  // a run of zero elements
      continue;
    }
    uint64_t bits = LoadBits(p + i * size, size);
    if (bits != 0) f(i, bits);
    ++i;
  }
}

std::string ElementsTooMany(uint64_t elements) {
  return "a chunk of " + std::to_string(elements) + " elements cannot be sparse (at most " +
         std::to_string(kMaxSparseElements) + ")";
}

// Parses a kSparse payload fed in pieces of any size (so a zstd stream can be parsed through
// a fixed window), with O(1) state. The sink receives, in order, OnCount(n) (n already
// checked against the element count), then OnIndex(k, idx) for k = 0..n-1 (in range,
// strictly increasing), then OnValue(k, bits) (nonzero bit patterns).
template <typename Sink>
class SparseParser {
 public:
  SparseParser(DType dtype, uint64_t elements, Sink* sink)
      : dtype_(dtype),
        size_(DTypeSize(dtype)),
        elements_(elements),
        varint_values_(ValuesAreVarints(dtype)),
        sink_(sink) {}

  Status Feed(ByteSpan bytes) {
    const std::byte* p = bytes.data();
    const std::byte* end = p + bytes.size();
    while (p < end) {
      if (part_ == Part::kEnd) {
        return Error("trailing bytes after the last value, from byte " + std::to_string(offset_));
      }
      if (part_ == Part::kValues && !varint_values_) {
        size_t take = std::min<size_t>(static_cast<size_t>(end - p), size_ - have_);
        std::memcpy(fixed_ + have_, p, take);
        have_ += take;
        p += take;
        offset_ += take;
        if (have_ == size_) {
          have_ = 0;
          LTB_RETURN_IF_ERROR(Value(LoadBits(fixed_, size_)));
        }
        continue;
      }
      if (varint_bytes_ == 0) varint_start_ = offset_;
      uint8_t b = static_cast<uint8_t>(*p++);
      ++offset_;
      if (varint_bytes_ == 9 && b > 1) return Error("varint longer than 64 bits" + Where());
      acc_ |= uint64_t{b & 0x7Fu} << (7 * varint_bytes_);
      ++varint_bytes_;
      if (b & 0x80) continue;
      if (varint_bytes_ > 1 && b == 0) return Error("non-canonical varint (redundant zero group)" + Where());
      uint64_t v = acc_;
      acc_ = 0;
      varint_bytes_ = 0;
      LTB_RETURN_IF_ERROR(Item(v));
    }
    return Status::Ok();
  }

  // The payload has ended: every part must be complete.
  Status Finish() const {
    if (part_ == Part::kEnd) return Status::Ok();
    std::string what = part_ == Part::kCount  ? "the element count"
                       : part_ == Part::kGaps ? "index " + std::to_string(k_) + " of " + std::to_string(n_)
                                              : "value " + std::to_string(k_) + " of " + std::to_string(n_);
    return Error("payload ends inside " + what + " after " + std::to_string(offset_) + " bytes (truncated)");
  }

 private:
  enum class Part { kCount, kGaps, kValues, kEnd };

  Status Error(const std::string& what) const { return DataLoss("sparse payload: " + what); }
  // Where the varint being read started.
  std::string Where() const { return " at byte " + std::to_string(varint_start_); }

  Status Item(uint64_t v) {
    switch (part_) {
      case Part::kCount:
        if (v > elements_) {
          return Error("stores " + std::to_string(v) + " elements, the chunk has " + std::to_string(elements_));
        }
        n_ = v;
        LTB_RETURN_IF_ERROR(sink_->OnCount(n_));
        part_ = n_ == 0 ? Part::kEnd : Part::kGaps;
        return Status::Ok();
      case Part::kGaps: {
        // next_ <= elements_; a gap this large would put the index past the end (or wrap
        // around, making the indices decrease).
        if (v >= elements_ - next_) {
          return Error("index " + std::to_string(k_) + " of " + std::to_string(n_) + " (gap " + std::to_string(v) +
                       " after position " + std::to_string(next_) + ") is past the chunk's " +
                       std::to_string(elements_) + " elements");
        }
        uint64_t idx = next_ + v;
        sink_->OnIndex(k_, idx);
        next_ = idx + 1;
        if (++k_ == n_) {
          k_ = 0;
          part_ = Part::kValues;
        }
        return Status::Ok();
      }
      case Part::kValues:
        if (v > MaxVarintValue(dtype_)) {
          return Error("value " + std::to_string(k_) + " of " + std::to_string(n_) + " is " + std::to_string(v) +
                       ", too large for " + DTypeName(dtype_));
        }
        return Value(dtype_ == DType::kI32 ? UnZigZag32(v) : v);
      case Part::kEnd:
        break;
    }
    return Internal("sparse parser: item after the end");
  }

  Status Value(uint64_t bits) {
    if (bits == 0) {
      return Error("value " + std::to_string(k_) + " of " + std::to_string(n_) +
                   " is zero (zero elements are never stored)");
    }
    sink_->OnValue(k_, bits);
    if (++k_ == n_) part_ = Part::kEnd;
    return Status::Ok();
  }

  const DType dtype_;
  const uint64_t size_;
  const uint64_t elements_;
  const bool varint_values_;
  Sink* sink_;
  Part part_ = Part::kCount;
  uint64_t n_ = 0, k_ = 0;
  uint64_t next_ = 0;    // smallest index the next stored element may have
  uint64_t offset_ = 0;  // payload bytes consumed
  uint64_t acc_ = 0;     // varint being read
  unsigned varint_bytes_ = 0;
  uint64_t varint_start_ = 0;
  std::byte fixed_[8] = {};  // f32/f64 value being read
  size_t have_ = 0;
};

struct NullSink {
  Status OnCount(uint64_t) { return Status::Ok(); }
  void OnIndex(uint64_t, uint64_t) {}
  void OnValue(uint64_t, uint64_t) {}
};

// Writes into a zeroed dense chunk. Each index marks its element (byte 0 set to 1); the
// k-th value goes to the k-th marked element, found by a forward scan: no index list.
struct DenseSink {
  MutableByteSpan dense;
  uint64_t size = 0;
  uint64_t cursor = 0;
  Status OnCount(uint64_t) { return Status::Ok(); }
  void OnIndex(uint64_t, uint64_t idx) { dense[idx * size] = std::byte{1}; }
  void OnValue(uint64_t, uint64_t bits) {
    while (dense[cursor * size] == std::byte{0}) ++cursor;  // the parser guarantees a marked one
    StoreBits(&dense[cursor * size], size, bits);
    ++cursor;
  }
};

struct SparseChunkSink {
  SparseChunk* out = nullptr;
  uint64_t size = 0;
  uint64_t reserve_limit = 0;  // stored elements the payload can hold at most (0: unknown)
  Status OnCount(uint64_t n) {
    uint64_t r = std::min(n, reserve_limit);
    out->index.reserve(r);
    out->values.reserve(r * size);
    return Status::Ok();
  }
  void OnIndex(uint64_t, uint64_t idx) { out->index.push_back(static_cast<uint32_t>(idx)); }
  void OnValue(uint64_t, uint64_t bits) {
    size_t at = out->values.size();
    out->values.resize(at + size);
    StoreBits(out->values.data() + at, size, bits);
  }
};

// Decompresses one zstd frame through a fixed window, handing each decoded piece to
// consume(ByteSpan); trailing bytes after the frame are an error.
template <typename F>
Status StreamZstd(ByteSpan payload, F&& consume) {
  struct Ctx {
    ZSTD_DStream* s = ZSTD_createDStream();
    ~Ctx() { ZSTD_freeDStream(s); }
  } ctx;
  if (ctx.s == nullptr) return Internal("cannot create a zstd stream");
  std::vector<std::byte> window(ZSTD_DStreamOutSize());
  ZSTD_inBuffer in{payload.data(), payload.size(), 0};
  for (;;) {
    ZSTD_outBuffer out{window.data(), window.size(), 0};
    size_t before = in.pos;
    size_t ret = ZSTD_decompressStream(ctx.s, &out, &in);
    if (ZSTD_isError(ret)) return DataLoss(std::string("zstd: ") + ZSTD_getErrorName(ret));
    if (out.pos > 0) LTB_RETURN_IF_ERROR(consume(ByteSpan(window.data(), out.pos)));
    if (ret == 0) break;  // the frame is complete
    if (out.pos == 0 && in.pos == before) return DataLoss("zstd payload is truncated");
  }
  if (in.pos != in.size) {
    return DataLoss("zstd payload has " + std::to_string(in.size - in.pos) + " trailing bytes after its frame");
  }
  return Status::Ok();
}

}  // namespace

Result<uint64_t> ZstdDecodedSize(ByteSpan payload, uint64_t cap) {
  uint64_t total = 0;
  LTB_RETURN_IF_ERROR(StreamZstd(payload, [&](ByteSpan piece) -> Status {
    total += piece.size();
    if (total > cap)
      return DataLoss("zstd payload decodes to more than the " + std::to_string(cap) + " bytes expected");
    return Status::Ok();
  }));
  return total;
}

namespace {

template <typename Sink>
Status ParseSparse(ByteSpan payload, bool zstd, DType dtype, uint64_t elements, Sink* sink) {
  if (elements > kMaxSparseElements) return DataLoss(ElementsTooMany(elements));
  SparseParser<Sink> parser(dtype, elements, sink);
  if (!zstd) {
    LTB_RETURN_IF_ERROR(parser.Feed(payload));
  } else {
    LTB_RETURN_IF_ERROR(StreamZstd(payload, [&](ByteSpan piece) { return parser.Feed(piece); }));
  }
  return parser.Finish();
}

Status DecodeSparseToChunk(ByteSpan payload, bool zstd, DType dtype, uint64_t elements, SparseChunk* out) {
  out->dtype = dtype;
  out->index.clear();
  out->values.clear();
  // Reserve no more than the payload can hold (each stored element takes at least 2 bytes).
  // A zstd frame's declared size is not trusted: its vectors grow with what is decoded.
  SparseChunkSink sink{out, DTypeSize(dtype), zstd ? 0 : payload.size() / 2};
  Status s = ParseSparse(payload, zstd, dtype, elements, &sink);
  if (!s.ok()) {
    out->index.clear();
    out->values.clear();
  }
  return s;
}

Status DecodeSparseToDense(ByteSpan payload, bool zstd, DType dtype, MutableByteSpan dense_out) {
  const uint64_t size = DTypeSize(dtype);
  if (dense_out.size() % size != 0) {
    return InvalidArgument("a dense " + std::string(DTypeName(dtype)) + " chunk cannot be " +
                           std::to_string(dense_out.size()) + " bytes");
  }
  std::fill(dense_out.begin(), dense_out.end(), std::byte{0});
  DenseSink sink{dense_out, size, 0};
  return ParseSparse(payload, zstd, dtype, dense_out.size() / size, &sink);
}

// With options.sparse: the smallest of raw, zstd, sparse, sparse+zstd and coded (those
// enabled) that saves min_saving over raw; on equal sizes the earlier in that order.
// (All-zero chunks are handled by EncodeChunk before it calls this.)
EncodedChunk EncodeWithSparse(ByteSpan data, const EncodeOptions& options) {
  EncodedChunk c;
  c.decoded_length = data.size();
  c.dtype = options.dtype;
  c.line_length = options.line_length;
  const double limit = (1.0 - options.min_saving) * static_cast<double>(data.size());
  Encoding best = Encoding::kRaw;
  size_t best_size = data.size();
  auto consider = [&](Encoding e, std::vector<std::byte>&& bytes) {
    if (static_cast<double>(bytes.size()) <= limit && bytes.size() < best_size) {
      best = e;
      best_size = bytes.size();
      c.owned = std::move(bytes);
    }
  };
  if (options.zstd) {
    if (auto z = CompressZstd(data, options.zstd_level)) consider(Encoding::kZstd, std::move(*z));
  }
  std::vector<std::byte> sparse = EncodeSparsePayload(data, options.dtype);
  std::optional<std::vector<std::byte>> sparse_zstd;
  if (options.zstd) sparse_zstd = CompressZstd(sparse, options.zstd_level);
  consider(Encoding::kSparse, std::move(sparse));
  if (sparse_zstd) consider(Encoding::kSparseZstd, std::move(*sparse_zstd));
  if (options.coded && options.dtype == DType::kI32 && options.line_length > 0 &&
      options.coded_width <= options.line_length) {
    std::vector<std::byte> coded = EncodeCodedPayload(
        data, options.line_length, options.coded_width == 0 ? options.line_length : options.coded_width);
    if (!coded.empty()) consider(Encoding::kCoded, std::move(coded));
  }
  c.encoding = best;
  if (best == Encoding::kRaw) {
    c.owned.clear();
    c.owned.shrink_to_fit();
    c.payload = data;
  } else {
    c.payload = c.owned;
  }
  c.checksum = Checksum(c.payload);
  return c;
}

}  // namespace

EncodedChunk EncodeChunk(ByteSpan data, const EncodeOptions& options) {
  EncodedChunk c;
  c.decoded_length = data.size();
  c.dtype = options.dtype;
  if (options.detect_zero && IsAllZero(data)) {
    c.encoding = Encoding::kZero;
    c.payload = {};
    c.checksum = Checksum(c.payload);
    return c;
  }
  const uint64_t element = DTypeSize(options.dtype);
  if (options.sparse && data.size() % element == 0 && data.size() / element <= kMaxSparseElements) {
    return EncodeWithSparse(data, options);
  }
  if (options.zstd) {
    std::optional<std::vector<std::byte>> z = CompressZstd(data, options.zstd_level);
    if (z && static_cast<double>(z->size()) <= (1.0 - options.min_saving) * static_cast<double>(data.size())) {
      c.owned = std::move(*z);
      c.encoding = Encoding::kZstd;
      c.payload = c.owned;
      c.checksum = Checksum(c.payload);
      return c;
    }
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
    case Encoding::kSparse:
      // At least the element count; the payload itself is checked when it is decoded.
      if (h.payload_length == 0) return DataLoss("sparse chunk with an empty payload");
      break;
    case Encoding::kSparseZstd:
      if (h.payload_length == 0) return DataLoss("sparse-zstd chunk with an empty payload");
      break;
    case Encoding::kCoded:
      if (h.payload_length == 0) return DataLoss("sparse-coded chunk with an empty payload");
      break;
  }
  return Status::Ok();
}

std::vector<std::byte> EncodeSparsePayload(ByteSpan dense, DType dtype) {
  const uint64_t size = DTypeSize(dtype);
  if (dense.size() % size != 0 || dense.size() / size > kMaxSparseElements) return {};
  std::vector<std::byte> gaps, values;
  uint64_t n = 0, next = 0;  // next: the position after the last stored element
  const bool varints = ValuesAreVarints(dtype);
  ForEachNonzero(dense, size, [&](uint64_t i, uint64_t bits) {
    AppendVarint(gaps, i - next);
    next = i + 1;
    ++n;
    if (!varints) {
      const std::byte* p = reinterpret_cast<const std::byte*>(&bits);
      values.insert(values.end(), p, p + size);
    } else {
      AppendVarint(values, dtype == DType::kI32 ? ZigZag32(bits) : bits);
    }
  });
  std::vector<std::byte> out;
  out.reserve(10 + gaps.size() + values.size());
  AppendVarint(out, n);
  out.insert(out.end(), gaps.begin(), gaps.end());
  out.insert(out.end(), values.begin(), values.end());
  return out;
}

Status DecodeSparsePayload(ByteSpan payload, DType dtype, uint64_t elements, SparseChunk* out) {
  return DecodeSparseToChunk(payload, false, dtype, elements, out);
}

Status DecodeSparseZstdPayload(ByteSpan payload, DType dtype, uint64_t elements, SparseChunk* out) {
  return DecodeSparseToChunk(payload, true, dtype, elements, out);
}

Status DecodeSparseInto(ByteSpan payload, DType dtype, MutableByteSpan dense_out) {
  return DecodeSparseToDense(payload, false, dtype, dense_out);
}

Status DecodeSparseZstdInto(ByteSpan payload, DType dtype, MutableByteSpan dense_out) {
  return DecodeSparseToDense(payload, true, dtype, dense_out);
}

Status CheckSparsePayload(Encoding encoding, ByteSpan payload, DType dtype, uint64_t elements) {
  if (encoding != Encoding::kSparse && encoding != Encoding::kSparseZstd) {
    return InvalidArgument(std::string("CheckSparsePayload on a ") + EncodingName(encoding) + " payload");
  }
  NullSink sink;
  return ParseSparse(payload, encoding == Encoding::kSparseZstd, dtype, elements, &sink);
}

Status CheckCodedChunkShape(DType dtype, uint64_t line_length, uint64_t elements) {
  if (dtype != DType::kI32) {
    return DataLoss(std::string("a sparse-coded chunk in a ") + DTypeName(dtype) + " array (coded chunks are i32)");
  }
  if (line_length == 0 || line_length > kMaxCodedLine) {
    return DataLoss("a sparse-coded chunk with lines of " + std::to_string(line_length) + " elements (at most " +
                    std::to_string(kMaxCodedLine) + ")");
  }
  if (elements > kMaxSparseElements) return DataLoss(ElementsTooMany(elements));
  return Status::Ok();
}

Status SparseFromDense(ByteSpan dense, DType dtype, SparseChunk* out) {
  const uint64_t size = DTypeSize(dtype);
  if (dense.size() % size != 0) {
    return InvalidArgument(std::to_string(dense.size()) + " bytes are not a whole number of " + DTypeName(dtype) +
                           " elements");
  }
  if (dense.size() / size > kMaxSparseElements) return InvalidArgument(ElementsTooMany(dense.size() / size));
  out->dtype = dtype;
  out->index.clear();
  out->values.clear();
  uint64_t n = 0;
  ForEachNonzero(dense, size, [&](uint64_t, uint64_t) { ++n; });
  out->index.reserve(n);
  out->values.resize(n * size);
  std::byte* v = out->values.data();
  ForEachNonzero(dense, size, [&](uint64_t i, uint64_t bits) {
    out->index.push_back(static_cast<uint32_t>(i));
    StoreBits(v, size, bits);
    v += size;
  });
  return Status::Ok();
}

}  // namespace ltb::format
