// Creates or resumes an .ltm container and appends chunks to it.
//
// Crash safety: a chunk is committed when its frame header is written, which happens
// only after its payload is written; a writer killed at any instant leaves a file whose
// committed chunks all read back. Reopening the same path with the same metadata resumes:
// the uncommitted tail is cut off and Has() reports what is already there, so the caller
// appends only what is missing. Finish() checks every chunk is present and seals the file
// with an index and a trailer.
//
// content_hash: the writer sums every chunk's content_hash contribution as it is appended
// (the sum does not depend on the order of commits) and records the sums in a
// content-hash frame when it seals (docs/FORMAT.md), so readers get an output's
// content_hash without reading it back. Chunks committed by an earlier, interrupted
// writer are read back and hashed once, when the resumed file is sealed.
//
// One writer per file: Open takes the output's lock (LockOutput) before it opens or
// creates anything, and the writer holds it until it is destroyed; a second writer of the
// same path (another process) fails with "PATH is in use by PID N" and touches nothing.
#pragma once

#include <cstdint>
#include <memory>
#include <mutex>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <unordered_set>
#include <vector>

#include "format/array_spec.h"
#include "format/chunk_codec.h"
#include "format/io/file.h"
#include "format/io/file_lock.h"
#include "format/layout.h"

namespace ltb::io {

class ContainerReader;

struct WriterOptions {
  // An existing file at the path with other metadata: fail (false) or replace it (true).
  bool overwrite_mismatch = false;
  // fdatasync after every chunk (survives power loss per chunk, at a large cost).
  bool sync_each_chunk = false;
  // Write large chunk payloads with O_DIRECT, around the page cache: each such payload is
  // put on a 4096-byte boundary (a small padding frame before it when needed, at most 4 KiB
  // of zeros per chunk) and written from an aligned buffer. Saves the kernel's copy into
  // the page cache, which bounds writers on many machines; the bytes and the commit order
  // are the same. Falls back to ordinary writes where the file system refuses O_DIRECT.
  bool direct_io = false;
  // Payloads smaller than this are written through the page cache even with direct_io.
  uint64_t direct_min_bytes = 64 << 10;
  // For crash tests: every file mutation (write, extend, sync) after the first
  // `stop_after_mutations` fails, leaving the file exactly as a writer killed there would.
  uint64_t stop_after_mutations = UINT64_MAX;
};

struct ResumeInfo {
  bool resumed = false;           // the file existed with the same metadata
  bool already_complete = false;  // ... and was sealed
  uint64_t committed_chunks = 0;  // chunks found committed
  uint64_t discarded_tail_bytes = 0;
};

// What the writer did with direct_io (for reports and tests).
struct DirectIoStats {
  bool active = false;          // direct writes are on (asked for, accepted, not fallen back)
  uint64_t direct_bytes = 0;    // payload bytes written with O_DIRECT
  uint64_t padding_frames = 0;  // padding frames written to align payloads
  uint64_t padding_bytes = 0;   // their size, headers included
  std::string fallback_reason;  // why direct writes stopped, if they did
};

class ContainerWriter {
 public:
  ContainerWriter() = default;  // an empty writer (closes nothing)
  ContainerWriter(ContainerWriter&&) noexcept;
  ContainerWriter& operator=(ContainerWriter&&) noexcept;
  ~ContainerWriter();

  // kFailedPrecondition "PATH is in use by PID N ..." when another process writes path.
  static Result<ContainerWriter> Open(const std::string& path, const nlohmann::json& metadata,
                                      const WriterOptions& options = {});

  const format::Metadata& metadata() const { return metadata_; }
  const ResumeInfo& resume_info() const { return resume_; }
  const std::string& path() const { return file_.path(); }
  DirectIoStats direct_io_stats() const;

  bool Has(uint32_t array, uint64_t chunk) const;
  // Chunks of `array` not yet committed, ascending.
  std::vector<uint64_t> Missing(uint32_t array) const;

  // Appends one encoded chunk. Thread-safe; encode outside, in parallel, then append.
  // A sparse-encoded chunk must have been encoded with the array's dtype and have at most
  // format::kMaxSparseElements elements (kInvalidArgument otherwise). `hash_sum` is the
  // chunk's content_hash sum (format::ChunkHashSum of its decoded bytes) when the caller
  // has it; without it the writer decodes the chunk to compute it.
  Status Append(uint32_t array, uint64_t chunk, const format::EncodedChunk& encoded,
                std::optional<uint64_t> hash_sum = std::nullopt);
  // Encodes and appends `data` (the chunk in the array's layout and dtype). With
  // options.sparse the array's dtype is used whatever options.dtype says, the line length
  // of kCoded (options.coded) is the array's, and a chunk of more than
  // format::kMaxSparseElements elements is refused (kInvalidArgument).
  Status Put(uint32_t array, uint64_t chunk, format::ByteSpan data, const format::EncodeOptions& options = {});

  // For producers whose input is not a container (a .npy, an in-memory array): a resumed
  // file is theirs only if its committed chunks hold what this run would write. Ok when
  // `chunk` was not found committed on resume, or holds exactly `data` (the dense chunk, as
  // Put takes it); otherwise kFailedPrecondition naming the file, the chunk, the first
  // element that differs (committed and new values) and what to do: the input changed
  // since the earlier run. Thread-safe. Reads the committed chunk back.
  Status CheckResumedChunk(uint32_t array, uint64_t chunk, format::ByteSpan data) const;

  // Seals the file (content-hash frame + index + trailer + fdatasync). Fails, naming the first missing chunk,
  // when a chunk is missing. A no-op on an already sealed file.
  Status Finish();

  // Closes the file and removes it, still holding the output's lock (so no other writer can
  // have started on it in between); leaves an empty writer. For a stage that finds its
  // freshly written output unusable.
  Status Discard();

 private:
  Status Resume(uint64_t file_size);
  Status CountMutation();  // fails once options_.stop_after_mutations is reached
  // Direct-I/O helpers; called with mu_ held.
  void OpenDirect();
  Status AppendPadding(uint64_t frame_offset);
  Status WritePayload(uint64_t offset, format::ByteSpan payload, bool direct);
  static uint64_t Key(uint32_t array, uint64_t chunk) { return (uint64_t{array} << 40) | chunk; }
  // Adds the sums of committed chunks this writer did not append (found on resume),
  // reading them back; called with mu_ held.
  Status HashResumedChunks();

  FileLock lock_;  // first: released after the file is closed
  // A reader of the chunks found on resume (CheckResumedChunk), opened on first use.
  mutable std::shared_ptr<const ContainerReader> resumed_reader_;
  File file_;
  format::Metadata metadata_;
  format::FileHeader header_;
  ResumeInfo resume_;
  WriterOptions options_;
  mutable std::mutex mu_;
  uint64_t end_ = 0;  // where the next frame goes
  bool sealed_ = false;
  uint64_t mutations_ = 0;
  std::vector<format::IndexEntry> frames_;
  std::unordered_set<uint64_t> committed_;
  std::vector<uint64_t> hash_sums_;      // per array: Σ content_hash sums of the chunks in hashed_
  std::unordered_set<uint64_t> hashed_;  // chunks this writer hashed (not those found on resume)
  File direct_;                          // the same file opened with O_DIRECT (options_.direct_io), else closed
  struct FreeDeleter {
    void operator()(std::byte* p) const;
  };
  std::unique_ptr<std::byte, FreeDeleter> bounce_;  // aligned staging for unaligned payloads
  DirectIoStats direct_stats_;
};

}  // namespace ltb::io
