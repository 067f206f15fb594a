// Damage sweep: flip every byte of a small container in turn, and truncate it at every
// offset. verify must report each flip as a problem and each truncation as a problem or
// as incomplete; nothing may crash or hang, and reading a damaged file may not allocate
// more than its size plus a small constant (tracked by replacing operator new).
#include <gtest/gtest.h>
#include <malloc.h>

#include <atomic>
#include <cstdlib>
#include <fstream>
#include <new>

#include "format/io/array_summary.h"
#include "format/io/container_reader.h"
#include "format/io/verifier.h"
#include "test_util.h"

namespace {
std::atomic<int64_t> g_live{0}, g_peak{0};

void* Track(void* p) {
  if (p == nullptr) throw std::bad_alloc();
  int64_t now =
      g_live.fetch_add(static_cast<int64_t>(malloc_usable_size(p))) + static_cast<int64_t>(malloc_usable_size(p));
  int64_t peak = g_peak.load();
  while (now > peak && !g_peak.compare_exchange_weak(peak, now)) {
  }
  return p;
}
void Untrack(void* p) {
  if (p == nullptr) return;
  g_live.fetch_sub(static_cast<int64_t>(malloc_usable_size(p)));
  std::free(p);
}
}  // namespace

void* operator new(size_t n) { return Track(std::malloc(n == 0 ? 1 : n)); }
void* operator new[](size_t n) { return Track(std::malloc(n == 0 ? 1 : n)); }
void* operator new(size_t n, std::align_val_t a) {
  return Track(std::aligned_alloc(static_cast<size_t>(a),
                                  (n + static_cast<size_t>(a) - 1) / static_cast<size_t>(a) * static_cast<size_t>(a)));
}
void operator delete(void* p) noexcept { Untrack(p); }
void operator delete[](void* p) noexcept { Untrack(p); }
void operator delete(void* p, size_t) noexcept { Untrack(p); }
void operator delete[](void* p, size_t) noexcept { Untrack(p); }
void operator delete(void* p, std::align_val_t) noexcept { Untrack(p); }
void operator delete(void* p, size_t, std::align_val_t) noexcept { Untrack(p); }

namespace ltb {
namespace {

constexpr int64_t kSmallConstant = 1 << 20;

void WriteBytes(const std::string& path, const std::vector<char>& b, size_t n) {
  std::ofstream(path, std::ios::binary | std::ios::trunc).write(b.data(), static_cast<std::streamsize>(n));
}

// Verifies and reads everything readable; returns the peak heap growth while doing so.
int64_t Exercise(const std::string& path, io::VerifyReport* report) {
  g_peak.store(g_live.load());
  int64_t base = g_live.load();
  *report = io::VerifyContainer(path);
  auto r = io::ContainerReader::Open(path);
  if (r.ok()) {
    const auto& meta = r->metadata();
    for (uint32_t a = 0; a < meta.arrays.size(); ++a) {
      for (const auto& e : r->chunk_frames()) {
        if (e.header.array == a) (void)r->ReadChunk(a, e.header.chunk_index);
      }
      (void)io::SummarizeArray(*r, a, 1);
    }
  }
  return g_peak.load() - base;
}

class DamageSweep : public ::testing::Test {
 protected:
  void SetUp() override {
    good_ = dir_.File("good.ltm");
    // Row blocks with raw, all-zero, zstd, sparse and sparse+zstd chunks, a side table, and
    // an i32 table in one sparse-coded chunk (lines of 16, 4 wide).
    format::ArraySpec mask;
    mask.name = "mask";
    mask.dtype = format::DType::kU8;
    mask.rows = 35;
    mask.cols = 1;
    mask.block = 35;
    auto meta = test::MatrixMetadata(35, 12, format::Layout::kRows, 7);
    meta["arrays"].push_back(mask.ToJson());
    format::ArraySpec codes;
    codes.name = "codes";
    codes.dtype = format::DType::kI32;
    codes.rows = 16;
    codes.cols = 3;
    codes.layout = format::Layout::kCols;
    codes.block = 3;
    meta["arrays"].push_back(codes.ToJson());
    auto w = io::ContainerWriter::Open(good_, meta);
    ASSERT_TRUE(w.ok());
    std::vector<float> m = test::MakeMatrix(35, 12, 11);
    for (size_t i = 7; i < 14; ++i)
      for (size_t c = 0; c < 12; ++c) m[i * 12 + c] = 0.0f;                          // chunk 1 all zero
    for (size_t c = 0; c < 12 * 7; ++c) m[14 * 12 + c] = static_cast<float>(c % 3);  // chunk 2 compressible
    for (size_t c = 0; c < 12 * 7; ++c)
      m[21 * 12 + c] = c % 23 == 5 ? 0.25f * static_cast<float>(c) : 0.0f;                // 3: sparse
    for (size_t c = 0; c < 12 * 7; ++c) m[28 * 12 + c] = (c * c) % 11 < 4 ? 1.0f : 0.0f;  // 4: sparse, compressible
    format::EncodeOptions eo;
    eo.zstd = true;
    for (uint64_t i = 0; i < 5; ++i) {
      eo.sparse = i >= 3;
      ASSERT_TRUE(w->Put(0, i, test::AsBytes(test::ChunkValues(w->metadata().matrix(), m, i)), eo).ok());
    }
    std::vector<uint8_t> mk(35, 1);
    ASSERT_TRUE(w->Put(1, 0, format::ByteSpan(reinterpret_cast<const std::byte*>(mk.data()), mk.size())).ok());
    std::vector<int32_t> cv(48, 0);
    for (int i : {0, 1, 5, 16, 17, 21, 26, 33, 40, 47}) cv[i] = (i % 3 == 0 ? -1 : 1) * (1 + i % 5);
    format::EncodeOptions co;
    co.sparse = true;
    co.coded = true;
    co.coded_width = 4;
    ASSERT_TRUE(w->Put(2, 0, test::AsBytes(cv), co).ok());
    ASSERT_TRUE(w->Finish().ok());
    bytes_ = test::ReadFileBytes(good_);
    auto r = io::ContainerReader::Open(good_);
    ASSERT_TRUE(r.ok());
    int encodings[6] = {0, 0, 0, 0, 0, 0};
    for (const auto& e : r->chunk_frames()) encodings[e.header.encoding]++;
    for (int e = 0; e < 6; ++e) ASSERT_GT(encodings[e], 0) << format::EncodingName(static_cast<format::Encoding>(e));
  }

