// Coded sparse chunks (encoding 5, format 1.2): codec round trips on many line shapes,
// densities and value ranges (the input is the oracle), the dense and sparse decodes
// agreeing, every truncation and trailing bytes refused, single-byte damage never crashing,
// the encoder's choice, and container round trips in both layouts through ReadChunk,
// ReadSparse, verify and content_hash. Hand-built malformed frames are in hostile_test.cpp;
// tests/format/coded_oracle.py decodes a payload from the spec's text alone.
#include <gtest/gtest.h>

#include <cstring>
#include <limits>
#include <random>

#include "format/chunk_codec.h"
#include "format/coded_codec.h"
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

constexpr int32_t kMin = std::numeric_limits<int32_t>::min();
constexpr int32_t kMax = std::numeric_limits<int32_t>::max();

// Decodes `payload` both ways and checks both against `dense`.
void ExpectDecodes(const std::vector<std::byte>& payload, uint64_t line, const std::vector<int32_t>& dense) {
  std::vector<int32_t> back(dense.size(), 12345);
  Status s = format::DecodeCodedInto(payload, line, std::as_writable_bytes(std::span<int32_t>(back)));
  ASSERT_TRUE(s.ok()) << s.message();
  EXPECT_EQ(back, dense);
  format::SparseChunk got, want;
  s = format::DecodeCodedPayload(payload, line, dense.size(), &got);
  ASSERT_TRUE(s.ok()) << s.message();
  ASSERT_TRUE(format::SparseFromDense(test::AsBytes(dense), DType::kI32, &want).ok());
  EXPECT_EQ(got.index, want.index);
  EXPECT_EQ(got.values, want.values);
  EXPECT_EQ(got.dtype, DType::kI32);
  EXPECT_TRUE(format::CheckCodedPayload(payload, line, dense.size()).ok());
}

std::vector<std::byte> Encode(const std::vector<int32_t>& dense, uint64_t line, uint64_t width) {
  return format::EncodeCodedPayload(test::AsBytes(dense), line, width);
}

// Quantised-wavelet-like lines: nonzeros denser and larger near (0, 0) of a W-wide image,
// neighbouring lines alike.
std::vector<int32_t> WaveletLike(uint64_t line, uint64_t width, uint64_t lines, double density, uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(0, 1);
  std::vector<int32_t> v(line * lines, 0);
  for (uint64_t t = 0; t < lines; ++t) {
    for (uint64_t p = 0; p < line; ++p) {
      const uint64_t x = p % width, y = p / width;
      const double near = 1.0 / (1.0 + 0.2 * static_cast<double>(std::max(x, y)));
      if (u(rng) < density * 4 * near || (t > 0 && v[(t - 1) * line + p] != 0 && u(rng) < 0.5)) {
        int32_t m = 1 + static_cast<int32_t>(u(rng) * u(rng) * 30 * near * 4);
        v[t * line + p] = u(rng) < 0.5 ? -m : m;
      }
    }
  }
  return v;
}

struct CodedShape {
  uint64_t line, width, lines;
};

TEST(CodedPayload, RoundTripsEveryShapeAndDensity) {
  const CodedShape shapes[] = {{1, 1, 1},    {1, 1, 5},     {7, 3, 4},  {16, 1, 3},  {33, 33, 4},
                               {100, 9, 6},  {64, 8, 3},    {65, 8, 3}, {17, 16, 5}, {300, 16, 4},
                               {256, 16, 9}, {1000, 31, 2}, {9, 2, 40}, {24, 5, 3}};
  std::mt19937 rng(7);
  for (const CodedShape& s : shapes) {
    const uint64_t n = s.line * s.lines;
    for (int pattern = 0; pattern < 7; ++pattern) {
      SCOPED_TRACE("line " + std::to_string(s.line) + " width " + std::to_string(s.width) + " lines " +
                   std::to_string(s.lines) + " pattern " + std::to_string(pattern));
      std::vector<int32_t> v(n, 0);
      std::uniform_int_distribution<int32_t> any(kMin, kMax);
      switch (pattern) {
        case 0:  // all zero
          break;
        case 1:  // one nonzero, at the last element
          v[n - 1] = -1;
          break;
        case 2:  // every element nonzero, the extremes included
          for (uint64_t i = 0; i < n; ++i) {
            const int32_t e[] = {1, -1, kMax, -kMax, kMin, 2, -2, 3};
            v[i] = e[i % 8];
          }
          break;
        case 3:  // random 32-bit values at random places
          for (uint64_t i = 0; i < n; ++i)
            if (rng() % 3 == 0) v[i] = any(rng) | 1;
          break;
        case 4:  // runs of one value
          for (uint64_t i = 0; i < n; ++i) v[i] = (i / 5) % 2 ? 7 : 0;
          break;
        case 5:
          v = WaveletLike(s.line, s.width, s.lines, 0.05, static_cast<uint32_t>(s.line));
          break;
        case 6:  // powers of two around every bucket boundary
          for (uint64_t i = 0; i < n; ++i) {
            const unsigned k = static_cast<unsigned>(i % 32);
            const int64_t m = (int64_t{1} << k) + static_cast<int64_t>(i % 3) - 1;
            if (m >= 1 && m <= kMax) v[i] = static_cast<int32_t>(i % 2 ? -m : m);
          }
          break;
      }
      std::vector<std::byte> p = Encode(v, s.line, s.width);
      ASSERT_FALSE(p.empty());
      EXPECT_EQ(static_cast<uint8_t>(p[0]), format::kCodedModel);
      ExpectDecodes(p, s.line, v);
      // Encoding is deterministic.
      EXPECT_EQ(Encode(v, s.line, s.width), p);
    }
  }
}

