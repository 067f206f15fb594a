#include "format/io/async_chunk_writer.h"

#include <algorithm>
#include <system_error>
#include <utility>

namespace ltb::io {

AsyncChunkWriter::AsyncChunkWriter(ContainerWriter& out, uint64_t capacity_bytes)
    : out_(out), capacity_(capacity_bytes) {
  try {
    thread_ = std::thread([this] { Loop(); });
  } catch (const std::system_error&) {
    // No thread to be had (a process or memory limit): Submit writes synchronously.
  }
}

AsyncChunkWriter::~AsyncChunkWriter() { (void)Close(); }

Status AsyncChunkWriter::Submit(uint32_t array, uint64_t chunk, format::ByteSpan data,
                                std::shared_ptr<const void> owner, const format::EncodeOptions& options) {
  std::unique_lock<std::mutex> lock(mu_);
  const uint64_t size = data.size();
  auto has_room = [&] { return queued_bytes_ == 0 || queued_bytes_ + size <= capacity_ || !error_.ok() || closing_; };
  if (!has_room()) {
    ++waits_;
    room_.wait(lock, has_room);
  }
  if (!error_.ok()) return error_;
  if (closing_) {
    return FailedPrecondition(out_.path() + ": the chunk writer is closed; chunk " + std::to_string(chunk) +
                              " of array " + std::to_string(array) + " was not written");
  }
  if (!thread_.joinable()) {  // synchronous fallback; mu_ keeps the first error
    error_ = out_.Put(array, chunk, data, options);
    return error_;
  }
  queue_.push_back(Job{array, chunk, data, std::move(owner), options});
  queued_bytes_ += size;
  peak_ = std::max(peak_, queued_bytes_);
  work_.notify_one();
  return Status::Ok();
}

void AsyncChunkWriter::Loop() {
  for (;;) {
    Job job;
    {
      std::unique_lock<std::mutex> lock(mu_);
      work_.wait(lock, [&] { return !queue_.empty() || closing_; });
      if (queue_.empty()) return;  // closing, and everything is written
      job = std::move(queue_.front());
      queue_.pop_front();
    }
    // The chunk's bytes count as queued until they are written and released.
    Status s = out_.Put(job.array, job.chunk, job.data, job.options);
    const uint64_t size = job.data.size();
    job.owner.reset();
    std::lock_guard<std::mutex> lock(mu_);
    queued_bytes_ -= size;
    if (!s.ok() && error_.ok()) {
      error_ = std::move(s);
      for (const Job& j : queue_) queued_bytes_ -= j.data.size();
      queue_.clear();  // dropped: a rerun writes them
    }
    room_.notify_all();
  }
}

Status AsyncChunkWriter::Close() {
  {
    std::lock_guard<std::mutex> lock(mu_);
    if (closed_) return error_;
    closing_ = true;
    work_.notify_all();
    room_.notify_all();
  }
  if (thread_.joinable()) thread_.join();
  std::lock_guard<std::mutex> lock(mu_);
  closed_ = true;
  return error_;
}

uint64_t AsyncChunkWriter::peak_queued_bytes() const {
  std::lock_guard<std::mutex> lock(mu_);
  return peak_;
}

uint64_t AsyncChunkWriter::submit_waits() const {
  std::lock_guard<std::mutex> lock(mu_);
  return waits_;
}

}  // namespace ltb::io
