// AsyncChunkWriter: chunks handed over from several threads all commit, whatever the
// order; the queue stays within its bound; the first write error reaches Submit and Close;
// a rerun after a failure resumes with the committed chunks.
#include <gtest/gtest.h>

#include <algorithm>
#include <memory>
#include <random>
#include <thread>
#include <vector>

#include "format/io/async_chunk_writer.h"
#include "test_util.h"

namespace ltb {
namespace {

using format::Layout;
using test::TempDir;

constexpr uint64_t kAsyncRows = 64, kAsyncCols = 32, kAsyncBlock = 2;  // 32 chunks of 256 bytes

// Submits the chunks `todo` of MakeMatrix(kAsyncRows, kAsyncCols, 3) from two threads, each
// in its own shuffled order; returns the first Submit failure, else Close's status.
Status WriteAsync(io::ContainerWriter& w, std::vector<uint64_t> todo, uint64_t capacity, uint64_t* peak = nullptr) {
  const auto m = test::MakeMatrix(kAsyncRows, kAsyncCols, 3);
  io::AsyncChunkWriter async(w, capacity);
  std::vector<Status> st(2);
  std::vector<std::thread> threads;
  for (int t = 0; t < 2; ++t) {
    threads.emplace_back([&, t] {
      std::vector<uint64_t> mine;
      for (size_t i = t; i < todo.size(); i += 2) mine.push_back(todo[i]);
      std::shuffle(mine.begin(), mine.end(), std::mt19937(7 + t));
      for (uint64_t c : mine) {
        auto v = std::make_shared<std::vector<float>>(test::ChunkValues(w.metadata().matrix(), m, c));
        Status s = async.Submit(0, c, test::AsBytes(*v), v);
        if (!s.ok()) {
          st[t] = s;
          return;
        }
      }
    });
  }
  for (auto& th : threads) th.join();
  Status closed = async.Close();
  if (peak) *peak = async.peak_queued_bytes();
  EXPECT_LE(async.peak_queued_bytes(), std::max<uint64_t>(capacity, kAsyncBlock * kAsyncCols * 4));
  for (const Status& s : st)
    if (!s.ok()) return s;
  return closed;
}

std::vector<uint64_t> AllChunks() {
  std::vector<uint64_t> v(kAsyncRows / kAsyncBlock);
  for (uint64_t i = 0; i < v.size(); ++i) v[i] = i;
  return v;
}

TEST(AsyncChunkWriter, CommitsEveryChunkInAnyOrderWithinTheBound) {
  TempDir dir;
  const auto meta = test::MatrixMetadata(kAsyncRows, kAsyncCols, Layout::kRows, kAsyncBlock);
  test::WriteMatrix(dir.File("ref.ltm"), kAsyncRows, kAsyncCols, Layout::kRows, kAsyncBlock, 3, false);
  for (uint64_t capacity : {uint64_t{0}, uint64_t{3 * 256}, uint64_t{1} << 20}) {
    const std::string path = dir.File("async" + std::to_string(capacity) + ".ltm");
    auto w = io::ContainerWriter::Open(path, meta);
    ASSERT_TRUE(w.ok()) << w.status().message();
    uint64_t peak = 0;
    Status s = WriteAsync(*w, AllChunks(), capacity, &peak);
    ASSERT_TRUE(s.ok()) << s.message();
    if (capacity == 0) {
      EXPECT_EQ(peak, 256u) << "a chunk is admitted into an empty queue, one at a time";
    }
    ASSERT_TRUE(w->Finish().ok());
    EXPECT_EQ(test::HashOf(path), test::HashOf(dir.File("ref.ltm"))) << "capacity " << capacity;
  }
}

TEST(AsyncChunkWriter, FirstWriteErrorReachesSubmitAndCloseAndARerunResumes) {
  TempDir dir;
  const std::string path = dir.File("fail.ltm");
  const auto meta = test::MatrixMetadata(kAsyncRows, kAsyncCols, Layout::kRows, kAsyncBlock);
  {
    io::WriterOptions o;
    o.stop_after_mutations = 21;  // two mutations per chunk (payload, header): fails in chunk 11
    auto w = io::ContainerWriter::Open(path, meta, o);
    ASSERT_TRUE(w.ok()) << w.status().message();
    Status s = WriteAsync(*w, AllChunks(), 4 * 256);
    EXPECT_EQ(s.code(), StatusCode::kInternal);
    EXPECT_NE(s.message().find("stopped after 21 writes"), std::string::npos) << s.message();
    EXPECT_EQ(w->Missing(0).size(), kAsyncRows / kAsyncBlock - 10) << "the chunks committed before the failure stay";
    // A closed writer refuses more chunks, with the error that stopped it.
    io::AsyncChunkWriter closed(*w, 0);
    ASSERT_TRUE(closed.Close().ok());
    auto v = std::make_shared<std::vector<float>>(kAsyncBlock * kAsyncCols, 1.0f);
    Status late = closed.Submit(0, w->Missing(0).front(), test::AsBytes(*v), v);
    EXPECT_EQ(late.code(), StatusCode::kFailedPrecondition);
    EXPECT_NE(late.message().find("closed"), std::string::npos) << late.message();
  }
  auto w = io::ContainerWriter::Open(path, meta);
  ASSERT_TRUE(w.ok()) << w.status().message();
  EXPECT_EQ(w->resume_info().committed_chunks, 10u);
  Status s = WriteAsync(*w, w->Missing(0), 4 * 256);
  ASSERT_TRUE(s.ok()) << s.message();
  ASSERT_TRUE(w->Finish().ok());
  test::WriteMatrix(dir.File("ref.ltm"), kAsyncRows, kAsyncCols, Layout::kRows, kAsyncBlock, 3, false);
  EXPECT_EQ(test::HashOf(path), test::HashOf(dir.File("ref.ltm")));
}

}  // namespace
}  // namespace ltb
