// Row-transform throughput: the stage's per-block kernel (TransformRows, from the input
// block to the output buffer, as the stage does from the mapped chunk) over a rows × 6R²
// f32 matrix in memory, beside a plain memcpy of the same bytes in the same run, with the
// same number of threads. Prints one JSON line per measurement.
// usage: ltb_row_transform_bench [--rows 65536] [--cube-res 32] [--threads 2] [--reps 5] [--filter haar]
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include "stages/row_transform/row_transform.h"

using Clock = std::chrono::steady_clock;

template <typename Fn>
double TimeParallel(int threads, uint64_t rows, uint64_t block, Fn fn) {
  auto t0 = Clock::now();
  std::vector<std::thread> pool;
  for (int t = 0; t < threads; ++t) {
    pool.emplace_back([&, t] {
      for (uint64_t r0 = t * block; r0 < rows; r0 += threads * block) fn(r0, std::min(block, rows - r0));
    });
  }
  for (auto& th : pool) th.join();
  return std::chrono::duration<double>(Clock::now() - t0).count();
}

int main(int argc, char** argv) {
  uint64_t rows = 65536, r = 32;
  int threads = 2, reps = 5;
  std::string only;  // --filter NAME: just that one
  for (int i = 1; i + 1 < argc; i += 2) {
    std::string k = argv[i];
    if (k == "--rows")
      rows = std::strtoull(argv[i + 1], nullptr, 10);
    else if (k == "--cube-res")
      r = std::strtoull(argv[i + 1], nullptr, 10);
    else if (k == "--threads")
      threads = std::atoi(argv[i + 1]);
    else if (k == "--reps")
      reps = std::atoi(argv[i + 1]);
    else if (k == "--filter")
      only = argv[i + 1];
  }
  const uint64_t cols = 6 * r * r, block = 256;  // rows per work item, like a chunk of the stage
  // Not value-initialised: the threads touch the pages first (fill, then an untimed copy).
  std::unique_ptr<float[]> src_mem(new float[rows * cols]), dst_mem(new float[rows * cols]);
  float* src = src_mem.get();
  float* dst = dst_mem.get();
  // Uniform in [-1, 1), from a counter hash (splitmix64) so the threads fill it fast.
  TimeParallel(threads, rows, block, [&](uint64_t r0, uint64_t n) {
    for (uint64_t i = r0 * cols; i < (r0 + n) * cols; ++i) {
      uint64_t z = (i + 1) * 0x9E3779B97F4A7C15ull;
      z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
      z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
      z ^= z >> 31;
      src[i] = static_cast<float>(static_cast<double>(z >> 40) * 0x1p-23 - 1.0);
    }
  });
  double gb = rows * cols * 4.0 / 1e9;
  // Untimed: fault in dst's pages, so the first repetition does not time the page faults.
  TimeParallel(threads, rows, block,
               [&](uint64_t r0, uint64_t n) { std::memcpy(dst + r0 * cols, src + r0 * cols, n * cols * 4); });
  for (int rep = 0; rep < reps; ++rep) {
    double tc = TimeParallel(threads, rows, block, [&](uint64_t r0, uint64_t n) {
      std::memcpy(dst + r0 * cols, src + r0 * cols, n * cols * 4);
    });
    std::printf("{\"what\":\"memcpy\",\"rep\":%d,\"seconds\":%.4f,\"gb_per_s\":%.3f}\n", rep, tc, gb / tc);
    for (auto f : {ltb::wavelet::Filter::kHaar, ltb::wavelet::Filter::kDb2, ltb::wavelet::Filter::kDb3,
                   ltb::wavelet::Filter::kDb4}) {
      if (!only.empty() && only != ltb::wavelet::FilterName(f)) continue;
      // Like the stage: from the (mapped) input chunk straight into the output buffer.
      double tt = TimeParallel(threads, rows, block, [&](uint64_t r0, uint64_t n) {
        thread_local std::vector<float> scratch(ltb::stages::RowBlockScratchSize(r));
        uint64_t zero = 0;
        ltb::stages::TransformRows(f, r, src + r0 * cols, dst + r0 * cols, n, scratch.data(), &zero);
      });
      std::printf("{\"what\":\"%s\",\"rep\":%d,\"seconds\":%.4f,\"gb_per_s\":%.3f,\"vs_memcpy\":%.3f}\n",
                  ltb::wavelet::FilterName(f), rep, tt, gb / tt, tc / tt);
    }
    std::fflush(stdout);
  }
  return 0;
}
