#include "format/coded_codec.h"

#include <algorithm>
#include <bit>
#include <cstring>
#include <memory>
#include <string>

#include "format/chunk_codec.h"

namespace ltb::format {
namespace {

// ---- The binary adaptive range coder (docs/FORMAT.md "The coder") ----

constexpr unsigned kCoderProbBits = 15;  // the coder's probability scale: P0 / 2^15
constexpr uint32_t kCoderTop = uint32_t{1} << 24;
constexpr unsigned kFastRate = 4;  // adaptation shifts of the two estimates of a bit model
constexpr unsigned kSlowRate = 7;

// One adaptive binary context: two estimates of P(bit = 0) in 1/65536 units, adapting at
// two speeds; the coder uses their mean.
struct BitModel {
  uint16_t fast = 0x8000;
  uint16_t slow = 0x8000;
};

inline uint32_t ZeroProbability(const BitModel& m) {
  return (uint32_t{m.fast} + uint32_t{m.slow}) >> (17 - kCoderProbBits);  // 35..32732
}

inline void Adapt(BitModel& m, unsigned bit) {
  if (bit != 0) {
    m.fast = static_cast<uint16_t>(m.fast - (m.fast >> kFastRate));
    m.slow = static_cast<uint16_t>(m.slow - (m.slow >> kSlowRate));
  } else {
    m.fast = static_cast<uint16_t>(m.fast + ((0x10000u - m.fast) >> kFastRate));
    m.slow = static_cast<uint16_t>(m.slow + ((0x10000u - m.slow) >> kSlowRate));
  }
}

class CodedBitWriter {
 public:
  static constexpr bool kEncode = true;
  explicit CodedBitWriter(std::vector<std::byte>* out) : out_(out) {}

  unsigned Bit(BitModel& m, unsigned bit) {
    const uint32_t bound = (range_ >> kCoderProbBits) * ZeroProbability(m);
    if (bit == 0) {
      range_ = bound;
    } else {
      low_ += bound;
      range_ -= bound;
    }
    Adapt(m, bit);
    while (range_ < kCoderTop) {
      range_ <<= 8;
      ShiftLow();
    }
    return bit;
  }

  // Writes out the rest of `low` (five shifts: the pending byte and low's four bytes).
  void Flush() {
    for (int i = 0; i < 5; ++i) ShiftLow();
  }

 private:
  void ShiftLow() {
    if (static_cast<uint32_t>(low_) < 0xFF000000u || (low_ >> 32) != 0) {
      const uint8_t carry = static_cast<uint8_t>(low_ >> 32);
      uint8_t pending = cache_;
      do {
        out_->push_back(static_cast<std::byte>(static_cast<uint8_t>(pending + carry)));
        pending = 0xFF;
      } while (--cache_size_ != 0);
      cache_ = static_cast<uint8_t>(low_ >> 24);
    }
    ++cache_size_;
    low_ = (low_ & 0x00FFFFFFu) << 8;
  }

  std::vector<std::byte>* out_;
  uint64_t low_ = 0;  // 33 bits: bit 32 is a carry into the bytes not yet written
  uint32_t range_ = 0xFFFFFFFFu;
  uint8_t cache_ = 0;        // the last byte not yet written (a carry may still change it)
  uint64_t cache_size_ = 1;  // the cache byte plus the 0xFF bytes queued behind it
};

class CodedBitReader {
 public:
  static constexpr bool kEncode = false;

  // `bytes`: the coder's part of the payload (after the model byte and W).
  Status Start(ByteSpan bytes) {
    if (bytes.size() < 5) {
      return DataLoss("coded payload: the coder's bytes end after " + std::to_string(bytes.size()) +
                      " bytes (at least 5; truncated)");
    }
    if (bytes[0] != std::byte{0}) return DataLoss("coded payload: the coder's first byte is not 0");
    data_ = reinterpret_cast<const uint8_t*>(bytes.data());
    size_ = bytes.size();
    code_ = (uint32_t{data_[1]} << 24) | (uint32_t{data_[2]} << 16) | (uint32_t{data_[3]} << 8) | data_[4];
    pos_ = 5;
    if (code_ == 0xFFFFFFFFu) return DataLoss("coded payload: the coder's start value is out of range");
    return Status::Ok();
  }

