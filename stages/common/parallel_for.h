// Runs a function over work items on a fixed number of threads, stopping at the first
// error or when the run is cancelled (SIGINT/SIGTERM through Progress). Items are
// independent; results must not depend on which thread runs which item.
#pragma once

#include <algorithm>
#include <atomic>
#include <cstdint>
#include <mutex>
#include <thread>
#include <vector>

#include "format/progress.h"
#include "format/status.h"

namespace ltb::stages {

template <typename Item, typename Fn>
Status ParallelFor(const std::vector<Item>& items, int jobs, const Progress& progress, const char* unit, Fn fn) {
  std::atomic<size_t> next{0};
  std::atomic<uint64_t> done{0};
  std::mutex mu;
  Status first;
  auto failed = [&] {
    std::lock_guard<std::mutex> lock(mu);
    return !first.ok();
  };
  auto fail = [&](Status s) {
    std::lock_guard<std::mutex> lock(mu);
    if (first.ok()) first = std::move(s);
  };
  auto work = [&] {
    while (!failed()) {
      if (progress.Cancelled()) {
        fail(Cancelled("interrupted; committed chunks are kept, rerun the same command to resume"));
        return;
      }
      size_t k = next.fetch_add(1);
      if (k >= items.size()) return;
      Status s = fn(items[k]);
      if (!s.ok()) {
        fail(std::move(s));
        return;
      }
      progress.Report(done.fetch_add(1) + 1, items.size(), unit);
    }
  };
  std::vector<std::thread> pool;
  for (int t = 1; t < std::max(1, jobs); ++t) pool.emplace_back(work);
  work();
  for (auto& th : pool) th.join();
  return first;
}

}  // namespace ltb::stages
