// Sparse chunk encodings (format 1.1): payload bytes exactly as docs/FORMAT.md lays them
// out, codec round trips for every dtype, the encoder's choice, container round trips in
// both layouts with uneven chunks (bit-exact, -0.0, denormals), ReadSparse agreeing across
// encodings, and content_hash independent of the encoding. Malformed payloads are in
// hostile_test.cpp; damage to a sparse chunk in damage_test.cpp.
#include <gtest/gtest.h>

#include <cstring>
#include <limits>
#include <random>

#include "format/chunk_codec.h"
#include "format/content_hash.h"
#include "format/io/array_summary.h"
#include "format/io/container_reader.h"
#include "format/io/container_writer.h"
#include "format/io/verifier.h"
#include "format/version.h"
#include "test_util.h"

namespace ltb {
namespace {

using format::DType;
using format::Encoding;
using format::Layout;

std::vector<std::byte> B(std::initializer_list<int> v) {
  std::vector<std::byte> out;
  for (int x : v) out.push_back(static_cast<std::byte>(x));
  return out;
}

template <typename T>
std::vector<std::byte> Payload(const std::vector<T>& dense, DType dtype) {
  return format::EncodeSparsePayload(test::AsBytes(dense), dtype);
}

bool IsSparse(Encoding e) { return e == Encoding::kSparse || e == Encoding::kSparseZstd; }

// One zstd frame of `bytes` (through the zstd candidate of EncodeChunk, accepted at any size).
std::vector<std::byte> ZstdFrame(format::ByteSpan bytes) {
  format::EncodeOptions eo;
  eo.detect_zero = false;
  eo.zstd = true;
  eo.min_saving = -1e9;
  format::EncodedChunk c = format::EncodeChunk(bytes, eo);
  EXPECT_EQ(c.encoding, Encoding::kZstd);
  return c.owned;
}

// ---- Payload bytes, laid out by hand from docs/FORMAT.md ----

TEST(SparsePayload, F32BytesAsSpecified) {
  // Stored: index 1 (1.0f) and index 4 (-0.0f, nonzero bits). Gaps 1 and 4-1-1 = 2.
  std::vector<float> v = {0.0f, 1.0f, 0.0f, 0.0f, -0.0f, 0.0f};
  EXPECT_EQ(Payload(v, DType::kF32), B({0x02, 0x01, 0x02, 0x00, 0x00, 0x80, 0x3F, 0x00, 0x00, 0x00, 0x80}));
}

TEST(SparsePayload, I32ZigzagVarints) {
  // zigzag(-1) = 1, zigzag(200) = 400 = varint 90 03, zigzag(INT32_MIN) = 2^32 - 1.
  std::vector<int32_t> v = {0, -1, 0, 200, std::numeric_limits<int32_t>::min()};
  EXPECT_EQ(Payload(v, DType::kI32), B({0x03, 0x01, 0x01, 0x00, 0x01, 0x90, 0x03, 0xFF, 0xFF, 0xFF, 0xFF, 0x0F}));
}

TEST(SparsePayload, UnsignedVarintsAndLongGaps) {
  std::vector<uint8_t> u8(400, 0);
  u8[0] = 7;
  u8[300] = 255;  // gap 299 = varint AB 02; 255 = varint FF 01
  EXPECT_EQ(Payload(u8, DType::kU8), B({0x02, 0x00, 0xAB, 0x02, 0x07, 0xFF, 0x01}));
  std::vector<uint64_t> u64 = {0, ~uint64_t{0}, 1};
  EXPECT_EQ(Payload(u64, DType::kU64),
            B({0x02, 0x01, 0x00, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0x01, 0x01}));
  std::vector<uint32_t> u32 = {0, 0, 0x80};
  EXPECT_EQ(Payload(u32, DType::kU32), B({0x01, 0x02, 0x80, 0x01}));
}

TEST(SparsePayload, F64AndEmpty) {
  std::vector<double> f64 = {0.0, std::numeric_limits<double>::denorm_min()};
  EXPECT_EQ(Payload(f64, DType::kF64), B({0x01, 0x01, 0x01, 0, 0, 0, 0, 0, 0, 0}));
  std::vector<float> zeros(5, 0.0f);
  EXPECT_EQ(Payload(zeros, DType::kF32), B({0x00}));
  // Not a whole number of elements: empty, never a valid payload.
  std::vector<uint8_t> odd(6, 1);
  EXPECT_TRUE(format::EncodeSparsePayload(test::AsBytes(odd), DType::kF32).empty());
}

// ---- Codec round trips ----

// Random bit patterns, about `density` of them nonzero, with special values mixed in.
std::vector<std::byte> RandomDense(DType dtype, uint64_t elements, double density, uint32_t seed) {
  const uint64_t size = format::DTypeSize(dtype);
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(0, 1);
  const uint64_t specials[] = {0x80000000u,           0x00000001u,           0x007FFFFFu, 0x7FC00001u, 0xFFFFFFFFu,
                               0x8000000000000000ull, 0x0000000000000001ull, 0xFFull,     0x80ull};
  std::vector<std::byte> out(elements * size);
  for (uint64_t i = 0; i < elements; ++i) {
    if (u(rng) >= density) continue;
    uint64_t bits = u(rng) < 0.3 ? specials[rng() % std::size(specials)] : rng() >> (rng() % 64);
    std::memcpy(&out[i * size], &bits, size);  // may still be zero: then it is not stored
  }
  return out;
}

TEST(SparseCodec, RoundTripsEveryDtype) {
  for (DType dtype : {DType::kF32, DType::kF64, DType::kU8, DType::kI32, DType::kU32, DType::kU64}) {
    for (double density : {0.0, 0.05, 0.5, 1.0}) {
      SCOPED_TRACE(std::string(format::DTypeName(dtype)) + " density " + std::to_string(density));
      const uint64_t elements = 1000;
      std::vector<std::byte> dense = RandomDense(dtype, elements, density, 7);
      std::vector<std::byte> payload = format::EncodeSparsePayload(dense, dtype);
      std::vector<std::byte> back(dense.size(), std::byte{0x5A});
      Status s = format::DecodeSparseInto(payload, dtype, back);
      ASSERT_TRUE(s.ok()) << s.message();
      EXPECT_EQ(back, dense);

      format::SparseChunk want, got;
      ASSERT_TRUE(format::SparseFromDense(dense, dtype, &want).ok());
      s = format::DecodeSparsePayload(payload, dtype, elements, &got);
      ASSERT_TRUE(s.ok()) << s.message();
      EXPECT_EQ(got.index, want.index);
      EXPECT_EQ(got.values, want.values);
      EXPECT_EQ(got.values.size(), got.index.size() * format::DTypeSize(dtype));
      for (size_t k = 1; k < got.index.size(); ++k) EXPECT_LT(got.index[k - 1], got.index[k]);

      std::vector<std::byte> frame = ZstdFrame(payload);
      std::fill(back.begin(), back.end(), std::byte{0x5A});
      s = format::DecodeSparseZstdInto(frame, dtype, back);
      ASSERT_TRUE(s.ok()) << s.message();
      EXPECT_EQ(back, dense);
      format::SparseChunk gz;
      s = format::DecodeSparseZstdPayload(frame, dtype, elements, &gz);
      ASSERT_TRUE(s.ok()) << s.message();
      EXPECT_EQ(gz.index, want.index);
      EXPECT_EQ(gz.values, want.values);
      EXPECT_TRUE(format::CheckSparsePayload(Encoding::kSparse, payload, dtype, elements).ok());
      EXPECT_TRUE(format::CheckSparsePayload(Encoding::kSparseZstd, frame, dtype, elements).ok());
    }
  }
}

TEST(SparseCodec, ZstdStreamLargerThanOneWindow) {
  // A payload of several zstd output windows (128 KiB each): pieces split values and varints.
  const uint64_t elements = 300000;
  std::vector<std::byte> dense = RandomDense(DType::kU64, elements, 0.6, 3);
  std::vector<std::byte> payload = format::EncodeSparsePayload(dense, DType::kU64);
  ASSERT_GT(payload.size(), 3u << 17);
  std::vector<std::byte> back(dense.size());
  Status s = format::DecodeSparseZstdInto(ZstdFrame(payload), DType::kU64, back);
  ASSERT_TRUE(s.ok()) << s.message();
  EXPECT_EQ(back, dense);
}

// ---- The encoder's choice ----

TEST(SparseEncoder, ChoosesSparseForMostlyZeroAndRawForDense) {
  std::vector<std::byte> mostly_zero = RandomDense(DType::kF32, 4096, 0.02, 11);
  std::vector<uint32_t> dense(4096);  // random bit patterns: zstd cannot shrink them either
  std::mt19937 rng(5);
  for (uint32_t& x : dense) x = rng() | 1u;
  for (bool zstd : {false, true}) {
    format::EncodeOptions eo;
    eo.sparse = true;
    eo.zstd = zstd;
    format::EncodedChunk c = format::EncodeChunk(mostly_zero, eo);
    EXPECT_TRUE(IsSparse(c.encoding)) << format::EncodingName(c.encoding);
    if (!zstd) {
      EXPECT_EQ(c.encoding, Encoding::kSparse);
    }
    EXPECT_EQ(c.checksum, format::Checksum(c.payload));
    EXPECT_EQ(c.decoded_length, mostly_zero.size());
    EXPECT_EQ(c.dtype, DType::kF32);
    std::vector<std::byte> back(mostly_zero.size());
    Status s = c.encoding == Encoding::kSparse ? format::DecodeSparseInto(c.payload, DType::kF32, back)
                                               : format::DecodeSparseZstdInto(c.payload, DType::kF32, back);
    ASSERT_TRUE(s.ok()) << s.message();
    EXPECT_EQ(back, mostly_zero);
    EXPECT_EQ(format::EncodeChunk(test::AsBytes(dense), eo).encoding, Encoding::kRaw);
  }
  // Without the option, never sparse.
  format::EncodeOptions plain;
  plain.zstd = true;
  EXPECT_FALSE(IsSparse(format::EncodeChunk(mostly_zero, plain).encoding));
}

TEST(SparseEncoder, KeepsSparseOnlyWhenItSavesMinSaving) {
  // 100 f32 with n nonzero (all gaps 0 or 1, one byte each): sparse = 1 + n + 4n bytes, raw 400.
  auto chunk = [](int n) {
    std::vector<float> v(100, 0.0f);
    for (int i = 0; i < n; ++i) v[i] = 1.0f + static_cast<float>(i) * 0.37f;
    return v;
  };
  format::EncodeOptions eo;
  eo.sparse = true;
  EXPECT_EQ(format::EncodeChunk(test::AsBytes(chunk(70)), eo).encoding, Encoding::kSparse);  // 351 bytes: 12% saved
  EXPECT_EQ(format::EncodeChunk(test::AsBytes(chunk(75)), eo).encoding, Encoding::kRaw);     // 376 bytes: 6% saved
}

TEST(SparseEncoder, ZeroChunksAndDeterminism) {
  std::vector<float> zeros(64, 0.0f);
  format::EncodeOptions eo;
  eo.sparse = true;
  eo.zstd = true;
  EXPECT_EQ(format::EncodeChunk(test::AsBytes(zeros), eo).encoding, Encoding::kZero);
  eo.detect_zero = false;
  format::EncodedChunk c = format::EncodeChunk(test::AsBytes(zeros), eo);
  EXPECT_EQ(c.encoding, Encoding::kSparse);
  EXPECT_EQ(std::vector<std::byte>(c.payload.begin(), c.payload.end()), B({0x00}));

  std::vector<std::byte> data = RandomDense(DType::kI32, 5000, 0.1, 9);
  eo.dtype = DType::kI32;
  format::EncodedChunk a = format::EncodeChunk(data, eo), b = format::EncodeChunk(data, eo);
  EXPECT_EQ(a.encoding, b.encoding);
  EXPECT_EQ(a.owned, b.owned);
  EXPECT_EQ(a.checksum, b.checksum);
}

// ---- Containers: round trips, ReadSparse and content_hash across encodings ----

nlohmann::json Meta(DType dtype, uint64_t rows, uint64_t cols, Layout layout, uint64_t block) {
  format::ArraySpec s;
  s.name = "matrix";
  s.dtype = dtype;
  s.rows = rows;
  s.cols = cols;
  s.layout = layout;
  s.block = block;
  return {{"arrays", {s.ToJson()}}};
}

// Bit patterns of a rows x cols matrix (row-major). The chunk-sized bands (rows or columns,
// as the layout chunks them) cycle through dense, sparse, all-zero and sparse with one
// repeated value, so a file mixes encodings; -0.0, denormals, NaN and INT_MIN bits are in.
std::vector<uint32_t> MakeBits(uint64_t rows, uint64_t cols, Layout layout, uint64_t block, uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(0, 1);
  const uint32_t specials[] = {0x80000000u /* -0.0f, INT32_MIN */, 0x00000001u, 0x007FFFFFu /* denormals */,
                               0x7FC00001u /* NaN */, 0xFFFFFFFFu /* -1 */};
  std::vector<uint32_t> m(rows * cols, 0);
  for (uint64_t r = 0; r < rows; ++r) {
    for (uint64_t c = 0; c < cols; ++c) {
      uint64_t band = (layout == Layout::kRows ? r : c) / block;
      double density = band % 4 == 0 ? 1.0 : band % 4 == 1 ? 0.08 : band % 4 == 2 ? 0.0 : 0.3;
      if (u(rng) >= density) continue;
      if (band % 4 == 3) {
        m[r * cols + c] = 0x3F800000u;  // 1.0f: compressible sparse payload
      } else {
        m[r * cols + c] = u(rng) < 0.3 ? specials[rng() % std::size(specials)] : (rng() | 1u);
      }
    }
  }
  m[(block + 1) * cols + block + 2] = 0x80000000u;  // -0.0f in a sparse band, always
  m[(block + 2) * cols + block + 1] = 0x00000001u;  // the smallest denormal
  return m;
}

struct SparseCase {
  DType dtype;
  Layout layout;
  uint64_t rows, cols, block;
};

class SparseContainer : public ::testing::TestWithParam<SparseCase> {};

TEST_P(SparseContainer, EveryEncodingReadsBackBitExactWithOneContentHash) {
  const SparseCase p = GetParam();
  test::TempDir dir;
  const std::vector<uint32_t> m = MakeBits(p.rows, p.cols, p.layout, p.block, 17);
  struct Mode {
    const char* name;
    bool zstd, sparse;
  };
  const Mode modes[] = {
      {"raw", false, false}, {"zstd", true, false}, {"sparse", false, true}, {"sparse-zstd", true, true}};
  std::string hashes[4];
  std::vector<format::SparseChunk> sparse_ref;
  for (int mi = 0; mi < 4; ++mi) {
    const Mode& mode = modes[mi];
    SCOPED_TRACE(mode.name);
    std::string path = dir.File(std::string(mode.name) + ".ltm");
    format::EncodeOptions eo;
    eo.zstd = mode.zstd;
    eo.sparse = mode.sparse;
    eo.dtype = p.dtype;
    Status written = test::WriteValues(path, Meta(p.dtype, p.rows, p.cols, p.layout, p.block), m, eo);
    ASSERT_TRUE(written.ok()) << written.message();
    auto v = io::VerifyContainer(path);
    EXPECT_TRUE(v.complete);
    EXPECT_TRUE(v.problems.empty()) << v.problems.front();
    auto r = io::ContainerReader::Open(path);
    ASSERT_TRUE(r.ok()) << r.status().message();
    EXPECT_EQ(r->header().minor, format::kFormatMinor);
    const format::ArraySpec& a = r->metadata().matrix();
    int by_encoding[5] = {0, 0, 0, 0, 0};
    for (const auto& e : r->chunk_frames()) by_encoding[e.header.encoding]++;
    if (mode.sparse) {
      // Dense bands stay raw, empty ones zero, sparse ones sparse; the repeated-value band
      // (the fourth chunk) compresses further.
      EXPECT_GT(by_encoding[0], 0);
      EXPECT_GT(by_encoding[1], 0);
      EXPECT_GT(by_encoding[3], 0);
      if (mode.zstd && a.ChunkCount() >= 4) {
        EXPECT_GT(by_encoding[4], 0);
      }
    } else {
      EXPECT_EQ(by_encoding[3] + by_encoding[4], 0);
    }
    // Dense reads: bit-exact, placed by the layout.
    std::vector<uint32_t> got(p.rows * p.cols, 0xDEADBEEF);
    for (uint64_t i = 0; i < a.ChunkCount(); ++i) {
      auto c = r->ReadChunk(0, i);
      ASSERT_TRUE(c.ok()) << c.status().message();
      auto vals = c->as<uint32_t>();
      const auto& e = c->extent();
      ASSERT_EQ(vals.size(), e.Elements());
      for (uint64_t rr = 0; rr < e.rows; ++rr)
        for (uint64_t cc = 0; cc < e.cols; ++cc)
          got[(e.row0 + rr) * p.cols + e.col0 + cc] =
              p.layout == Layout::kRows ? vals[rr * e.cols + cc] : vals[cc * e.rows + rr];
    }
    EXPECT_EQ(got, m);
    // Sparse reads: the same for every encoding; indices in the chunk's storage order.
    for (uint64_t i = 0; i < a.ChunkCount(); ++i) {
      auto s = r->ReadSparse(0, i);
      ASSERT_TRUE(s.ok()) << s.status().message();
      EXPECT_EQ(s->dtype, p.dtype);
      const auto& e = s->extent;
      EXPECT_EQ(e.row0, a.Extent(i).row0);
      EXPECT_EQ(e.col0, a.Extent(i).col0);
      auto vals = s->as<uint32_t>();
      ASSERT_EQ(vals.size(), s->index.size());
      for (size_t k = 0; k < s->index.size(); ++k) {
        uint64_t idx = s->index[k];
        uint64_t rr = p.layout == Layout::kRows ? idx / e.cols : idx % e.rows;
        uint64_t cc = p.layout == Layout::kRows ? idx % e.cols : idx / e.rows;
        EXPECT_EQ(vals[k], m[(e.row0 + rr) * p.cols + e.col0 + cc]);
        EXPECT_NE(vals[k], 0u);
      }
      if (mi == 0) {
        sparse_ref.push_back(std::move(s).value());
      } else {
        EXPECT_EQ(s->index, sparse_ref[i].index) << "chunk " << i;
        EXPECT_EQ(s->values, sparse_ref[i].values) << "chunk " << i;
      }
    }
    auto sum = io::SummarizeArray(*r, 0, 2);
    ASSERT_TRUE(sum.ok()) << sum.status().message();
    hashes[mi] = sum->content_hash;
  }
  // The hash of the whole matrix as one dense row-major chunk.
  format::ArraySpec whole;
  whole.dtype = p.dtype;
  whole.rows = p.rows;
  whole.cols = p.cols;
  whole.block = p.rows;
  format::ContentHasher h;
  h.AddChunk(whole, whole.Extent(0), test::AsBytes(m));
  for (int mi = 0; mi < 4; ++mi) EXPECT_EQ(hashes[mi], h.Finish(whole)) << modes[mi].name;
}

INSTANTIATE_TEST_SUITE_P(Shapes, SparseContainer,
                         ::testing::Values(SparseCase{DType::kF32, Layout::kRows, 23, 17, 5},
                                           SparseCase{DType::kF32, Layout::kCols, 23, 17, 4},
                                           SparseCase{DType::kI32, Layout::kRows, 19, 13, 4},
                                           SparseCase{DType::kI32, Layout::kCols, 19, 13, 5}));

// ---- The 2^32 - 1 element limit of sparse chunks ----

TEST(SparseLimits, ChunksBeyondUint32IndicesAreRefused) {
  test::TempDir dir;
  std::string path = dir.File("big.ltm");
  const uint64_t elements = uint64_t(1) << 33;  // one u8 chunk of 8 GiB (nothing that large is allocated)
  auto w = io::ContainerWriter::Open(path, Meta(DType::kU8, 1, elements, Layout::kCols, elements));
  ASSERT_TRUE(w.ok()) << w.status().message();
  std::vector<uint8_t> small(16, 1);
  format::EncodeOptions eo;
  eo.sparse = true;
  Status s = w->Put(0, 0, test::AsBytes(small), eo);
  EXPECT_EQ(s.code(), StatusCode::kInvalidArgument);
  EXPECT_NE(s.message().find("more than a sparse chunk holds (4294967295)"), std::string::npos) << s.message();

  std::vector<std::byte> payload = B({0x00});
  format::EncodedChunk hand;
  hand.encoding = Encoding::kSparse;
  hand.decoded_length = elements;
  hand.dtype = DType::kU8;
  hand.owned = payload;
  hand.payload = hand.owned;
  hand.checksum = format::Checksum(hand.payload);
  s = w->Append(0, 0, hand);
  EXPECT_EQ(s.code(), StatusCode::kInvalidArgument);
  hand.dtype = DType::kF32;
  s = w->Append(0, 0, hand);
  EXPECT_EQ(s.code(), StatusCode::kInvalidArgument);
  EXPECT_NE(s.message().find("sparse-encoded as f32, the array is u8"), std::string::npos) << s.message();

  // An all-zero chunk is fine; ReadSparse refuses it (its indices would not fit in 32 bits).
  format::EncodedChunk zero;
  zero.encoding = Encoding::kZero;
  zero.decoded_length = elements;
  zero.checksum = format::Checksum({});
  ASSERT_TRUE(w->Append(0, 0, zero).ok());
  ASSERT_TRUE(w->Finish().ok());
  auto r = io::ContainerReader::Open(path);
  ASSERT_TRUE(r.ok()) << r.status().message();
  auto sp = r->ReadSparse(0, 0);
  EXPECT_EQ(sp.status().code(), StatusCode::kInvalidArgument);
  EXPECT_NE(sp.status().message().find("read it with ReadChunk"), std::string::npos) << sp.status().message();
}

TEST(SparseLimits, SparseWriterRefusesWrongDtypeThroughAppendOnly) {
  // Put encodes with the array's dtype whatever EncodeOptions::dtype says.
  test::TempDir dir;
  std::string path = dir.File("u8.ltm");
  auto w = io::ContainerWriter::Open(path, Meta(DType::kU8, 4, 100, Layout::kRows, 4));
  ASSERT_TRUE(w.ok()) << w.status().message();
  std::vector<uint8_t> v(400, 0);
  v[17] = 200;
  format::EncodeOptions eo;
  eo.sparse = true;
  eo.dtype = DType::kF64;
  ASSERT_TRUE(w->Put(0, 0, test::AsBytes(v), eo).ok());
  ASSERT_TRUE(w->Finish().ok());
  auto r = io::ContainerReader::Open(path);
  ASSERT_TRUE(r.ok());
  EXPECT_EQ(r->Find(0, 0)->header.encoding, static_cast<uint16_t>(Encoding::kSparse));
  auto c = r->ReadChunk(0, 0);
  ASSERT_TRUE(c.ok()) << c.status().message();
  EXPECT_EQ(std::vector<uint8_t>(c->as<uint8_t>().begin(), c->as<uint8_t>().end()), v);
}

}  // namespace
}  // namespace ltb