  unsigned Bit(BitModel& m, unsigned /*unused*/) {
    const uint32_t bound = (range_ >> kCoderProbBits) * ZeroProbability(m);
    unsigned bit;
    if (code_ < bound) {
      range_ = bound;
      bit = 0;
    } else {
      code_ -= bound;
      range_ -= bound;
      bit = 1;
    }
    Adapt(m, bit);
    while (range_ < kCoderTop) {
      range_ <<= 8;
      code_ = (code_ << 8) | NextByte();
    }
    return bit;
  }

  // Whether the coder needed bytes past the end of the payload.
  bool overrun() const { return overrun_; }

  // After the last symbol: every byte consumed, none missing, and the code value 0 (the
  // encoder's flush writes out `low` exactly).
  Status Finish() const {
    if (overrun_) return DataLoss("coded payload is truncated (the coder ran past its end)");
    if (pos_ != size_) {
      return DataLoss("coded payload has " + std::to_string(size_ - pos_) + " trailing bytes after the coder's end");
    }
    if (code_ != 0) return DataLoss("coded payload: the coder does not end on its flush (damaged)");
    return Status::Ok();
  }

 private:
  uint32_t NextByte() {
    if (pos_ < size_) return data_[pos_++];
    overrun_ = true;
    return 0;
  }

  const uint8_t* data_ = nullptr;
  uint64_t size_ = 0, pos_ = 0;
  uint32_t range_ = 0xFFFFFFFFu;
  uint32_t code_ = 0;
  bool overrun_ = false;
};

// ---- The context model (docs/FORMAT.md "Contexts") ----

constexpr unsigned kBlockShift = 3;  // blocks of 8 × 8 positions
constexpr uint64_t kBlockSide = uint64_t{1} << kBlockShift;
constexpr unsigned kQuadShift = 2;  // each made of 2 × 2 quads of 4 × 4 positions
constexpr uint64_t kQuadSide = uint64_t{1} << kQuadShift;
constexpr unsigned kBlockLevels = 8;
constexpr unsigned kSigLevels = 10;
constexpr unsigned kMagLevels = 7;
constexpr unsigned kMagBuckets = 9;
constexpr unsigned kPrefixContexts = 16;
constexpr unsigned kMaxExponent = 31;                               // |v| <= 2^31
constexpr uint64_t kSigLevelEnd = uint64_t{1} << (kSigLevels - 1);  // bw of this and above: kSigLevels − 1

struct CodedContexts {
  BitModel line[2];
  BitModel block[kBlockLevels][2][3];
  BitModel quad[kBlockLevels][2][3];
  BitModel sig[kSigLevels][3][2][3];
  BitModel prefix[kMagLevels][kMagBuckets][kPrefixContexts];
  BitModel suffix[kMaxExponent + 1][kMaxExponent];
  BitModel sign[3][3];
};

// A position's state byte: 0 when zero, else min(|v|, 127) | (v < 0) << 7.
constexpr uint8_t kNegativeBit = 0x80;
inline unsigned StateMagnitude(uint8_t s) { return s & 0x7Fu; }
inline unsigned StateSign(uint8_t s) { return s == 0 ? 0u : (s & kNegativeBit) ? 2u : 1u; }

// Bucket of the neighbourhood magnitude sum (0..508).
inline unsigned MagnitudeBucket(unsigned s) {
  if (s <= 2) return s;
  if (s <= 4) return 3;
  if (s <= 7) return 4;
  if (s <= 12) return 5;
  if (s <= 20) return 6;
  if (s <= 40) return 7;
  return 8;
}

inline uint32_t AbsoluteValue(int32_t v) { return v < 0 ? 0u - static_cast<uint32_t>(v) : static_cast<uint32_t>(v); }

inline int32_t LoadI32(const std::byte* p) {
  int32_t v;
  std::memcpy(&v, p, sizeof v);
  return v;
}

// Codes the lines of one chunk in order, with the line state of the previous line. The
// same code encodes (Coder = CodedBitWriter: the bits come from the input values) and
// decodes (CodedBitReader: the bits come from the payload), so both sides see the same
// contexts by construction.
template <typename Coder>
class CodedLines {
 public:
  CodedLines(Coder* coder, uint64_t line_length, uint64_t width)
      : coder_(coder),
        length_(line_length),
        width_(width),
        height_((line_length + width - 1) / width),
        blocks_x_((width + kBlockSide - 1) >> kBlockShift),
        blocks_y_((height_ + kBlockSide - 1) >> kBlockShift),
        quads_x_((width + kQuadSide - 1) >> kQuadShift),
        quads_y_((height_ + kQuadSide - 1) >> kQuadShift),
        contexts_(std::make_unique<CodedContexts>()) {
    for (uint64_t v = 0; v <= kSigLevelEnd; ++v) {
      sig_level_[v] = static_cast<uint8_t>(std::min<unsigned>(std::bit_width(v), kSigLevels - 1));
    }
    for (int i = 0; i < 2; ++i) {
      state_[i].assign(length_, 0);
      block_[i].assign(blocks_x_ * blocks_y_, 0);
      quad_[i].assign(quads_x_ * quads_y_, 0);
    }
  }

