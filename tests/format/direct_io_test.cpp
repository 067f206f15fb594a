// WriterOptions::direct_io: payloads written with O_DIRECT on 4096-byte boundaries behind
// padding frames. The logical content, the verification and the crash guarantees are those
// of an ordinary write; only the frame positions differ.
#include <gtest/gtest.h>

#include <cstdlib>
#include <cstring>

#include "format/io/array_summary.h"
#include "format/io/container_reader.h"
#include "format/io/container_writer.h"
#include "format/io/verifier.h"
#include "test_util.h"

namespace ltb {
namespace {

using format::Layout;
using test::TempDir;

// 49 rows of 1500 f32 (6000 bytes), 12 rows per chunk: chunks of 72,000 bytes (not a
// multiple of 4096: a buffered tail after the direct part) and a last one of 6,000 bytes
// (under the direct threshold). Chunk 1 is all zero (no payload), chunk 2 is passed in from
// a 4096-aligned buffer (no staging copy), the others from ordinary vectors.
constexpr uint64_t kRows = 49, kCols = 1500, kBlock = 12;

std::vector<float> Matrix() {
  auto m = test::MakeMatrix(kRows, kCols, 5);
  std::fill(m.begin() + kBlock * kCols, m.begin() + 2 * kBlock * kCols, 0.0f);
  return m;
}

Status WriteAll(const std::string& path, const io::WriterOptions& o, io::DirectIoStats* stats = nullptr) {
  auto meta = test::MatrixMetadata(kRows, kCols, Layout::kRows, kBlock);
  auto m = Matrix();
  auto w = io::ContainerWriter::Open(path, meta, o);
  if (!w.ok()) return w.status();
  for (uint64_t i : w->Missing(0)) {
    auto v = test::ChunkValues(w->metadata().matrix(), m, i);
    Status s;
    if (i == 2) {
      const size_t bytes = (v.size() * 4 + 4095) / 4096 * 4096;
      std::unique_ptr<float, decltype(&std::free)> aligned(static_cast<float*>(std::aligned_alloc(4096, bytes)),
                                                           &std::free);
      std::memcpy(aligned.get(), v.data(), v.size() * 4);
      s = w->Put(0, i, format::ByteSpan(reinterpret_cast<const std::byte*>(aligned.get()), v.size() * 4));
    } else {
      s = w->Put(0, i, test::AsBytes(v));
    }
    if (!s.ok()) return s;
  }
  if (stats != nullptr) *stats = w->direct_io_stats();
  return w->Finish();
}

TEST(DirectIo, SameContentAlignedPayloadsAndAPlainVerify) {
  TempDir dir;
  const std::string plain = dir.File("plain.ltm"), direct = dir.File("direct.ltm");
  ASSERT_TRUE(WriteAll(plain, {}).ok());
  io::WriterOptions o;
  o.direct_io = true;
  io::DirectIoStats st;
  Status s = WriteAll(direct, o, &st);
  ASSERT_TRUE(s.ok()) << s.message();
  if (!st.active) GTEST_SKIP() << "the temporary directory's file system refuses O_DIRECT: " << st.fallback_reason;

  // Chunks 0, 2 and 3 have 72,000 bytes: 17 whole 4096-byte blocks each went direct, each
  // behind a padding frame (a 72,000-byte payload does not end on a 4096-byte boundary).
  EXPECT_EQ(st.direct_bytes, 3u * (72000 / 4096) * 4096);
  EXPECT_EQ(st.padding_frames, 3u);
  EXPECT_LE(st.padding_bytes, 3u * 4096);

  auto r = io::ContainerReader::Open(direct);
  ASSERT_TRUE(r.ok()) << r.status().message();
  EXPECT_TRUE(r->complete());
  EXPECT_TRUE(r->problems().empty());
  for (const auto& e : r->chunk_frames()) {
    if (e.header.payload_length >= o.direct_min_bytes) {
      EXPECT_EQ((e.frame_offset + format::kFrameHeaderSize) % 4096, 0u) << "chunk " << e.header.chunk_index;
    }
  }
  // Element for element what was put, and the same content_hash as the ordinary write.
  auto m = Matrix();
  const auto& spec = r->metadata().matrix();
  for (uint64_t i = 0; i < spec.ChunkCount(); ++i) {
    auto c = r->ReadChunk(0, i);
    ASSERT_TRUE(c.ok()) << c.status().message();
    auto want = test::ChunkValues(spec, m, i);
    ASSERT_EQ(c->as<float>().size(), want.size());
    EXPECT_EQ(0, std::memcmp(c->as<float>().data(), want.data(), want.size() * 4)) << "chunk " << i;
  }
  EXPECT_EQ(test::HashOf(direct), test::HashOf(plain));
  EXPECT_NE(test::ReadFileBytes(direct).size(), test::ReadFileBytes(plain).size());  // the padding frames

  // Padding frames are known: verify reports neither problems nor notes.
  io::VerifyReport v = io::VerifyContainer(direct);
  EXPECT_TRUE(v.complete);
  EXPECT_TRUE(v.problems.empty()) << v.problems.front();
  EXPECT_TRUE(v.notes.empty()) << v.notes.front();
  EXPECT_EQ(v.chunks_ok, spec.ChunkCount());
}

// As Container.EveryInterruptedWriteAndSealVerifiesAndResumes, with direct writes: every
// stop (padding extension, padding header, direct payload, buffered tail, header, seal)
// leaves a file that verifies, and resuming with direct_io gives the uninterrupted file
// byte for byte; resuming with ordinary writes gives the same content.
TEST(DirectIo, EveryInterruptedWriteVerifiesAndResumes) {
  TempDir dir;
  io::WriterOptions o;
  o.direct_io = true;
  const std::string ref = dir.File("ref.ltm");
  io::DirectIoStats st;
  ASSERT_TRUE(WriteAll(ref, o, &st).ok());
  if (!st.active) GTEST_SKIP() << "the temporary directory's file system refuses O_DIRECT: " << st.fallback_reason;
  const std::vector<char> ref_bytes = test::ReadFileBytes(ref);
  const std::string ref_hash = test::HashOf(ref);
  int interrupted = 0;
  for (uint64_t stop = 0;; ++stop) {
    const std::string path = dir.File("cut" + std::to_string(stop) + ".ltm");
    io::WriterOptions cut = o;
    cut.stop_after_mutations = stop;
    if (WriteAll(path, cut).ok()) break;
    ++interrupted;
    test::ExpectInterruptedFileIntact(path, stop);
    if (::testing::Test::HasFatalFailure()) return;
    // Half the cuts resume with ordinary writes (a rerun without direct I/O).
    const std::string copy = dir.File("copy" + std::to_string(stop) + ".ltm");
    std::filesystem::copy_file(path, copy);
    ASSERT_TRUE(WriteAll(path, o).ok()) << "resume after " << stop;
    EXPECT_EQ(test::ReadFileBytes(path), ref_bytes)
        << "resume after " << stop << " differs from an uninterrupted write";
    ASSERT_TRUE(WriteAll(copy, {}).ok()) << "buffered resume after " << stop;
    EXPECT_EQ(test::HashOf(copy), ref_hash) << "buffered resume after " << stop;
    EXPECT_TRUE(io::VerifyContainer(copy).problems.empty()) << "buffered resume after " << stop;
  }
  // 3 direct chunks (padding extension and header, direct part, buffered tail, header), the
  // zero chunk's header, the small chunk's payload, padding and header, and 5 sealing steps.
  EXPECT_GE(interrupted, 3 * 4 + 1 + 3 + 5);
}

TEST(DirectIo, ReaderSeesExactlyTheCommittedChunksWhileAWriterAppends) {
  TempDir dir;
  const std::string path = dir.File("live.ltm");
  io::WriterOptions o;
  o.direct_io = true;
  o.direct_min_bytes = 4096;
  auto meta = test::MatrixMetadata(40, 2048, Layout::kRows, 4);  // 32 KiB chunks
  auto m = test::MakeMatrix(40, 2048, 3);
  auto w = io::ContainerWriter::Open(path, meta, o);
  ASSERT_TRUE(w.ok());
  const auto& spec = w->metadata().matrix();
  for (uint64_t i = 0; i < spec.ChunkCount(); ++i) {
    auto r = io::ContainerReader::Open(path);
    ASSERT_TRUE(r.ok()) << r.status().message();
    EXPECT_EQ(r->committed(0), i);
    EXPECT_TRUE(r->problems().empty());
    for (uint64_t j = 0; j < i; ++j) {
      auto c = r->ReadChunk(0, j);
      ASSERT_TRUE(c.ok()) << c.status().message();
      auto want = test::ChunkValues(spec, m, j);
      EXPECT_EQ(0, std::memcmp(c->as<float>().data(), want.data(), want.size() * 4)) << "chunk " << j;
    }
    ASSERT_TRUE(w->Put(0, i, test::AsBytes(test::ChunkValues(spec, m, i))).ok());
  }
  ASSERT_TRUE(w->Finish().ok());
  EXPECT_TRUE(io::VerifyContainer(path).problems.empty());
}

}  // namespace
}  // namespace ltb
