#include "format/io/array_summary.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <mutex>
#include <thread>
#include <vector>

#include "format/content_hash.h"

namespace ltb::io {

using namespace ltb::format;

namespace {

template <typename T>
void AddValues(std::span<const T> v, ArrayStats* s) {
  s->count += v.size();
  for (T x : v) {
    if (x != T(0)) s->nonzero++;
    if constexpr (std::is_floating_point_v<T>) {
      if (std::isnan(x)) {
        s->nan++;
        continue;
      }
      if (std::isinf(x)) {
        s->inf++;
        continue;
      }
    }
    double d = static_cast<double>(x);
    s->min = std::min(s->min, d);
    s->max = std::max(s->max, d);
    s->sum += d;
  }
}

void AddChunkStats(const ArraySpec& a, const Chunk& c, ArrayStats* s) {
  switch (a.dtype) {
    case DType::kF32:
      AddValues(c.as<float>(), s);
      break;
    case DType::kF64:
      AddValues(c.as<double>(), s);
      break;
    case DType::kU8:
      AddValues(c.as<uint8_t>(), s);
      break;
    case DType::kI32:
      AddValues(c.as<int32_t>(), s);
      break;
    case DType::kU32:
      AddValues(c.as<uint32_t>(), s);
      break;
    case DType::kU64:
      AddValues(c.as<uint64_t>(), s);
      break;
  }
}

struct PerChunk {
  uint64_t hash_sum = 0;
  ArrayStats stats;
};

}  // namespace

Result<ArraySummary> SummarizeArray(const ContainerReader& reader, uint32_t array, int threads,
                                    const Progress& progress) {
  const ArraySpec& a = reader.metadata().arrays.at(array);
  // Work items are the committed chunks (never a table sized by the metadata's chunk
  // count, which a hostile file can make huge), in chunk order for a deterministic reduce.
  std::vector<uint64_t> chunks;
  for (const auto& e : reader.chunk_frames())
    if (e.header.array == array) chunks.push_back(e.header.chunk_index);
  std::sort(chunks.begin(), chunks.end());
  const uint64_t n = chunks.size();
  std::vector<PerChunk> results(n);
  std::atomic<uint64_t> next{0}, done{0};
  std::mutex mu;
  Status first_error;
  auto work = [&] {
    for (;;) {
      uint64_t k = next.fetch_add(1);
      if (k >= n) return;
      {
        std::lock_guard<std::mutex> lock(mu);
        if (!first_error.ok()) return;
      }
      const uint64_t i = chunks[k];
      PerChunk& pc = results[k];
      if (reader.Find(array, i)->header.encoding == static_cast<uint16_t>(Encoding::kZero)) {
        pc.stats.count = a.Extent(i).Elements();  // all zero: no hash contribution, no payload to read
        pc.stats.min = pc.stats.max = 0;
      } else {
        auto chunk = reader.ReadChunk(array, i);
        if (!chunk.ok()) {
          std::lock_guard<std::mutex> lock(mu);
          if (first_error.ok()) first_error = chunk.status();
          return;
        }
        ContentHasher h;
        h.AddChunk(a, chunk->extent(), chunk->bytes());
        pc.hash_sum = h.sum();
        AddChunkStats(a, *chunk, &pc.stats);
      }
      progress.Report(done.fetch_add(1) + 1, n, "chunks");
    }
  };
  int t = std::max(1, threads);
  std::vector<std::thread> pool;
  for (int k = 1; k < t; ++k) pool.emplace_back(work);
  work();
  for (auto& th : pool) th.join();
  LTB_RETURN_IF_ERROR(first_error);

  // Reduce in chunk order so floating-point sums do not depend on the thread count.
  ArraySummary out;
  out.chunks_read = n;
  out.chunks_missing = reader.metadata().OwnedChunks(array) - n;
  uint64_t hash_sum = 0;
  for (const PerChunk& pc : results) {
    hash_sum += pc.hash_sum;
    ArrayStats& s = out.stats;
    s.count += pc.stats.count;
    s.nonzero += pc.stats.nonzero;
    s.nan += pc.stats.nan;
    s.inf += pc.stats.inf;
    s.min = std::min(s.min, pc.stats.min);
    s.max = std::max(s.max, pc.stats.max);
    s.sum += pc.stats.sum;
  }
  out.hash_sum = hash_sum;
  if (out.chunks_missing == 0) {
    ContentHasher total;
    total.AddSum(hash_sum);
    out.content_hash = total.Finish(a);
  }
  return out;
}

}  // namespace ltb::io