  // Codes one line. Encoding: `in` holds its L values (little-endian i32). Decoding: `in`
  // is null, and each decoded nonzero value v at position p is stored at out[p] (when out
  // is not null; the other positions of out are not written).
  Status Line(const std::byte* in, std::byte* out) {
    Coder coder = *coder_;  // a local copy, which the stores to the line buffers cannot alias
    Status s = CodeLine(coder, in, out);
    *coder_ = coder;
    return s;
  }

  // Calls f(p) for the nonzero positions of the line just coded, in increasing order: row
  // by row through the nonzero blocks of each block row, and their nonzero quads.
  template <typename F>
  void ForEachNonzero(F&& f) const {
    if (flag_[cur_] == 0) return;
    const uint8_t* const cur = state_[cur_].data();
    const uint8_t* const qcur = quad_[cur_].data();
    const std::vector<uint64_t>& blocks = nonzero_blocks_;
    for (size_t first = 0; first < blocks.size();) {
      const uint64_t by = blocks[first] / blocks_x_;
      size_t end = first;
      while (end < blocks.size() && blocks[end] / blocks_x_ == by) ++end;
      const uint64_t y1 = std::min((by + 1) << kBlockShift, height_);
      for (uint64_t y = by << kBlockShift; y < y1; ++y) {
        const uint64_t row = y * width_, qrow = (y >> kQuadShift) * quads_x_;
        if (row >= length_) return;
        for (size_t i = first; i < end; ++i) {
          const uint64_t qx0 = (blocks[i] % blocks_x_) << (kBlockShift - kQuadShift);
          for (uint64_t qx = qx0; qx < std::min(qx0 + 2, quads_x_); ++qx) {
            if (qcur[qrow + qx] == 0) continue;
            const uint64_t x0 = qx << kQuadShift;
            if (row + x0 >= length_) break;
            const uint64_t xe = std::min({x0 + kQuadSide, width_, length_ - row});
            for (uint64_t x = x0; x < xe; ++x)
              if (cur[row + x] != 0) f(row + x);
          }
        }
      }
      first = end;
    }
  }