TEST(CodedPayload, EmptyForShapesItCannotCode) {
  std::vector<int32_t> v(12, 1);
  EXPECT_TRUE(Encode(v, 5, 1).empty());   // 12 elements are not lines of 5
  EXPECT_TRUE(Encode(v, 0, 1).empty());   // no line length
  EXPECT_TRUE(Encode(v, 12, 0).empty());  // W = 0
  EXPECT_TRUE(Encode(v, 6, 7).empty());   // W > L
  EXPECT_TRUE(format::EncodeCodedPayload(test::AsBytes(std::vector<uint8_t>(6)), 3, 1).empty());  // not i32
}

TEST(CodedPayload, CompressesWaveletLikeLinesBelowTheSparseEncodings) {
  std::vector<int32_t> v = WaveletLike(32 * 32, 32, 64, 0.03, 3);
  std::vector<std::byte> coded = Encode(v, 32 * 32, 32);
  std::vector<std::byte> sparse = format::EncodeSparsePayload(test::AsBytes(v), DType::kI32);
  EXPECT_LT(coded.size(), sparse.size());
  ExpectDecodes(coded, 32 * 32, v);
}

// Every truncation of a small payload and every trailing byte is refused; a few hundred
// single-byte corruptions decode or are refused, never crash (the ASan tree runs this).
TEST(CodedPayload, DamageIsRefusedNeverACrash) {
  const uint64_t line = 60, width = 8;
  std::vector<int32_t> v = WaveletLike(line, width, 12, 0.08, 11);
  v[5] = kMin;
  v[70] = kMax;
  std::vector<std::byte> p = Encode(v, line, width);
  ASSERT_GT(p.size(), 20u);
  ExpectDecodes(p, line, v);
  std::vector<int32_t> out(v.size());
  auto dense = std::as_writable_bytes(std::span<int32_t>(out));
  for (size_t cut = 0; cut < p.size(); ++cut) {
    std::vector<std::byte> t(p.begin(), p.begin() + static_cast<std::ptrdiff_t>(cut));
    Status s = format::DecodeCodedInto(t, line, dense);
    EXPECT_EQ(s.code(), StatusCode::kDataLoss) << "cut at " << cut;
    format::SparseChunk sc;
    EXPECT_EQ(format::DecodeCodedPayload(t, line, v.size(), &sc).code(), StatusCode::kDataLoss) << cut;
    EXPECT_TRUE(sc.index.empty());
    EXPECT_EQ(format::CheckCodedPayload(t, line, v.size()).code(), StatusCode::kDataLoss) << cut;
  }
  for (int extra : {1, 2, 7}) {
    for (int value : {0, 0xFF}) {
      std::vector<std::byte> t = p;
      t.insert(t.end(), static_cast<size_t>(extra), static_cast<std::byte>(value));
      Status s = format::DecodeCodedInto(t, line, dense);
      EXPECT_EQ(s.code(), StatusCode::kDataLoss) << extra << " trailing bytes " << value;
    }
  }
  std::mt19937 rng(5);
  int refused = 0, decoded = 0;
  for (int i = 0; i < 400; ++i) {
    std::vector<std::byte> t = p;
    const size_t at = rng() % t.size();
    t[at] ^= static_cast<std::byte>(1 + rng() % 255);
    Status s = format::DecodeCodedInto(t, line, dense);
    format::SparseChunk sc;
    Status s2 = format::DecodeCodedPayload(t, line, v.size(), &sc);
    EXPECT_EQ(s.ok(), s2.ok());
    if (s.ok()) {
      ++decoded;  // the frame checksum catches this; the decoder only has to stay in bounds
    } else {
      ++refused;
      EXPECT_EQ(s.code(), StatusCode::kDataLoss) << s.message();
    }
  }
  EXPECT_GT(refused, 300) << decoded << " damaged payloads decoded";
}

