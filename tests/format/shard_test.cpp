// Shard files (format/array_spec.h ShardChunkRange, ShardMetadataJson, Metadata::Owns) and
// the writer, reader and verifier on them; stage manifests (format/io/manifest.h) joining
// shards into the one matrix, and refusing shards that do not fit.
#include <gtest/gtest.h>

#include <cstring>
#include <filesystem>
#include <fstream>

#include "format/io/array_summary.h"
#include "format/io/container_reader.h"
#include "format/io/container_writer.h"
#include "format/io/manifest.h"
#include "format/io/verifier.h"
#include "format/json_text.h"
#include "test_util.h"

namespace ltb {
namespace {

using format::Layout;
using test::TempDir;

// The properties every (C, n) must have: shard i owns [b_i, e_i); b_0 = 0, e_{n-1} = C,
// e_i = b_{i+1} (contiguous, a partition), and the sizes differ by at most one.
std::pair<uint64_t, uint64_t> Range(uint64_t b, uint64_t e) { return {b, e}; }

void ExpectPartition(uint64_t chunks, uint64_t n) {
  SCOPED_TRACE("C = " + std::to_string(chunks) + ", n = " + std::to_string(n));
  uint64_t next = 0, smallest = UINT64_MAX, largest = 0;
  for (uint64_t i = 0; i < n; ++i) {
    auto [b, e] = format::ShardChunkRange(chunks, i, n);
    ASSERT_EQ(b, next) << "shard " << i << " does not start where shard " << i - 1 << " ends";
    ASSERT_LE(b, e) << "shard " << i;
    ASSERT_LE(e, chunks) << "shard " << i;
    smallest = std::min(smallest, e - b);
    largest = std::max(largest, e - b);
    next = e;
  }
  EXPECT_EQ(next, chunks) << "the shards do not cover every chunk";
  EXPECT_LE(largest - smallest, 1u) << "unbalanced shards";
  EXPECT_EQ(smallest, chunks / n);
}

TEST(ShardChunkRange, PartitionsEveryArrayForManyChunkAndShardCounts) {
  for (uint64_t c = 0; c <= 70; ++c)
    for (uint64_t n = 1; n <= 80; ++n) ExpectPartition(c, n);
  // n > C: some shards own nothing, never a chunk twice.
  ExpectPartition(0, format::kMaxShards);
  ExpectPartition(3, format::kMaxShards);
  ExpectPartition(format::kMaxShards - 1, format::kMaxShards);
  ExpectPartition(format::kMaxShards + 1, format::kMaxShards);
  // Large chunk counts: the products stay exact (no 64-bit overflow of C * i).
  ExpectPartition(format::kMaxDim, 7);
  ExpectPartition(format::kMaxDim, format::kMaxShards);
  ExpectPartition(UINT64_MAX / 3, 1000);
  ExpectPartition(UINT64_MAX, 13);
}

TEST(ShardChunkRange, NoChunksOwnsNothingAndOneShardOwnsAll) {
  for (uint64_t n : {1ull, 2ull, 5ull, 65536ull})
    for (uint64_t i = 0; i < n; i += 1 + n / 7) EXPECT_EQ(format::ShardChunkRange(0, i, n), Range(0ull, 0ull));
  for (uint64_t c : {0ull, 1ull, 9ull, 1ull << 40}) EXPECT_EQ(format::ShardChunkRange(c, 0, 1), Range(0ull, c));
  // Shards of 2 chunks among 5: 0 and 1 own nothing, the chunks go to 2 and 4.
  EXPECT_EQ(format::ShardChunkRange(2, 0, 5), Range(0ull, 0ull));
  EXPECT_EQ(format::ShardChunkRange(2, 2, 5), Range(0ull, 1ull));
  EXPECT_EQ(format::ShardChunkRange(2, 3, 5), Range(1ull, 1ull));
  EXPECT_EQ(format::ShardChunkRange(2, 4, 5), Range(1ull, 2ull));
}

// Two arrays of different chunk counts (10 row blocks, a side table of 3 chunks).
nlohmann::json TwoArrays() {
  nlohmann::json j = test::MatrixMetadata(50, 4, Layout::kRows, 5);
  format::ArraySpec side;
  side.name = "side";
  side.rows = 3;
  side.cols = 2;
  side.layout = Layout::kRows;
  side.block = 1;
  j["arrays"].push_back(side.ToJson());
  return j;
}

// Given bounds (a stage balancing its shards, as sample does by geometry rows) set the ranges
// of every array with bounds.back() chunks; the others keep the even split; bounds that are not
// count + 1 non-decreasing indices from 0 are refused.
TEST(ShardMetadata, GivenBoundsSetTheRangesOfArraysOfThatManyChunks) {
  const std::vector<uint64_t> bounds = {0, 0, 7, 10};  // 10 chunks of the matrix: 0, 7 and 3 chunks
  for (uint64_t i = 0; i < 3; ++i) {
    auto j = format::ShardMetadataJson(TwoArrays(), i, 3, &bounds);
    ASSERT_TRUE(j.ok()) << j.status().message();
    auto m = format::MetadataFromJson(*j);
    ASSERT_TRUE(m.ok()) << m.status().message();
    EXPECT_EQ(m->shard->chunks[0], std::make_pair(bounds[i], bounds[i + 1]));
    EXPECT_EQ(m->shard->chunks[1], format::ShardChunkRange(3, i, 3));  // 3 chunks: not the bounds' array
  }
  for (const std::vector<uint64_t>& bad :
       {std::vector<uint64_t>{0, 7, 10}, std::vector<uint64_t>{1, 2, 7, 10}, std::vector<uint64_t>{0, 8, 7, 10}}) {
    EXPECT_FALSE(format::ShardMetadataJson(TwoArrays(), 0, 3, &bad).ok());
  }
}

TEST(ShardMetadata, RangesPerArrayOwnsAndOwnedChunks) {
  for (uint64_t n : {1ull, 2ull, 3ull, 7ull, 11ull}) {
    uint64_t owned0 = 0, owned1 = 0;
    for (uint64_t i = 0; i < n; ++i) {
      auto j = format::ShardMetadataJson(TwoArrays(), i, n);
      ASSERT_TRUE(j.ok()) << j.status().message();
      auto m = format::MetadataFromJson(*j);
      ASSERT_TRUE(m.ok()) << m.status().message();
      ASSERT_TRUE(m->shard.has_value());
      EXPECT_EQ(m->shard->index, i);
      EXPECT_EQ(m->shard->count, n);
      ASSERT_EQ(m->shard->chunks.size(), 2u);
      EXPECT_EQ(m->shard->chunks[0], format::ShardChunkRange(10, i, n));
      EXPECT_EQ(m->shard->chunks[1], format::ShardChunkRange(3, i, n));
      for (uint32_t a = 0; a < 2; ++a) {
        uint64_t count = 0;
        for (uint64_t c = 0; c < m->arrays[a].ChunkCount() + 2; ++c) {
          bool in = c >= m->shard->chunks[a].first && c < m->shard->chunks[a].second;
          EXPECT_EQ(m->Owns(a, c), in) << "array " << a << " chunk " << c;
          count += m->Owns(a, c);
        }
        EXPECT_EQ(m->OwnedChunks(a), count);
      }
      owned0 += m->OwnedChunks(0);
      owned1 += m->OwnedChunks(1);
      // Resharding a shard's metadata replaces its "shard" key, it does not nest.
      auto again = format::ShardMetadataJson(*j, 0, 1);
      ASSERT_TRUE(again.ok());
      EXPECT_EQ((*again)["shard"]["count"], 1);
    }
    EXPECT_EQ(owned0, 10u);
    EXPECT_EQ(owned1, 3u);
  }
  auto whole = format::MetadataFromJson(TwoArrays());
  ASSERT_TRUE(whole.ok());
  EXPECT_FALSE(whole->shard.has_value());
  EXPECT_TRUE(whole->Owns(0, 9));
  EXPECT_FALSE(whole->Owns(0, 10));
  EXPECT_EQ(whole->OwnedChunks(0), 10u);
  EXPECT_EQ(whole->OwnedChunks(1), 3u);
}

TEST(ShardMetadata, RefusesBadShardNumbersAndRanges) {
  EXPECT_FALSE(format::ShardMetadataJson(TwoArrays(), 3, 3).ok());
  EXPECT_FALSE(format::ShardMetadataJson(TwoArrays(), 0, 0).ok());
  EXPECT_FALSE(format::ShardMetadataJson(TwoArrays(), 0, format::kMaxShards + 1).ok());
  EXPECT_TRUE(format::ShardMetadataJson(TwoArrays(), format::kMaxShards - 1, format::kMaxShards).ok());
  auto good = format::ShardMetadataJson(TwoArrays(), 1, 3);
  ASSERT_TRUE(good.ok());
  auto with = [&](auto edit) {
    nlohmann::json j = *good;
    edit(j["shard"]);
    return format::MetadataFromJson(j);
  };
  EXPECT_TRUE(with([](nlohmann::json&) {}).ok());
  EXPECT_FALSE(with([](nlohmann::json& s) { s["index"] = 3; }).ok());
  EXPECT_FALSE(with([](nlohmann::json& s) { s["count"] = 0; }).ok());
  EXPECT_FALSE(with([](nlohmann::json& s) { s["count"] = format::kMaxShards + 1; }).ok());
  EXPECT_FALSE(with([](nlohmann::json& s) { s["chunks"][0] = {5, 4}; }).ok());   // begin > end
  EXPECT_FALSE(with([](nlohmann::json& s) { s["chunks"][0] = {5, 11}; }).ok());  // past the 10 chunks
  EXPECT_FALSE(with([](nlohmann::json& s) { s["chunks"][1] = {0}; }).ok());      // not [b, e]
  EXPECT_FALSE(with([](nlohmann::json& s) { s["chunks"].erase(1); }).ok());      // one range for two arrays
  EXPECT_FALSE(with([](nlohmann::json& s) { s["chunks"][0] = {-1, 2}; }).ok());
  EXPECT_FALSE(with([](nlohmann::json& s) { s.erase("chunks"); }).ok());
  EXPECT_FALSE(with([](nlohmann::json& s) { s = 3; }).ok());
}

// Writes the chunks `which` of MakeMatrix(50, 4, seed) (row blocks of 5: 10 chunks).
Status PutChunks(io::ContainerWriter& w, const std::vector<uint64_t>& which, uint32_t seed = 42) {
  auto m = test::MakeMatrix(50, 4, seed);
  for (uint64_t c : which) {
    auto v = test::ChunkValues(w.metadata().matrix(), m, c);
    Status s = w.Put(0, c, test::AsBytes(v));
    if (!s.ok()) return s;
  }
  return Status::Ok();
}

nlohmann::json ShardMeta(uint64_t index, uint64_t count) {
  auto j = format::ShardMetadataJson(test::MatrixMetadata(50, 4, Layout::kRows, 5), index, count);
  EXPECT_TRUE(j.ok()) << j.status().message();
  return *j;
}

TEST(ShardWriter, RefusesChunksItDoesNotOwnAndSealsWithItsOwn) {
  TempDir dir;
  const std::string path = dir.File("s1.ltm");
  {
    auto w = io::ContainerWriter::Open(path, ShardMeta(1, 3));  // owns chunks [3, 6)
    ASSERT_TRUE(w.ok()) << w.status().message();
    EXPECT_EQ(w->Missing(0), (std::vector<uint64_t>{3, 4, 5}));
    for (uint64_t c : {0ull, 2ull, 6ull, 9ull}) {
      Status s = PutChunks(*w, {c});
      EXPECT_EQ(s.code(), StatusCode::kInvalidArgument) << "chunk " << c << ": " << s.message();
      EXPECT_NE(s.message().find("does not belong to shard 1 of 3"), std::string::npos) << s.message();
      EXPECT_FALSE(w->Has(0, c));
    }
    ASSERT_TRUE(PutChunks(*w, {4}).ok());
    EXPECT_EQ(w->Missing(0), (std::vector<uint64_t>{3, 5}));
    Status early = w->Finish();
    EXPECT_EQ(early.code(), StatusCode::kFailedPrecondition) << early.message();
    EXPECT_NE(early.message().find("2 chunks missing (first: array \"matrix\" chunk 3)"), std::string::npos)
        << early.message();
  }
  {  // resumes with the same shard metadata, keeping chunk 4
    auto w = io::ContainerWriter::Open(path, ShardMeta(1, 3));
    ASSERT_TRUE(w.ok()) << w.status().message();
    EXPECT_TRUE(w->resume_info().resumed);
    EXPECT_EQ(w->resume_info().committed_chunks, 1u);
    ASSERT_TRUE(PutChunks(*w, {3, 5}).ok());
    EXPECT_TRUE(w->Missing(0).empty());
    Status s = w->Finish();
    ASSERT_TRUE(s.ok()) << s.message();
  }
  auto r = io::ContainerReader::Open(path);
  ASSERT_TRUE(r.ok()) << r.status().message();
  EXPECT_FALSE(r->is_manifest());
  EXPECT_TRUE(r->sealed());
  EXPECT_TRUE(r->complete()) << "a shard with all the chunks it owns is complete";
  EXPECT_TRUE(r->problems().empty()) << r->problems().front();
  EXPECT_EQ(r->committed(0), 3u);
  auto m = test::MakeMatrix(50, 4, 42);
  for (uint64_t c = 0; c < 10; ++c) {
    auto chunk = r->ReadChunk(0, c);
    if (c >= 3 && c < 6) {
      ASSERT_TRUE(chunk.ok()) << chunk.status().message();
      auto want = test::ChunkValues(r->metadata().matrix(), m, c);
      ASSERT_EQ(chunk->as<float>().size(), want.size());
      EXPECT_EQ(0, std::memcmp(chunk->as<float>().data(), want.data(), want.size() * 4));
    } else {
      EXPECT_EQ(chunk.status().code(), StatusCode::kNotFound) << "chunk " << c << " of another shard read as data";
    }
  }
  auto v = io::VerifyContainer(path);
  EXPECT_TRUE(v.complete);
  EXPECT_TRUE(v.problems.empty()) << v.problems.front();
  EXPECT_EQ(v.chunks_expected, 3u);
  EXPECT_EQ(v.chunks_ok, 3u);
  // The file of shard 1 is not shard 2's: another shard's metadata does not resume it.
  auto other = io::ContainerWriter::Open(path, ShardMeta(2, 3));
  EXPECT_FALSE(other.ok());
  // Resuming a sealed complete shard appends nothing and leaves it byte-identical.
  auto before = test::ReadFileBytes(path);
  {
    auto w = io::ContainerWriter::Open(path, ShardMeta(1, 3));
    ASSERT_TRUE(w.ok()) << w.status().message();
    EXPECT_TRUE(w->resume_info().already_complete);
    EXPECT_TRUE(w->Missing(0).empty());
    EXPECT_TRUE(w->Finish().ok());
  }
  EXPECT_EQ(test::ReadFileBytes(path), before);
}

TEST(ShardWriter, AShardThatOwnsNothingSealsEmptyAndIsComplete) {
  TempDir dir;
  // 10 chunks among 20 shards: shard 0 owns [0, 0).
  const std::string path = dir.File("empty.ltm");
  {
    auto w = io::ContainerWriter::Open(path, ShardMeta(0, 20));
    ASSERT_TRUE(w.ok()) << w.status().message();
    EXPECT_TRUE(w->Missing(0).empty());
    EXPECT_FALSE(PutChunks(*w, {0}).ok());
    Status s = w->Finish();
    ASSERT_TRUE(s.ok()) << s.message();
  }
  auto r = io::ContainerReader::Open(path);
  ASSERT_TRUE(r.ok()) << r.status().message();
  EXPECT_TRUE(r->sealed());
  EXPECT_TRUE(r->complete());
  EXPECT_EQ(r->committed(0), 0u);
  auto v = io::VerifyContainer(path);
  EXPECT_TRUE(v.complete);
  EXPECT_EQ(v.chunks_expected, 0u);
}

TEST(ShardWriter, AnUnshardedWriterStillNeedsEveryChunk) {
  TempDir dir;
  const std::string path = dir.File("whole.ltm");
  auto w = io::ContainerWriter::Open(path, test::MatrixMetadata(50, 4, Layout::kRows, 5));
  ASSERT_TRUE(w.ok());
  ASSERT_TRUE(PutChunks(*w, {0, 1, 2, 3, 4, 5, 6, 7, 8}).ok());
  EXPECT_FALSE(w->Finish().ok());
  ASSERT_TRUE(PutChunks(*w, {9}).ok());
  EXPECT_TRUE(w->Finish().ok());
}

// Writes all n shards of OUT through OpenStageOutput, as a stage would.
void WriteShards(const std::string& out, uint64_t n, uint32_t seed = 42) {
  for (uint64_t i = 0; i < n; ++i) {
    auto w = io::OpenStageOutput(out, test::MatrixMetadata(50, 4, Layout::kRows, 5), {}, io::ShardSpec{i, n});
    ASSERT_TRUE(w.ok()) << w.status().message();
    EXPECT_EQ(w->path(), io::ShardPath(out, i, n));
    ASSERT_TRUE(PutChunks(*w, w->Missing(0), seed).ok());
    Status s = w->Finish();
    ASSERT_TRUE(s.ok()) << s.message();
  }
}

using test::HashOf;

TEST(ShardPath, NamesTheShardDirectoryAndPadsTheNumbers) {
  EXPECT_EQ(io::ShardPath("d/rows.ltm", 2, 4), "d/rows.shards/00002-of-00004.ltm");
  EXPECT_EQ(io::ShardPath("rows.ltm", 0, 65536), "rows.shards/00000-of-65536.ltm");
  EXPECT_EQ(io::ShardDirectory("a/b/cols4d.ltm"), "a/b/cols4d.shards");
}

TEST(Manifest, CommittedShardsReadAsTheWholeMatrix) {
  TempDir dir;
  const std::string whole = dir.File("whole.ltm");
  test::WriteMatrix(whole, 50, 4, Layout::kRows, 5, 42, false);
  const std::string want = HashOf(whole);
  ASSERT_EQ(want.size(), 16u);
  for (uint64_t n : {2ull, 3ull, 7ull, 10ull, 13ull}) {  // n = 1 writes OUT itself, no shards
    SCOPED_TRACE("n = " + std::to_string(n));
    const std::string out = dir.File("m" + std::to_string(n) + ".ltm");
    WriteShards(out, n);
    auto c = io::CommitShards(out, n);
    ASSERT_TRUE(c.ok()) << c.status().message();
    EXPECT_EQ(c->content_hash, want);
    EXPECT_TRUE(io::LooksLikeManifest(out));
    auto r = io::ContainerReader::Open(out);
    ASSERT_TRUE(r.ok()) << r.status().message();
    EXPECT_TRUE(r->is_manifest());
    EXPECT_TRUE(r->complete());
    EXPECT_EQ(r->shards().size(), n);
    EXPECT_FALSE(r->metadata().shard.has_value());
    EXPECT_EQ(HashOf(out), want);
    auto m = test::MakeMatrix(50, 4, 42);
    for (uint64_t k = 0; k < 10; ++k) {
      auto chunk = r->ReadChunk(0, k);
      ASSERT_TRUE(chunk.ok()) << chunk.status().message();
      auto v = test::ChunkValues(r->metadata().matrix(), m, k);
      EXPECT_EQ(0, std::memcmp(chunk->as<float>().data(), v.data(), v.size() * 4)) << "chunk " << k;
    }
    auto v = io::VerifyContainer(out);
    EXPECT_TRUE(v.complete) << (v.problems.empty() ? "" : v.problems.front());
    const std::string merged = dir.File("merged" + std::to_string(n) + ".ltm");
    auto mr = io::MergeManifest(out, merged, false);
    ASSERT_TRUE(mr.ok()) << mr.status().message();
    EXPECT_EQ(mr->chunks, 10u);
    EXPECT_FALSE(io::LooksLikeManifest(merged));
    EXPECT_EQ(HashOf(merged), want);
    auto mv = io::VerifyContainer(merged);
    EXPECT_TRUE(mv.complete);
  }
}

TEST(Manifest, CommitRefusesMissingForeignAndMismatchedShards) {
  TempDir dir;
  const std::string out = dir.File("m.ltm");
  WriteShards(out, 3);
  std::filesystem::remove(io::ShardPath(out, 1, 3));
  auto c = io::CommitShards(out, 3);
  ASSERT_FALSE(c.ok());
  EXPECT_EQ(c.status().code(), StatusCode::kNotFound);
  EXPECT_NE(c.status().message().find("1 of 3 shards missing (shard 1;"), std::string::npos) << c.status().message();
  EXPECT_FALSE(std::filesystem::exists(out)) << "a failed commit wrote the manifest";

  // Shard 1 of another matrix (other values): commits (values are not metadata), but a
  // shard with other metadata does not.
  {
    auto meta = test::MatrixMetadata(50, 4, Layout::kRows, 5);
    meta["note"] = "other parameters";
    auto w = io::OpenStageOutput(out, meta, {}, io::ShardSpec{1, 3});
    ASSERT_TRUE(w.ok()) << w.status().message();
    ASSERT_TRUE(PutChunks(*w, w->Missing(0)).ok());
    ASSERT_TRUE(w->Finish().ok());
  }
  c = io::CommitShards(out, 3);
  ASSERT_FALSE(c.ok());
  EXPECT_NE(c.status().message().find("shard 1 of 3"), std::string::npos) << c.status().message();
  EXPECT_NE(c.status().message().find("note"), std::string::npos) << c.status().message();
  EXPECT_FALSE(std::filesystem::exists(out));

  // An incomplete shard.
  std::filesystem::remove(io::ShardPath(out, 1, 3));
  {
    auto w = io::OpenStageOutput(out, test::MatrixMetadata(50, 4, Layout::kRows, 5), {}, io::ShardSpec{1, 3});
    ASSERT_TRUE(w.ok());
    ASSERT_TRUE(PutChunks(*w, {w->Missing(0).front()}).ok());
  }
  c = io::CommitShards(out, 3);
  ASSERT_FALSE(c.ok());
  EXPECT_NE(c.status().message().find("incomplete"), std::string::npos) << c.status().message();

  // Shard 2's file in shard 1's place.
  std::filesystem::copy_file(io::ShardPath(out, 2, 3), io::ShardPath(out, 1, 3),
                             std::filesystem::copy_options::overwrite_existing);
  c = io::CommitShards(out, 3);
  ASSERT_FALSE(c.ok());
  EXPECT_NE(c.status().message().find("says it is shard 2 of 3"), std::string::npos) << c.status().message();
  EXPECT_FALSE(std::filesystem::exists(out));

  // An existing container at OUT is not replaced without overwrite.
  std::filesystem::remove(io::ShardPath(out, 1, 3));
  WriteShards(out, 3);
  test::WriteMatrix(out, 50, 4, Layout::kRows, 5, 42, false);
  auto before = test::ReadFileBytes(out);
  c = io::CommitShards(out, 3);
  ASSERT_FALSE(c.ok());
  EXPECT_EQ(test::ReadFileBytes(out), before);
  io::CommitOptions o;
  o.overwrite = true;
  c = io::CommitShards(out, 3, o);
  ASSERT_TRUE(c.ok()) << c.status().message();
  EXPECT_TRUE(io::LooksLikeManifest(out));
}

TEST(Manifest, ReaderRefusesShardsChangedAfterTheCommit) {
  TempDir dir;
  const std::string out = dir.File("m.ltm");
  WriteShards(out, 3);
  ASSERT_TRUE(io::CommitShards(out, 3).ok());
  const std::string s1 = io::ShardPath(out, 1, 3);
  const auto original = test::ReadFileBytes(s1);
  auto restore = [&] {
    std::ofstream f(s1, std::ios::binary | std::ios::trunc);
    f.write(original.data(), static_cast<std::streamsize>(original.size()));
  };
  auto expect_refused = [&](const std::string& what, const std::string& says) {
    SCOPED_TRACE(what);
    auto r = io::ContainerReader::Open(out);
    ASSERT_FALSE(r.ok());
    EXPECT_NE(r.status().message().find("shard 1 of 3 (" + s1 + ")"), std::string::npos) << r.status().message();
    EXPECT_NE(r.status().message().find(says), std::string::npos) << r.status().message();
    auto v = io::VerifyContainer(out);
    EXPECT_FALSE(v.complete);
    ASSERT_FALSE(v.problems.empty());
    restore();
    EXPECT_TRUE(io::ContainerReader::Open(out).ok()) << what << ": restoring the shard did not repair";
  };
  std::filesystem::remove(s1);
  expect_refused("missing", "is missing");
  // Same size and metadata, other values: the fingerprint changes.
  std::filesystem::remove(s1);
  {
    auto w = io::OpenStageOutput(out, test::MatrixMetadata(50, 4, Layout::kRows, 5), {}, io::ShardSpec{1, 3});
    ASSERT_TRUE(w.ok());
    ASSERT_TRUE(PutChunks(*w, w->Missing(0), /*seed=*/43).ok());
    ASSERT_TRUE(w->Finish().ok());
  }
  ASSERT_EQ(std::filesystem::file_size(s1), original.size());
  expect_refused("rewritten with other values", "fingerprint");
  std::filesystem::resize_file(s1, original.size() - 10);
  expect_refused("truncated", "");
  std::filesystem::copy_file(io::ShardPath(out, 2, 3), s1, std::filesystem::copy_options::overwrite_existing);
  expect_refused("shard 2's file", "says it is shard 2 of 3");
}

// A manifest listing itself, or two manifests listing each other, as a shard: an error
// naming the shard, not an endless recursion (a stack overflow before the fix).
TEST(Manifest, AManifestAsAShardIsRefusedNotRecursedInto) {
  TempDir dir;
  const std::string out = dir.File("m.ltm");
  WriteShards(out, 2);
  ASSERT_TRUE(io::CommitShards(out, 2).ok());
  auto text = test::ReadFileBytes(out);
  std::string s(text.begin(), text.end());
  const size_t nl = s.find('\n');
  nlohmann::json j = *ParseJson(s.substr(nl + 1));
  auto write = [&](const std::string& path, const std::string& shard1) {
    j["shards"][1]["path"] = shard1;
    std::ofstream f(path, std::ios::binary | std::ios::trunc);
    f << s.substr(0, nl + 1) << JsonText(j);
  };
  write(dir.File("self.ltm"), "self.ltm");
  write(dir.File("a.ltm"), "b.ltm");
  write(dir.File("b.ltm"), "a.ltm");
  for (const char* name : {"self.ltm", "a.ltm", "b.ltm"}) {
    SCOPED_TRACE(name);
    auto r = io::ContainerReader::Open(dir.File(name));
    ASSERT_FALSE(r.ok());
    EXPECT_NE(r.status().message().find("shard 1 of 2"), std::string::npos) << r.status().message();
    EXPECT_NE(r.status().message().find("is itself a manifest"), std::string::npos) << r.status().message();
    auto v = io::VerifyContainer(dir.File(name));
    EXPECT_FALSE(v.complete);
    EXPECT_FALSE(v.problems.empty());
  }
  EXPECT_TRUE(io::ContainerReader::Open(out).ok());
}

}  // namespace
}  // namespace ltb