 private:
  Status CodeLine(Coder& coder, const std::byte* in, std::byte* out) {
    // The buffers of line t−2 become line t's; clear what that line set.
    std::swap(cur_, prev_);
    Clear(cur_);
    nonzero_blocks_.clear();
    uint8_t* const bcur = block_[cur_].data();
    const uint8_t* const bprev = block_[prev_].data();
    uint8_t* const qcur = quad_[cur_].data();
    const uint8_t* const qprev = quad_[prev_].data();
    CodedContexts& m = *contexts_;

    unsigned want = 0;
    if constexpr (Coder::kEncode) want = AnyNonzero(in, 0, length_);
    if (coder.Bit(m.line[flag_[prev_]], want) == 0) return Status::Ok();
    flag_[cur_] = 1;
    bool any_block = false;
    for (uint64_t by = 0; by < blocks_y_; ++by) {
      const uint64_t y0 = by << kBlockShift, y1 = std::min(y0 + kBlockSide, height_);
      for (uint64_t bx = 0; bx < blocks_x_; ++bx) {
        const uint64_t x0 = bx << kBlockShift, x1 = std::min(x0 + kBlockSide, width_);
        if (y0 * width_ + x0 >= length_) break;  // this block and the rest of the row are past the line's end
        const uint64_t b = by * blocks_x_ + bx;
        const unsigned left = bx > 0 ? bcur[b - 1] : 0, up = by > 0 ? bcur[b - blocks_x_] : 0;
        const unsigned level = std::min<unsigned>(std::bit_width(std::max(bx, by)), kBlockLevels - 1);
        if constexpr (Coder::kEncode) want = BlockNonzero(in, x0, x1, y0, y1);
        if (coder.Bit(m.block[level][bprev[b]][left + up], want) == 0) continue;
        bcur[b] = 1;
        nonzero_blocks_.push_back(b);
        any_block = true;
        bool any_quad = false;
        for (uint64_t qy = y0 >> kQuadShift; qy < (y1 + kQuadSide - 1) >> kQuadShift; ++qy) {
          const uint64_t qy0 = qy << kQuadShift, qy1 = std::min(qy0 + kQuadSide, y1);
          for (uint64_t qx = x0 >> kQuadShift; qx < (x1 + kQuadSide - 1) >> kQuadShift; ++qx) {
            const uint64_t qx0 = qx << kQuadShift, qx1 = std::min(qx0 + kQuadSide, x1);
            if (qy0 * width_ + qx0 >= length_) break;  // past the line's end
            const uint64_t q = qy * quads_x_ + qx;
            const unsigned qleft = qx > 0 ? qcur[q - 1] : 0, qup = qy > 0 ? qcur[q - quads_x_] : 0;
            const unsigned qlevel = std::min<unsigned>(std::bit_width(std::max(qx, qy)), kBlockLevels - 1);
            if constexpr (Coder::kEncode) want = BlockNonzero(in, qx0, qx1, qy0, qy1);
            if (coder.Bit(m.quad[qlevel][qprev[q]][qleft + qup], want) == 0) continue;
            qcur[q] = 1;
            any_quad = true;
            LTB_RETURN_IF_ERROR(CodeQuad(coder, in, out, qx0, qx1, qy0, qy1));
          }
        }
        if (!any_quad) {
          return DataLoss("coded payload: a block flagged nonzero holds no nonzero quad (damaged)");
        }
      }
    }
    if (!any_block) return DataLoss("coded payload: a line flagged nonzero holds no nonzero block (damaged)");
    return Status::Ok();
  }

