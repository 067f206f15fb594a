// Progress reporting from libraries: a callback the main turns into a progress bar.
// Libraries never print.
#pragma once

#include <cstdint>
#include <functional>
#include <string>

namespace ltb {

struct Progress {
  // done/total in `unit` (e.g. "bytes", "chunks"); may be called from any thread.
  std::function<void(uint64_t done, uint64_t total, const char* unit)> update;
  // Returns true when the run should stop (SIGINT/SIGTERM): committed work is kept.
  std::function<bool()> cancelled;

  void Report(uint64_t done, uint64_t total, const char* unit) const {
    if (update) update(done, total, unit);
  }
  bool Cancelled() const { return cancelled && cancelled(); }
};

}  // namespace ltb
