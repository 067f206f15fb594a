#include "format/io/io_trace.h"

#include <atomic>
#include <utility>

namespace ltb::io {

namespace {
std::atomic<IoRecorder*> g_recorder{nullptr};
std::atomic<unsigned> g_skipped{0};
}  // namespace

void SetIoRecorder(IoRecorder* recorder) { g_recorder.store(recorder); }

bool Recording() { return g_recorder.load(std::memory_order_relaxed) != nullptr; }

void RecordIo(IoOp op) {
  if (IoRecorder* r = g_recorder.load(std::memory_order_relaxed)) r->Record(std::move(op));
}

void SetSkippedBarriers(unsigned mask) { g_skipped.store(mask); }

bool BarrierSkipped(Barrier barrier) { return (g_skipped.load(std::memory_order_relaxed) & barrier) != 0; }

}  // namespace ltb::io