  // The positions of one quad flagged nonzero, row by row.
  Status CodeQuad(Coder& coder, const std::byte* in, std::byte* out, uint64_t x0, uint64_t x1, uint64_t y0,
                  uint64_t y1) {
    uint8_t* const cur = state_[cur_].data();
    const uint8_t* const prev = state_[prev_].data();
    CodedContexts& m = *contexts_;
    unsigned want = 0;
    bool any_position = false;
    for (uint64_t y = y0; y < y1; ++y) {
      const uint64_t row = y * width_;
      if (row + x0 >= length_) break;
      const uint64_t xe = std::min(x1, length_ - row);
      const uint8_t* const parents = cur + (y >> 1) * width_;
      const unsigned level_y = sig_level_[std::min<uint64_t>(y, kSigLevelEnd)];
      for (uint64_t x = x0; x < xe; ++x) {
        const uint64_t p = row + x;
        const uint8_t sl = x > 0 ? cur[p - 1] : 0;
        const uint8_t su = y > 0 ? cur[p - width_] : 0;
        const uint8_t sul = x > 0 && y > 0 ? cur[p - width_ - 1] : 0;
        const unsigned near = std::min<unsigned>((sl != 0) + (su != 0) + (sul != 0), 2);
        const unsigned parent = parents[x >> 1] != 0;
        const unsigned pm = StateMagnitude(prev[p]);
        // min(bw(max(x, y)), 9) = max of the two clipped bit widths
        const unsigned level = std::max<unsigned>(sig_level_[std::min<uint64_t>(x, kSigLevelEnd)], level_y);
        int32_t v = 0;
        if constexpr (Coder::kEncode) {
          v = LoadI32(in + 4 * p);
          want = v != 0;
        }
        if (coder.Bit(m.sig[level][near][parent][std::min(pm, 2u)], want) == 0) continue;
        any_position = true;
        // Magnitude: |v| = 2^k + suffix, k in unary (contexts by level and the
        // neighbourhood), then the k suffix bits from the top (contexts by k and bit).
        const unsigned bucket = MagnitudeBucket(StateMagnitude(sl) + StateMagnitude(su) + 2 * pm);
        BitModel* prefix = m.prefix[std::min(level, kMagLevels - 1)][bucket];
        const uint32_t a = AbsoluteValue(v);
        const unsigned k_want = Coder::kEncode ? static_cast<unsigned>(std::bit_width(a)) - 1 : 0;
        unsigned k = 0;
        while (k < kMaxExponent && coder.Bit(prefix[std::min(k, kPrefixContexts - 1)], k_want > k ? 1u : 0u) != 0) {
          ++k;
        }
        uint64_t mag = 1;
        for (unsigned i = 0; i < k; ++i) {
          mag = (mag << 1) | coder.Bit(m.suffix[k][i], (a >> (k - 1 - i)) & 1u);
        }
        const unsigned negative = coder.Bit(m.sign[StateSign(prev[p])][StateSign(sl)], v < 0 ? 1u : 0u);
        if (mag > (uint64_t{1} << 31) || (mag == (uint64_t{1} << 31) && negative == 0)) {
          return DataLoss("coded payload: a value at position " + std::to_string(p) + " does not fit i32");
        }
        cur[p] = static_cast<uint8_t>(std::min<uint64_t>(mag, 127) | (negative ? kNegativeBit : 0));
        if (out != nullptr) {
          const int32_t value =
              negative ? static_cast<int32_t>(0u - static_cast<uint32_t>(mag)) : static_cast<int32_t>(mag);
          std::memcpy(out + 4 * p, &value, sizeof value);
        }
      }
    }
    if (!any_position) return DataLoss("coded payload: a quad flagged nonzero holds no nonzero value (damaged)");
    return Status::Ok();
  }

  static unsigned AnyNonzero(const std::byte* in, uint64_t begin, uint64_t end) {
    for (uint64_t p = begin; p < end; ++p)
      if (LoadI32(in + 4 * p) != 0) return 1;
    return 0;
  }
  unsigned BlockNonzero(const std::byte* in, uint64_t x0, uint64_t x1, uint64_t y0, uint64_t y1) const {
    for (uint64_t y = y0; y < y1; ++y) {
      const uint64_t row = y * width_;
      if (row + x0 >= length_) break;
      if (AnyNonzero(in, row + x0, std::min(row + x1, length_))) return 1;
    }
    return 0;
  }