TEST(CodedPayload, MalformedHeadersAreDataLoss) {
  std::vector<int32_t> v = {0, 3, 0, -4, 0, 0, 0, 0};
  std::vector<std::byte> p = Encode(v, 4, 2);
  ASSERT_EQ(static_cast<uint8_t>(p[1]), 2);  // varint W = 2
  std::vector<int32_t> out(8);
  auto dense = std::as_writable_bytes(std::span<int32_t>(out));
  auto expect = [&](std::vector<std::byte> t, const std::string& want) {
    Status s = format::DecodeCodedInto(t, 4, dense);
    EXPECT_EQ(s.code(), StatusCode::kDataLoss) << want;
    EXPECT_NE(s.message().find(want), std::string::npos) << s.message();
  };
  expect({}, "empty");
  auto q = p;
  q[0] = std::byte{2};
  expect(q, "unknown model 2");
  q = p;
  q[1] = std::byte{0};
  expect(q, "image width 0");
  q = p;
  q[1] = std::byte{5};
  expect(q, "image width 5");
  q = p;  // W = 2 as the non-canonical 0x82 0x00
  q[1] = std::byte{0x82};
  q.insert(q.begin() + 2, std::byte{0});
  expect(q, "non-canonical");
  expect({std::byte{1}}, "ends inside the image width");
  expect({std::byte{1}, std::byte{0x80}}, "ends inside the image width");
  q = p;
  q[2] = std::byte{1};  // the coder's first byte is always 0
  expect(q, "first byte");
  // A line longer than the format allows, and a shape that is not lines.
  EXPECT_EQ(format::DecodeCodedInto(p, 3, dense).code(), StatusCode::kInvalidArgument);
  EXPECT_EQ(format::CheckCodedChunkShape(DType::kF32, 4, 8).code(), StatusCode::kDataLoss);
  EXPECT_EQ(format::CheckCodedChunkShape(DType::kI32, format::kMaxCodedLine + 1, format::kMaxCodedLine + 1).code(),
            StatusCode::kDataLoss);
  EXPECT_TRUE(format::CheckCodedChunkShape(DType::kI32, 4, 8).ok());
}

// ---- The encoder's choice ----

TEST(CodedChoice, EncodeChunkKeepsTheSmallestAndOnlyForI32) {
  std::vector<int32_t> v = WaveletLike(16 * 16, 16, 32, 0.03, 9);
  format::EncodeOptions eo;
  eo.sparse = true;
  eo.zstd = true;
  eo.dtype = DType::kI32;
  eo.coded = true;
  eo.coded_width = 16;
  eo.line_length = 256;
  format::EncodedChunk c = format::EncodeChunk(test::AsBytes(v), eo);
  EXPECT_EQ(c.encoding, Encoding::kCoded);
  EXPECT_EQ(c.line_length, 256u);
  EXPECT_EQ(c.payload.size(), Encode(v, 256, 16).size());
  // Without a line length, or with W above it, or for another dtype: never coded.
  eo.line_length = 0;
  EXPECT_NE(format::EncodeChunk(test::AsBytes(v), eo).encoding, Encoding::kCoded);
  eo.line_length = 8;
  EXPECT_NE(format::EncodeChunk(test::AsBytes(v), eo).encoding, Encoding::kCoded);
  eo.line_length = 256;
  eo.dtype = DType::kU32;
  EXPECT_NE(format::EncodeChunk(test::AsBytes(v), eo).encoding, Encoding::kCoded);
  // All zero stays kZero; coded_width 0 is one image row per line.
  eo.dtype = DType::kI32;
  std::vector<int32_t> zeros(512, 0);
  EXPECT_EQ(format::EncodeChunk(test::AsBytes(zeros), eo).encoding, Encoding::kZero);
  eo.coded_width = 0;
  c = format::EncodeChunk(test::AsBytes(v), eo);
  ASSERT_EQ(c.encoding, Encoding::kCoded);
  EXPECT_EQ(c.payload.size(), Encode(v, 256, 256).size());
}

// ---- Containers ----

nlohmann::json I32Meta(uint64_t rows, uint64_t cols, Layout layout, uint64_t block) {
  format::ArraySpec s;
  s.name = "matrix";
  s.dtype = DType::kI32;
  s.rows = rows;
  s.cols = cols;
  s.layout = layout;
  s.block = block;
  return {{"arrays", {s.ToJson()}}};
}

