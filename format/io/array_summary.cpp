#include "format/io/array_summary.h"

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
    case DType::kF32: AddValues(c.as<float>(), s); break;
    case DType::kF64: AddValues(c.as<double>(), s); break;
    case DType::kU8: AddValues(c.as<uint8_t>(), s); break;
    case DType::kI32: AddValues(c.as<int32_t>(), s); break;
    case DType::kU32: AddValues(c.as<uint32_t>(), s); break;
    case DType::kU64: AddValues(c.as<uint64_t>(), s); break;
  }
}

struct PerChunk {
  uint64_t hash_sum = 0;
  ArrayStats stats;
  bool present = false;
};

}  // namespace

Result<ArraySummary> SummarizeArray(const ContainerReader& reader, uint32_t array, int threads,
                                    const Progress& progress) {
  const ArraySpec& a = reader.metadata().arrays.at(array);
  uint64_t n = a.ChunkCount();
  std::vector<PerChunk> results(n);
  std::atomic<uint64_t> next{0}, done{0};
  std::mutex mu;
  Status first_error;
  auto work = [&] {
    for (;;) {
      uint64_t i = next.fetch_add(1);
      if (i >= n) return;
      if (reader.Find(array, i) == nullptr) continue;
      {
        std::lock_guard<std::mutex> lock(mu);
        if (!first_error.ok()) return;
      }
      PerChunk& pc = results[i];
      if (reader.Find(array, i)->header.encoding == static_cast<uint16_t>(Encoding::kZero)) {
        pc.stats.count = a.Extent(i).Elements();  // all zero: no hash contribution, no payload to read
        pc.stats.min = pc.stats.max = 0;
        pc.present = true;
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
        pc.present = true;
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
  uint64_t hash_sum = 0;
  for (const PerChunk& pc : results) {
    if (!pc.present) {
      out.chunks_missing++;
      continue;
    }
    out.chunks_read++;
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
  if (out.chunks_missing == 0) {
    ContentHasher total;
    total.AddSum(hash_sum);
    out.content_hash = total.Finish(a);
  }
  return out;
}

}  // namespace ltb::io