  // Zeroes the state a line left in buffer i (only its nonzero blocks hold anything).
  void Clear(int i) {
    if (flag_[i] == 0) return;
    uint8_t* const s = state_[i].data();
    uint8_t* const blocks = block_[i].data();
    for (uint64_t by = 0; by < blocks_y_; ++by) {
      for (uint64_t bx = 0; bx < blocks_x_; ++bx) {
        if (blocks[by * blocks_x_ + bx] == 0) continue;
        const uint64_t x0 = bx << kBlockShift, x1 = std::min(x0 + kBlockSide, width_);
        for (uint64_t y = by << kBlockShift; y < std::min((by + 1) << kBlockShift, height_); ++y) {
          const uint64_t row = y * width_;
          if (row + x0 >= length_) break;
          std::memset(s + row + x0, 0, std::min(row + x1, length_) - (row + x0));
        }
      }
    }
    std::memset(blocks, 0, block_[i].size());
    std::memset(quad_[i].data(), 0, quad_[i].size());
    flag_[i] = 0;
  }

  Coder* coder_;
  const uint64_t length_, width_, height_, blocks_x_, blocks_y_, quads_x_, quads_y_;
  std::unique_ptr<CodedContexts> contexts_;
  std::vector<uint8_t> state_[2];         // per position of a line: see StateMagnitude
  std::vector<uint8_t> block_[2];         // per block: 1 when it holds a nonzero
  std::vector<uint8_t> quad_[2];          // per quad: 1 when it holds a nonzero
  std::vector<uint64_t> nonzero_blocks_;  // of the current line, in coding order
  uint8_t sig_level_[kSigLevelEnd + 1];   // min(bw(v), kSigLevels − 1)
  uint8_t flag_[2] = {0, 0};              // per buffer: its line holds a nonzero
  int cur_ = 1, prev_ = 0;                // swapped at the start of every line
};

void PutCodedVarint(std::vector<std::byte>& out, uint64_t v) {
  while (v >= 0x80) {
    out.push_back(static_cast<std::byte>((v & 0x7F) | 0x80));
    v >>= 7;
  }
  out.push_back(static_cast<std::byte>(v));
}

// The model byte and W; the coder's bytes follow at *offset.
Status ParseCodedHeader(ByteSpan payload, uint64_t line_length, uint64_t* width, size_t* offset) {
  if (payload.empty()) return DataLoss("coded payload is empty");
  const uint8_t model = static_cast<uint8_t>(payload[0]);
  if (model != kCodedModel) {
    return DataLoss("coded payload: unknown model " + std::to_string(model) + " (this build knows model " +
                    std::to_string(kCodedModel) + ")");
  }
  uint64_t w = 0;
  size_t i = 1;
  for (unsigned shift = 0;; shift += 7) {
    if (i >= payload.size()) return DataLoss("coded payload: ends inside the image width (truncated)");
    const uint8_t b = static_cast<uint8_t>(payload[i++]);
    if (shift == 63 && b > 1) return DataLoss("coded payload: image width varint longer than 64 bits");
    w |= uint64_t{b & 0x7Fu} << shift;
    if ((b & 0x80) == 0) {
      if (i > 2 && b == 0) return DataLoss("coded payload: non-canonical image width varint");
      break;
    }
  }
  if (w == 0 || w > line_length) {
    return DataLoss("coded payload: image width " + std::to_string(w) + " is not in 1.." + std::to_string(line_length) +
                    " (the line length)");
  }
  *width = w;
  *offset = i;
  return Status::Ok();
}

Status CheckCodedShape(uint64_t line_length, uint64_t elements) {
  if (line_length == 0 || elements % line_length != 0) {
    return InvalidArgument("a coded chunk of " + std::to_string(elements) + " elements cannot have lines of " +
                           std::to_string(line_length));
  }
  if (line_length > kMaxCodedLine) {
    return DataLoss("a coded chunk's lines hold at most " + std::to_string(kMaxCodedLine) + " elements, not " +
                    std::to_string(line_length));
  }
  if (elements > kMaxSparseElements) {
    return DataLoss("a chunk of " + std::to_string(elements) + " elements cannot be coded (at most " +
                    std::to_string(kMaxSparseElements) + ")");
  }
  return Status::Ok();
}

// Decodes every line; after line t, done(t, lines) is called (lines: the CodedLines, whose
// ForEachNonzero lists line t). `out_line(t)` gives where line t's values go (or null).
template <typename OutLine, typename Done>
Status DecodeCodedLines(ByteSpan payload, uint64_t line_length, uint64_t elements, OutLine&& out_line, Done&& done) {
  LTB_RETURN_IF_ERROR(CheckCodedShape(line_length, elements));
  uint64_t width = 0;
  size_t offset = 0;
  LTB_RETURN_IF_ERROR(ParseCodedHeader(payload, line_length, &width, &offset));
  CodedBitReader reader;
  LTB_RETURN_IF_ERROR(reader.Start(payload.subspan(offset)));
  CodedLines<CodedBitReader> lines(&reader, line_length, width);
  const uint64_t count = elements / line_length;
  for (uint64_t t = 0; t < count; ++t) {
    Status s = lines.Line(nullptr, out_line(t));
    if (!s.ok()) return s.WithContext("line " + std::to_string(t));
    if (reader.overrun()) return reader.Finish().WithContext("line " + std::to_string(t));
    done(t, lines);
  }
  return reader.Finish();
}

}  // namespace

std::vector<std::byte> EncodeCodedPayload(ByteSpan dense, uint64_t line_length, uint64_t width) {
  if (dense.size() % 4 != 0 || !CheckCodedShape(line_length, dense.size() / 4).ok() || width == 0 ||
      width > line_length) {
    return {};
  }
  std::vector<std::byte> out;
  out.push_back(static_cast<std::byte>(kCodedModel));
  PutCodedVarint(out, width);
  CodedBitWriter writer(&out);
  CodedLines<CodedBitWriter> lines(&writer, line_length, width);
  const uint64_t count = dense.size() / 4 / line_length;
  for (uint64_t t = 0; t < count; ++t) {
    Status s = lines.Line(dense.data() + 4 * t * line_length, nullptr);
    if (!s.ok()) return {};  // the encoder never produces an inconsistency
  }
  writer.Flush();
  return out;
}

Status DecodeCodedInto(ByteSpan payload, uint64_t line_length, MutableByteSpan dense_out) {
  if (dense_out.size() % 4 != 0) {
    return InvalidArgument("a dense i32 chunk cannot be " + std::to_string(dense_out.size()) + " bytes");
  }
  std::fill(dense_out.begin(), dense_out.end(), std::byte{0});
  return DecodeCodedLines(
      payload, line_length, dense_out.size() / 4, [&](uint64_t t) { return dense_out.data() + 4 * t * line_length; },
      [](uint64_t, const auto&) {});
}

Status DecodeCodedPayload(ByteSpan payload, uint64_t line_length, uint64_t elements, SparseChunk* out) {
  out->dtype = DType::kI32;
  out->index.clear();
  out->values.clear();
  Status s = CheckCodedShape(line_length, elements);
  if (s.ok()) {
    std::vector<int32_t> line(line_length);  // one line of values, written where nonzero
    std::vector<int32_t> values;             // grows with what is decoded, never from a claim
    s = DecodeCodedLines(
        payload, line_length, elements, [&](uint64_t) { return reinterpret_cast<std::byte*>(line.data()); },
        [&](uint64_t t, const auto& lines) {
          lines.ForEachNonzero([&](uint64_t p) {
            out->index.push_back(static_cast<uint32_t>(t * line_length + p));
            values.push_back(line[p]);
          });
        });
    if (s.ok()) {
      out->values.resize(values.size() * 4);
      if (!values.empty()) std::memcpy(out->values.data(), values.data(), out->values.size());
    }
  }
  if (!s.ok()) {
    out->index.clear();
    out->values.clear();
  }
  return s;
}

Status CheckCodedPayload(ByteSpan payload, uint64_t line_length, uint64_t elements) {
  return DecodeCodedLines(
      payload, line_length, elements, [](uint64_t) -> std::byte* { return nullptr; }, [](uint64_t, const auto&) {});
}

}  // namespace ltb::format
