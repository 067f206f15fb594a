// Encodes and appends chunks to a ContainerWriter on one background thread, so the threads
// that produce chunks (the sample stage's ray tracers) do not wait for encoding, checksums,
// content hashes or write syscalls.
//
// Bounded: Submit blocks while the queued chunks hold capacity_bytes or more (a chunk is
// always admitted into an empty queue, whatever its size), so memory stays at most
// capacity_bytes plus one chunk. Commits happen in the order the writer thread takes the
// chunks, which the container allows (any order; each chunk commits on its own).
//
// Errors: the first failed append is kept. Later Submits fail with it without queueing
// (their chunks are dropped), the chunks still queued are dropped, and Close returns it.
// Chunks committed before the failure stay committed (ContainerWriter's guarantee), so a
// rerun resumes after them.
#pragma once

#include <condition_variable>
#include <cstdint>
#include <deque>
#include <memory>
#include <mutex>
#include <thread>

#include "format/chunk_codec.h"
#include "format/io/container_writer.h"
#include "format/status.h"

namespace ltb::io {

class AsyncChunkWriter {
 public:
  // `out` must outlive this writer (or its Close).
  AsyncChunkWriter(ContainerWriter& out, uint64_t capacity_bytes);
  ~AsyncChunkWriter();  // Close(), its status dropped: call Close to learn it
  AsyncChunkWriter(const AsyncChunkWriter&) = delete;
  AsyncChunkWriter& operator=(const AsyncChunkWriter&) = delete;

  // Queues out.Put(array, chunk, data, options). `owner` keeps the bytes of `data` alive
  // until the chunk is written or dropped (the caller hands its buffer over; no copy).
  // Blocks while the queue is full. Fails (nothing queued) once a write has failed or the
  // writer is closed.
  Status Submit(uint32_t array, uint64_t chunk, format::ByteSpan data, std::shared_ptr<const void> owner,
                const format::EncodeOptions& options = {});

  // Writes what is queued, stops the thread and returns the first error (Ok if none). Once
  // closed, returns the same status again.
  Status Close();

  uint64_t capacity_bytes() const { return capacity_; }
  // Most bytes queued at once, and how often Submit had to wait for room (for benchmarks).
  uint64_t peak_queued_bytes() const;
  uint64_t submit_waits() const;

 private:
  struct Job {
    uint32_t array;
    uint64_t chunk;
    format::ByteSpan data;
    std::shared_ptr<const void> owner;
    format::EncodeOptions options;
  };
  void Loop();

  ContainerWriter& out_;
  const uint64_t capacity_;
  mutable std::mutex mu_;
  std::condition_variable room_, work_;
  std::deque<Job> queue_;
  uint64_t queued_bytes_ = 0, peak_ = 0, waits_ = 0;
  bool closing_ = false, closed_ = false;
  Status error_;
  std::thread thread_;
};

}  // namespace ltb::io
