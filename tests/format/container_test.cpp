// Container behaviour: round trips, layouts, encodings, resume, readers during writes,
// absent-is-not-zero, and content_hash independence from chunking and encoding.
#include <gtest/gtest.h>

#include <cstring>
#include <fstream>

#include "format/chunk_codec.h"
#include "format/content_hash.h"
#include "format/io/array_summary.h"
#include "format/io/container_reader.h"
#include "format/io/container_writer.h"
#include "format/io/verifier.h"
#include "format/layout.h"
#include "test_util.h"

namespace ltb {
namespace {

using format::Layout;
using test::TempDir;

std::vector<float> ReadAll(const io::ContainerReader& r) {
  const auto& a = r.metadata().matrix();
  std::vector<float> m(a.rows * a.cols, -7.0f);
  for (uint64_t i = 0; i < a.ChunkCount(); ++i) {
    auto c = r.ReadChunk(0, i);
    EXPECT_TRUE(c.ok()) << c.status().message();
    if (!c.ok()) continue;
    auto v = c->as<float>();
    const auto& e = c->extent();
    for (uint64_t rr = 0; rr < e.rows; ++rr)
      for (uint64_t cc = 0; cc < e.cols; ++cc)
        m[(e.row0 + rr) * a.cols + e.col0 + cc] = a.layout == Layout::kRows ? v[rr * e.cols + cc] : v[cc * e.rows + rr];
  }
  return m;
}

struct Shape {
  uint64_t rows, cols, block;
  Layout layout;
  bool zstd;
};

class RoundTrip : public ::testing::TestWithParam<Shape> {};

TEST_P(RoundTrip, ReadsBackBitExact) {
  Shape s = GetParam();
  TempDir dir;
  std::string path = dir.File("m.ltm");
  test::WriteMatrix(path, s.rows, s.cols, s.layout, s.block, 42, s.zstd);
  auto r = io::ContainerReader::Open(path);
  ASSERT_TRUE(r.ok()) << r.status().message();
  EXPECT_TRUE(r->sealed());
  EXPECT_TRUE(r->complete());
  EXPECT_TRUE(r->problems().empty());
  auto expected = test::MakeMatrix(s.rows, s.cols, 42);
  auto got = ReadAll(*r);
  ASSERT_EQ(got.size(), expected.size());
  EXPECT_EQ(0, std::memcmp(got.data(), expected.data(), got.size() * 4));
  auto v = io::VerifyContainer(path);
  EXPECT_TRUE(v.complete);
  EXPECT_TRUE(v.problems.empty()) << v.problems.front();
}

INSTANTIATE_TEST_SUITE_P(Shapes, RoundTrip,
                         ::testing::Values(Shape{1, 37, 1, Layout::kRows, false}, Shape{37, 1, 5, Layout::kRows, false},
                                           Shape{37, 1, 1, Layout::kCols, true}, Shape{1, 37, 8, Layout::kCols, false},
                                           Shape{50, 24, 7, Layout::kRows, true}, Shape{50, 24, 5, Layout::kCols, true},
                                           Shape{64, 96, 64, Layout::kRows, false}));

TEST(ContentHash, IndependentOfChunkingLayoutAndEncoding) {
  TempDir dir;
  std::vector<std::string> hashes;
  int k = 0;
  for (Shape s : {Shape{50, 24, 7, Layout::kRows, false}, Shape{50, 24, 50, Layout::kRows, true},
                  Shape{50, 24, 1, Layout::kCols, false}, Shape{50, 24, 5, Layout::kCols, true}}) {
    std::string path = dir.File("h" + std::to_string(k++) + ".ltm");
    test::WriteMatrix(path, s.rows, s.cols, s.layout, s.block, 9, s.zstd);
    auto r = io::ContainerReader::Open(path);
    ASSERT_TRUE(r.ok());
    auto sum = io::SummarizeArray(*r, 0, 2);
    ASSERT_TRUE(sum.ok()) << sum.status().message();
    hashes.push_back(sum->content_hash);
  }
  for (const auto& h : hashes) EXPECT_EQ(h, hashes.front());
  EXPECT_EQ(hashes.front().size(), 16u);
}

TEST(ContentHash, ChangesWithOneElementItsPositionAndTheShape) {
  format::ArraySpec a;
  a.name = "matrix";
  a.rows = 4;
  a.cols = 6;
  a.block = 4;
  std::vector<float> m(24, 0.0f);
  m[5] = 1.0f;
  auto hash = [&](const std::vector<float>& v, const format::ArraySpec& spec) {
    format::ContentHasher h;
    h.AddChunk(spec, spec.Extent(0), test::AsBytes(v));
    return h.Finish(spec);
  };
  std::string base = hash(m, a);
  auto moved = m;
  std::swap(moved[5], moved[6]);
  EXPECT_NE(base, hash(moved, a));
  auto negzero = m;
  negzero[0] = -0.0f;  // a different bit pattern is different content
  EXPECT_NE(base, hash(negzero, a));
  format::ArraySpec b = a;
  b.rows = 6;
  b.cols = 4;
  b.block = 6;
  EXPECT_NE(base, hash(m, b));
}

TEST(Container, MissingChunkIsReportedNotZero) {
  TempDir dir;
  std::string path = dir.File("partial.ltm");
  {
    auto w = io::ContainerWriter::Open(path, test::MatrixMetadata(10, 4, Layout::kRows, 2));
    ASSERT_TRUE(w.ok());
    std::vector<float> zeros(8, 0.0f);
    ASSERT_TRUE(w->Put(0, 0, test::AsBytes(zeros)).ok());
    ASSERT_TRUE(w->Put(0, 2, test::AsBytes(zeros)).ok());
    Status s = w->Finish();
    EXPECT_EQ(s.code(), StatusCode::kFailedPrecondition);
    EXPECT_NE(s.message().find("3 chunks missing (first: array \"matrix\" chunk 1)"), std::string::npos) << s.message();
  }
  auto r = io::ContainerReader::Open(path);
  ASSERT_TRUE(r.ok());
  EXPECT_FALSE(r->complete());
  EXPECT_FALSE(r->sealed());
  EXPECT_TRUE(r->ReadChunk(0, 0).ok());
  auto missing = r->ReadChunk(0, 1);
  EXPECT_EQ(missing.status().code(), StatusCode::kNotFound);
  EXPECT_NE(missing.status().message().find("chunk 1 (rows 2-3) is missing"), std::string::npos)
      << missing.status().message();
  auto sum = io::SummarizeArray(*r, 0, 1);
  ASSERT_TRUE(sum.ok());
  EXPECT_TRUE(sum->content_hash.empty());
  EXPECT_EQ(sum->chunks_missing, 3u);
}

TEST(Container, ResumeAppendsOnlyMissingChunks) {
  TempDir dir;
  std::string path = dir.File("resume.ltm");
  auto meta = test::MatrixMetadata(12, 3, Layout::kRows, 2);
  auto m = test::MakeMatrix(12, 3, 5);
  {
    auto w = io::ContainerWriter::Open(path, meta);
    ASSERT_TRUE(w.ok());
    for (uint64_t i : {0, 3, 4})
      ASSERT_TRUE(w->Put(0, i, test::AsBytes(test::ChunkValues(w->metadata().matrix(), m, i))).ok());
  }  // dropped without Finish: like a stopped writer
  auto w = io::ContainerWriter::Open(path, meta);
  ASSERT_TRUE(w.ok()) << w.status().message();
  EXPECT_TRUE(w->resume_info().resumed);
  EXPECT_EQ(w->resume_info().committed_chunks, 3u);
  EXPECT_EQ(w->Missing(0), (std::vector<uint64_t>{1, 2, 5}));
  for (uint64_t i : w->Missing(0))
    ASSERT_TRUE(w->Put(0, i, test::AsBytes(test::ChunkValues(w->metadata().matrix(), m, i))).ok());
  ASSERT_TRUE(w->Finish().ok());
  auto r = io::ContainerReader::Open(path);
  ASSERT_TRUE(r.ok());
  EXPECT_TRUE(r->complete());
  auto got = ReadAll(*r);
  EXPECT_EQ(0, std::memcmp(got.data(), m.data(), m.size() * 4));
  // Reopening a sealed file with the same metadata is a no-op.
  auto again = io::ContainerWriter::Open(path, meta);
  ASSERT_TRUE(again.ok());
  EXPECT_TRUE(again->resume_info().already_complete);
  EXPECT_TRUE(again->Missing(0).empty());
}

// A writer stopped after every possible number of file mutations (payload, padding, header,
// and each step of sealing) leaves a file that verifies without a problem, and resuming it
// yields the uninterrupted file byte for byte. Sixteen chunks put copies of chunk frame
// headers at 64-byte-aligned offsets inside the index payload, where a scanner would take
// them for frames if the payload were ever on disk without its own header.
TEST(Container, EveryInterruptedWriteAndSealVerifiesAndResumes) {
  TempDir dir;
  const uint64_t rows = 32, cols = 5, block = 2;
  auto meta = test::MatrixMetadata(rows, cols, Layout::kRows, block);
  auto m = test::MakeMatrix(rows, cols, 9);
  for (uint64_t r = 0; r < rows; r += 6) std::fill(m.begin() + r * cols, m.begin() + (r + 2) * cols, 0.0f);
  auto write = [&](const std::string& path, uint64_t stop_after) {
    io::WriterOptions o;
    o.stop_after_mutations = stop_after;
    auto w = io::ContainerWriter::Open(path, meta, o);
    if (!w.ok()) return w.status();
    for (uint64_t i : w->Missing(0)) {
      Status s = w->Put(0, i, test::AsBytes(test::ChunkValues(w->metadata().matrix(), m, i)));
      if (!s.ok()) return s;
    }
    return w->Finish();
  };
  std::string ref = dir.File("ref.ltm");
  ASSERT_TRUE(write(ref, UINT64_MAX).ok());
  std::vector<char> ref_bytes = test::ReadFileBytes(ref);
  ASSERT_EQ(io::ContainerReader::Open(ref)->metadata().matrix().ChunkCount(), 16u);
  int interrupted = 0;
  for (uint64_t stop = 0;; ++stop) {
    std::string path = dir.File("cut" + std::to_string(stop) + ".ltm");
    Status s = write(path, stop);
    if (s.ok()) break;  // `stop` exceeds the number of mutations of a whole write
    ++interrupted;
    // (Stopped only before the final fdatasync, the file is complete: the trailer is written.)
    test::ExpectInterruptedFileIntact(path, stop);
    if (::testing::Test::HasFatalFailure()) return;
    ASSERT_TRUE(write(path, UINT64_MAX).ok()) << "resume after " << stop;
    EXPECT_EQ(test::ReadFileBytes(path), ref_bytes)
        << "resume after " << stop << " differs from an uninterrupted write";
  }
  // 16 chunks, 2 of 3 padded (the zero ones have no payload) + 5 sealing steps.
  EXPECT_GE(interrupted, 16 + 5);
}

TEST(Container, RefusesToResumeWithOtherMetadata) {
  TempDir dir;
  std::string path = dir.File("other.ltm");
  test::WriteMatrix(path, 6, 4, Layout::kRows, 2, 1, false);
  auto meta = test::MatrixMetadata(6, 4, Layout::kRows, 3);
  auto w = io::ContainerWriter::Open(path, meta);
  EXPECT_EQ(w.status().code(), StatusCode::kFailedPrecondition);
  EXPECT_NE(w.status().message().find("\"arrays\""), std::string::npos) << w.status().message();
  EXPECT_NE(w.status().message().find("--overwrite"), std::string::npos);
  io::WriterOptions o;
  o.overwrite_mismatch = true;
  auto w2 = io::ContainerWriter::Open(path, meta, o);
  ASSERT_TRUE(w2.ok()) << w2.status().message();
  EXPECT_FALSE(w2->resume_info().resumed);
}

TEST(Container, RefusesToClobberAFileThatIsNotAContainer) {
  TempDir dir;
  std::string path = dir.File("notes.ltm");
  FILE* f = fopen(path.c_str(), "w");
  fputs("my precious notes\n", f);
  fclose(f);
  auto w = io::ContainerWriter::Open(path, test::MatrixMetadata(2, 2, Layout::kRows, 1));
  EXPECT_EQ(w.status().code(), StatusCode::kFailedPrecondition);
  EXPECT_NE(w.status().message().find("is not a readable .ltm container"), std::string::npos);
}

TEST(Container, ReaderSeesExactlyTheCommittedChunksWhileAWriterAppends) {
  TempDir dir;
  std::string path = dir.File("live.ltm");
  auto meta = test::MatrixMetadata(40, 16, Layout::kRows, 4);
  auto m = test::MakeMatrix(40, 16, 3);
  auto w = io::ContainerWriter::Open(path, meta);
  ASSERT_TRUE(w.ok());
  const auto& spec = w->metadata().matrix();
  for (uint64_t i = 0; i < spec.ChunkCount(); ++i) {
    auto r = io::ContainerReader::Open(path);
    ASSERT_TRUE(r.ok()) << r.status().message();
    EXPECT_EQ(r->committed(0), i);
    for (uint64_t j = 0; j < spec.ChunkCount(); ++j) {
      auto c = r->ReadChunk(0, j);
      EXPECT_EQ(c.ok(), j < i) << "chunk " << j << " after " << i << " commits";
    }
    ASSERT_TRUE(w->Put(0, i, test::AsBytes(test::ChunkValues(spec, m, i))).ok());
    ASSERT_TRUE(r->Refresh().ok());
    EXPECT_EQ(r->committed(0), i + 1);
  }
  ASSERT_TRUE(w->Finish().ok());
}

TEST(Container, AllZeroChunksCostNoPayload) {
  TempDir dir;
  std::string path = dir.File("zeros.ltm");
  auto w = io::ContainerWriter::Open(path, test::MatrixMetadata(1000, 256, Layout::kRows, 100));
  ASSERT_TRUE(w.ok());
  std::vector<float> zeros(100 * 256, 0.0f);
  for (uint64_t i = 0; i < 10; ++i) ASSERT_TRUE(w->Put(0, i, test::AsBytes(zeros)).ok());
  ASSERT_TRUE(w->Finish().ok());
  auto r = io::ContainerReader::Open(path);
  ASSERT_TRUE(r.ok());
  EXPECT_LT(r->file_size(), 4096u);  // 1 MB of zeros: header, metadata, 10 frame headers, index
  auto c = r->ReadChunk(0, 3);
  ASSERT_TRUE(c.ok());
  EXPECT_EQ(c->encoding(), format::Encoding::kZero);
  for (float x : c->as<float>()) ASSERT_EQ(x, 0.0f);
}

TEST(Container, RawChunksAreMappedAlignedWithoutCopy) {
  TempDir dir;
  std::string path = dir.File("aligned.ltm");
  test::WriteMatrix(path, 64, 33, Layout::kRows, 9, 4, false);
  auto r = io::ContainerReader::Open(path);
  ASSERT_TRUE(r.ok());
  for (const auto& e : r->chunk_frames()) EXPECT_EQ(e.frame_offset % format::kAlignment, 0u);
  auto c = r->ReadChunk(0, 0);
  ASSERT_TRUE(c.ok());
  ASSERT_EQ(c->encoding(), format::Encoding::kRaw);
  EXPECT_EQ(reinterpret_cast<uintptr_t>(c->bytes().data()) % format::kAlignment, 0u);
}

TEST(Container, SideTablesAreChunksToo) {
  TempDir dir;
  std::string path = dir.File("side.ltm");
  format::ArraySpec depth;
  depth.name = "depth";
  depth.dtype = format::DType::kU8;
  depth.rows = 24;
  depth.cols = 1;
  depth.block = 24;
  auto meta = test::MatrixMetadata(8, 24, Layout::kCols, 6);
  meta["arrays"].push_back(depth.ToJson());
  auto w = io::ContainerWriter::Open(path, meta);
  ASSERT_TRUE(w.ok()) << w.status().message();
  auto m = test::MakeMatrix(8, 24, 2);
  for (uint64_t i = 0; i < 4; ++i)
    ASSERT_TRUE(w->Put(0, i, test::AsBytes(test::ChunkValues(w->metadata().matrix(), m, i))).ok());
  EXPECT_EQ(w->Finish().code(), StatusCode::kFailedPrecondition);  // the depth table is missing
  std::vector<uint8_t> d(24);
  for (int i = 0; i < 24; ++i) d[i] = static_cast<uint8_t>(i % 5);
  ASSERT_TRUE(w->Put(1, 0, format::ByteSpan(reinterpret_cast<const std::byte*>(d.data()), d.size())).ok());
  ASSERT_TRUE(w->Finish().ok());
  auto r = io::ContainerReader::Open(path);
  ASSERT_TRUE(r.ok());
  EXPECT_EQ(r->metadata().FindArray("depth"), 1);
  auto c = r->ReadChunk(1, 0);
  ASSERT_TRUE(c.ok());
  EXPECT_EQ(0, std::memcmp(c->bytes().data(), d.data(), d.size()));
}

// The writer records every array's content_hash when it seals: whatever way the chunks
// came (Put raw, zstd or sparse; Append with the caller's sum or without one), the record
// equals what a reader computes from the decoded chunks, and verify agrees.
TEST(Container, WriterRecordsTheContentHashOfEveryArray) {
  TempDir dir;
  const std::string path = dir.File("hashed.ltm");
  format::ArraySpec m, side;
  m.name = "matrix";
  m.rows = 40;
  m.cols = 9;
  m.layout = Layout::kRows;
  m.block = 4;
  side.name = "side";
  side.dtype = format::DType::kU32;
  side.rows = 7;
  side.cols = 13;
  side.layout = Layout::kCols;
  side.block = 3;
  nlohmann::json meta = {{"arrays", {m.ToJson(), side.ToJson()}}};
  auto values = test::MakeMatrix(m.rows, m.cols, 4);
  for (size_t i = 0; i < values.size(); i += 3) values[i] = 0.0f;  // sparse enough for the sparse encodings
  std::vector<uint32_t> table(side.rows * side.cols);
  for (size_t i = 0; i < table.size(); ++i) table[i] = static_cast<uint32_t>(i * 2654435761u % 97);
  {
    auto w = io::ContainerWriter::Open(path, meta);
    ASSERT_TRUE(w.ok()) << w.status().message();
    for (uint64_t i = 0; i < m.ChunkCount(); ++i) {
      auto v = test::ChunkValues(m, values, i);
      format::EncodeOptions eo;
      eo.zstd = i % 2 == 0;
      eo.sparse = i % 3 == 0;
      if (i % 4 == 1) {
        // Encoded outside, appended without a sum: the writer decodes it to hash it.
        ASSERT_TRUE(w->Append(0, i, format::EncodeChunk(test::AsBytes(v), eo)).ok());
      } else {
        ASSERT_TRUE(w->Put(0, i, test::AsBytes(v), eo).ok());
      }
    }
    for (uint64_t i = 0; i < side.ChunkCount(); ++i) {
      auto v = test::ChunkValues(side, table, i);
      const auto sum = format::ChunkHashSum(side, side.Extent(i), test::AsBytes(v));
      ASSERT_TRUE(w->Append(1, i, format::EncodeChunk(test::AsBytes(v), {}), sum).ok());
    }
    ASSERT_TRUE(w->Finish().ok());
  }
  auto r = io::ContainerReader::Open(path);
  ASSERT_TRUE(r.ok()) << r.status().message();
  io::VerifyReport v = io::VerifyContainer(path, 2);
  EXPECT_TRUE(v.complete);
  EXPECT_TRUE(v.problems.empty()) << v.problems.front();
  for (uint32_t a = 0; a < 2; ++a) {
    auto s = io::SummarizeArray(*r, a, 1);
    ASSERT_TRUE(s.ok()) << s.status().message();
    EXPECT_FALSE(s->content_hash.empty());
    EXPECT_EQ(r->RecordedContentHash(a), s->content_hash) << "array " << a;
    EXPECT_EQ(r->RecordedHashSum(a), s->hash_sum) << "array " << a;
    EXPECT_EQ(v.content_hash.at(a), s->content_hash) << "array " << a;
    EXPECT_EQ(v.recorded_content_hash.at(a), s->content_hash) << "array " << a;
  }
}

// A record that does not match the chunks is a problem for verify (readers trust it, so
// verify is where a wrong one is caught); a damaged record is ignored by readers.
TEST(Container, VerifyRecomputesTheRecordedContentHash) {
  TempDir dir;
  const std::string path = dir.File("record.ltm");
  test::WriteMatrix(path, 12, 5, Layout::kRows, 4, 3, false);
  const std::string truth = test::HashOf(path);
  auto r = io::ContainerReader::Open(path);
  ASSERT_TRUE(r.ok());
  ASSERT_EQ(r->RecordedContentHash(0), truth);
  // The record sits just before the index frame, whose offset the trailer gives.
  std::vector<char> bytes = test::ReadFileBytes(path);
  uint64_t index_offset = 0;
  std::memcpy(&index_offset, bytes.data() + bytes.size() - 64 + 8, 8);
  const uint64_t at = index_offset - format::ContentHashFrameSize(1);
  auto rewrite = [&](const std::vector<char>& b) {
    std::ofstream(path, std::ios::binary | std::ios::trunc).write(b.data(), static_cast<std::streamsize>(b.size()));
  };
  // Gives the record frame in `b` a payload of `length` bytes under a valid checksum.
  auto reseal = [&](std::vector<char>& b, uint64_t length) {
    auto h = format::DecodeFrameHeader(format::ByteSpan(reinterpret_cast<const std::byte*>(b.data() + at), 64), at,
                                       b.size());
    if (!h.ok() || h->type != static_cast<uint16_t>(format::FrameType::kContentHash)) return false;
    h->payload_length = h->decoded_length = length;
    h->payload_checksum =
        format::Checksum(format::ByteSpan(reinterpret_cast<const std::byte*>(b.data() + at + 64), length));
    auto hb = format::EncodeFrameHeader(*h);
    std::memcpy(b.data() + at, hb.data(), hb.size());
    return true;
  };
  {
    // A wrong sum under a valid checksum.
    std::vector<char> b = bytes;
    b[at + 64 + 8] ^= 1;
    ASSERT_TRUE(reseal(b, 16));
    rewrite(b);
    auto wrong = io::ContainerReader::Open(path);
    ASSERT_TRUE(wrong.ok());
    EXPECT_NE(wrong->RecordedContentHash(0), truth);
    EXPECT_FALSE(wrong->RecordedContentHash(0).empty());
    io::VerifyReport v = io::VerifyContainer(path);
    EXPECT_FALSE(v.complete);
    ASSERT_EQ(v.problems.size(), 1u);
    EXPECT_NE(v.problems[0].find("recorded content_hash " + wrong->RecordedContentHash(0)), std::string::npos)
        << v.problems[0];
    EXPECT_NE(v.problems[0].find(truth), std::string::npos) << v.problems[0];
  }
  {
    // A record of the wrong size (valid checksum): refused by size, not read or allocated.
    std::vector<char> b = bytes;
    ASSERT_TRUE(reseal(b, 24));  // the frame's zero padding makes up the rest
    rewrite(b);
    auto odd = io::ContainerReader::Open(path);
    ASSERT_TRUE(odd.ok());
    EXPECT_EQ(odd->RecordedContentHash(0), "");
    io::VerifyReport v = io::VerifyContainer(path);
    ASSERT_FALSE(v.problems.empty());
    EXPECT_NE(v.problems[0].find("content-hash frame of 24 bytes; 1 arrays take 16"), std::string::npos)
        << v.problems[0];
  }
  {
    // A damaged record (checksum mismatch): readers fall back to reading the chunks.
    std::vector<char> b = bytes;
    b[at + 64 + 9] ^= 1;
    rewrite(b);
    auto damaged = io::ContainerReader::Open(path);
    ASSERT_TRUE(damaged.ok());
    EXPECT_EQ(damaged->RecordedContentHash(0), "");
    EXPECT_EQ(test::HashOf(path), truth);
    EXPECT_FALSE(io::VerifyContainer(path).problems.empty());
  }
}

}  // namespace
}  // namespace ltb