  test::TempDir dir_;
  std::string good_;
  std::vector<char> bytes_;
};

TEST_F(DamageSweep, EveryByteFlipIsReported) {
  io::VerifyReport r;
  Exercise(good_, &r);
  ASSERT_TRUE(r.complete);
  ASSERT_TRUE(r.problems.empty());
  std::string bad = dir_.File("bad.ltm");
  size_t undetected = 0;
  for (size_t i = 0; i < bytes_.size(); ++i) {
    auto b = bytes_;
    b[i] = static_cast<char>(b[i] ^ 0xFF);
    WriteBytes(bad, b, b.size());
    int64_t grew = Exercise(bad, &r);
    EXPECT_LE(grew, static_cast<int64_t>(b.size()) + kSmallConstant) << "flip at " << i;
    if (r.problems.empty()) {
      ++undetected;
      ADD_FAILURE() << "flip of byte " << i << " of " << bytes_.size() << " not reported (complete=" << r.complete
                    << ")";
    }
  }
  EXPECT_EQ(undetected, 0u);
}

TEST_F(DamageSweep, EveryTruncationIsReported) {
  std::string bad = dir_.File("short.ltm");
  io::VerifyReport r;
  for (size_t n = 0; n < bytes_.size(); ++n) {
    WriteBytes(bad, bytes_, n);
    int64_t grew = Exercise(bad, &r);
    EXPECT_LE(grew, static_cast<int64_t>(n) + kSmallConstant) << "truncated to " << n;
    // A truncated file is damaged or incomplete, never complete.
    EXPECT_FALSE(r.complete) << "truncated to " << n;
    EXPECT_TRUE(!r.problems.empty() || r.readable) << "truncated to " << n;
  }
}

// A sparse chunk whose payload (checksum intact) claims as many stored elements as the chunk
// has, in a few bytes: nothing may be sized by that count before the payload bears it out.
TEST(SparseCount, HostileCountIsNotAllocated) {
  test::TempDir dir;
  std::string path = dir.File("count.ltm");
  const uint64_t elements = uint64_t(1) << 22;
  format::ArraySpec s;
  s.name = "matrix";
  s.dtype = format::DType::kU8;
  s.rows = 1;
  s.cols = elements;
  s.layout = format::Layout::kCols;
  s.block = elements;
  {
    auto w = io::ContainerWriter::Open(path, {{"arrays", {s.ToJson()}}});
    ASSERT_TRUE(w.ok()) << w.status().message();
    format::EncodedChunk c;
    c.encoding = format::Encoding::kSparse;
    c.decoded_length = elements;
    c.dtype = format::DType::kU8;
    c.owned = {std::byte{0x80}, std::byte{0x80}, std::byte{0x80}, std::byte{0x02}, std::byte{0x00}};  // n = 2^22
    c.payload = c.owned;
    c.checksum = format::Checksum(c.payload);
    // With a content_hash sum given, the writer does not decode the (undecodable) payload.
    ASSERT_TRUE(w->Append(0, 0, c, 0).ok());
    ASSERT_TRUE(w->Finish().ok());
  }
  auto r = io::ContainerReader::Open(path);
  ASSERT_TRUE(r.ok()) << r.status().message();
  g_peak.store(g_live.load());
  int64_t base = g_live.load();
  auto sparse = r->ReadSparse(0, 0);
  EXPECT_EQ(sparse.status().code(), StatusCode::kDataLoss);
  EXPECT_NE(sparse.status().message().find("payload ends inside index 1 of 4194304"), std::string::npos)
      << sparse.status().message();
  auto v = io::VerifyContainer(path);
  ASSERT_FALSE(v.problems.empty());
  EXPECT_NE(v.problems[0].find("payload ends inside index 1 of 4194304"), std::string::npos) << v.problems[0];
  EXPECT_LE(g_peak.load() - base, kSmallConstant);
  // The dense read allocates the chunk the metadata describes (4 MiB), no more.
  g_peak.store(g_live.load());
  base = g_live.load();
  EXPECT_EQ(r->ReadChunk(0, 0).status().code(), StatusCode::kDataLoss);
  EXPECT_LE(g_peak.load() - base, static_cast<int64_t>(elements) + kSmallConstant);
}

}  // namespace
}  // namespace ltb
