// Creates or resumes an .ltm container and appends chunks to it.
//
// Crash safety: a chunk is committed when its frame header is written, which happens
// only after its payload is written; a writer killed at any instant leaves a file whose
// committed chunks all read back. Reopening the same path with the same metadata resumes:
// the uncommitted tail is cut off and Has() reports what is already there, so the caller
// appends only what is missing. Finish() checks every chunk is present and seals the file
// with an index and a trailer.
#pragma once

#include <cstdint>
#include <mutex>
#include <string>
#include <unordered_set>
#include <vector>

#include <nlohmann/json.hpp>

#include "format/array_spec.h"
#include "format/chunk_codec.h"
#include "format/io/file.h"
#include "format/layout.h"

namespace ltb::io {

struct WriterOptions {
  // An existing file at the path with other metadata: fail (false) or replace it (true).
  bool overwrite_mismatch = false;
  // fdatasync after every chunk (survives power loss per chunk, at a large cost).
  bool sync_each_chunk = false;
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

class ContainerWriter {
 public:
  ContainerWriter() = default;  // an empty writer (closes nothing)
  ContainerWriter(ContainerWriter&&) noexcept;
  ContainerWriter& operator=(ContainerWriter&&) noexcept;
  ~ContainerWriter();

  static Result<ContainerWriter> Open(const std::string& path, const nlohmann::json& metadata,
                                      const WriterOptions& options = {});

  const format::Metadata& metadata() const { return metadata_; }
  const ResumeInfo& resume_info() const { return resume_; }
  const std::string& path() const { return file_.path(); }

  bool Has(uint32_t array, uint64_t chunk) const;
  // Chunks of `array` not yet committed, ascending.
  std::vector<uint64_t> Missing(uint32_t array) const;

  // Appends one encoded chunk. Thread-safe; encode outside, in parallel, then append.
  // A sparse-encoded chunk must have been encoded with the array's dtype and have at most
  // format::kMaxSparseElements elements (kInvalidArgument otherwise).
  Status Append(uint32_t array, uint64_t chunk, const format::EncodedChunk& encoded);
  // Encodes and appends `data` (the chunk in the array's layout and dtype). With
  // options.sparse the array's dtype is used whatever options.dtype says, and a chunk of
  // more than format::kMaxSparseElements elements is refused (kInvalidArgument).
  Status Put(uint32_t array, uint64_t chunk, format::ByteSpan data, const format::EncodeOptions& options = {});

  // Seals the file (index + trailer + fdatasync). Fails, naming the first missing chunk,
  // when a chunk is missing. A no-op on an already sealed file.
  Status Finish();

 private:
  Status Resume(uint64_t file_size);
  Status CountMutation();  // fails once options_.stop_after_mutations is reached
  static uint64_t Key(uint32_t array, uint64_t chunk) { return (uint64_t{array} << 40) | chunk; }

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
};

}  // namespace ltb::io