TEST(CodedContainer, RoundTripsInBothLayoutsWithVerifyAndOneContentHash) {
  test::TempDir dir;
  for (Layout layout : {Layout::kCols, Layout::kRows}) {
    SCOPED_TRACE(format::LayoutName(layout));
    // 24 x 20 matrix: lines are columns (24 = a 6 x 4 image) or rows (20 = a 5 x 4 image).
    const uint64_t rows = 24, cols = 20, block = 7;
    std::vector<int32_t> m(rows * cols, 0);
    std::mt19937 rng(3);
    for (auto& x : m)
      if (rng() % 4 == 0) x = static_cast<int32_t>(rng() % 41) - 20;
    m[5] = kMin;
    m[6] = kMax;
    std::string hash[2];
    for (int coded = 0; coded < 2; ++coded) {
      const std::string path = dir.File(std::string(format::LayoutName(layout)) + std::to_string(coded) + ".ltm");
      format::EncodeOptions eo;
      eo.sparse = true;
      eo.zstd = true;
      eo.coded = coded == 1;
      eo.coded_width = layout == Layout::kCols ? 6 : 5;
      eo.min_saving = -1e9;  // keep a candidate even where it saves nothing
      Status written = test::WriteValues(path, I32Meta(rows, cols, layout, block), m, eo);
      ASSERT_TRUE(written.ok()) << written.message();
      auto v = io::VerifyContainer(path);
      EXPECT_TRUE(v.complete);
      EXPECT_TRUE(v.problems.empty()) << v.problems.front();
      auto r = io::ContainerReader::Open(path);
      ASSERT_TRUE(r.ok()) << r.status().message();
      EXPECT_EQ(r->header().minor, format::kMinorCoded);
      int coded_chunks = 0;
      for (const auto& e : r->chunk_frames()) coded_chunks += e.header.encoding == 5;
      if (coded == 1) {
        EXPECT_GT(coded_chunks, 0);
      } else {
        EXPECT_EQ(coded_chunks, 0);
      }
      const format::ArraySpec& a = r->metadata().matrix();
      for (uint64_t i = 0; i < a.ChunkCount(); ++i) {
        auto want = test::ChunkValues(a, m, i);
        auto c = r->ReadChunk(0, i);
        ASSERT_TRUE(c.ok()) << c.status().message();
        EXPECT_EQ(std::vector<int32_t>(c->as<int32_t>().begin(), c->as<int32_t>().end()), want);
        auto sp = r->ReadSparse(0, i);
        ASSERT_TRUE(sp.ok()) << sp.status().message();
        format::SparseChunk ref;
        ASSERT_TRUE(format::SparseFromDense(test::AsBytes(want), DType::kI32, &ref).ok());
        EXPECT_EQ(sp->index, ref.index);
        EXPECT_EQ(sp->values, ref.values);
        EXPECT_EQ(sp->extent.cols, a.Extent(i).cols);
        // A coded chunk copies as stored (what `merge` does).
        auto enc = r->ReadEncoded(0, i);
        ASSERT_TRUE(enc.ok());
        EXPECT_EQ(enc->line_length, format::CodedLineLength(layout, a.Extent(i)));
      }
      auto sum = io::SummarizeArray(*r, 0, 2);
      ASSERT_TRUE(sum.ok()) << sum.status().message();
      hash[coded] = sum->content_hash;
    }
    EXPECT_EQ(hash[0], hash[1]);
    EXPECT_FALSE(hash[0].empty());
  }
}

TEST(CodedContainer, WriterRefusesACodedChunkForAnotherDtypeOrLine) {
  test::TempDir dir;
  format::ArraySpec s;
  s.name = "matrix";
  s.dtype = DType::kF32;
  s.rows = 8;
  s.cols = 2;
  s.layout = Layout::kCols;
  s.block = 2;
  auto w = io::ContainerWriter::Open(dir.File("f.ltm"), nlohmann::json{{"arrays", {s.ToJson()}}});
  ASSERT_TRUE(w.ok());
  std::vector<int32_t> v = {0, 1, 0, 0, 0, 0, 2, 0, 0, 0, 0, 0, 0, 0, 0, 3};
  format::EncodedChunk c;
  c.encoding = Encoding::kCoded;
  c.decoded_length = 64;
  c.dtype = DType::kI32;
  c.line_length = 8;
  c.owned = Encode(v, 8, 4);
  c.payload = c.owned;
  c.checksum = format::Checksum(c.payload);
  EXPECT_EQ(w->Append(0, 0, c).code(), StatusCode::kInvalidArgument);  // an f32 array
  // Through Put the array's dtype rules: an f32 array never gets kCoded.
  format::EncodeOptions eo;
  eo.sparse = true;
  eo.coded = true;
  eo.dtype = DType::kI32;
  ASSERT_TRUE(w->Put(0, 0, test::AsBytes(v), eo).ok());
  ASSERT_TRUE(w->Finish().ok());
  auto r = io::ContainerReader::Open(dir.File("f.ltm"));
  ASSERT_TRUE(r.ok());
  EXPECT_NE(r->Find(0, 0)->header.encoding, 5);
}

}  // namespace
}  // namespace ltb
