// Opens an .ltm container and reads its committed chunks. A sealed file is opened
// through its index; an unsealed one (being written, or left by a killed writer) by
// scanning its frames. Only committed chunks are visible; a chunk that was never
// committed is reported missing, never read as zeros.
#pragma once

#include <cstdint>
#include <string>
#include <unordered_map>
#include <vector>

#include "format/array_spec.h"
#include "format/chunk_codec.h"
#include "format/io/file.h"
#include "format/io/mapped_region.h"
#include "format/layout.h"

namespace ltb::io {

// One decoded (dense) chunk: raw chunks are a zero-copy mapping, others an owned buffer.
class Chunk {
 public:
  format::ByteSpan bytes() const { return owned_.empty() ? region_.bytes() : format::ByteSpan(owned_); }
  template <typename T>
  std::span<const T> as() const {
    auto b = bytes();
    return {reinterpret_cast<const T*>(b.data()), b.size() / sizeof(T)};
  }
  format::Encoding encoding() const { return encoding_; }
  const format::ChunkExtent& extent() const { return extent_; }

 private:
  friend class ContainerReader;
  format::Encoding encoding_ = format::Encoding::kRaw;
  format::ChunkExtent extent_;
  MappedRegion region_;
  std::vector<std::byte> owned_;
};

struct ReadOptions {
  bool verify_checksum = true;
  // Reading chunks in file order: read the chunk ahead and start the I/O of the next
  // `readahead_chunks` frames, so it overlaps the caller's work on this one.
  bool sequential = true;
  uint32_t readahead_chunks = 2;
};

class ContainerReader {
 public:
  static Result<ContainerReader> Open(const std::string& path);

  const std::string& path() const { return file_.path(); }
  const format::FileHeader& header() const { return header_; }
  const format::Metadata& metadata() const { return metadata_; }
  uint64_t file_size() const { return file_size_; }
  bool sealed() const { return sealed_; }
  // Every chunk of every array is committed.
  bool complete() const;
  uint64_t committed(uint32_t array) const { return committed_.at(array); }

  // The frame of a committed chunk, or nullptr when it is missing.
  const format::IndexEntry* Find(uint32_t array, uint64_t chunk) const;
  // Chunk frames in file order.
  const std::vector<format::IndexEntry>& chunk_frames() const { return chunk_frames_; }
  // Structural problems found while opening (damaged regions, duplicate or stray frames).
  const std::vector<std::string>& problems() const { return problems_; }
  uint64_t uncommitted_tail_bytes() const { return tail_bytes_; }

  // The dense chunk, whatever its encoding. Fails with kNotFound when the chunk is missing,
  // kDataLoss on checksum or decode errors (naming file, array, chunk and what is wrong).
  Result<Chunk> ReadChunk(uint32_t array, uint64_t chunk, const ReadOptions& options = {}) const;

  // The chunk's stored (nonzero-bit-pattern) elements: decoded without densifying for the
  // sparse encodings, derived from the dense chunk for raw, zstd and all-zero ones, so every
  // encoding gives the same result. Errors as ReadChunk; kInvalidArgument for a dense-encoded
  // chunk of more than format::kMaxSparseElements elements (use ReadChunk).
  Result<format::SparseChunk> ReadSparse(uint32_t array, uint64_t chunk, const ReadOptions& options = {}) const;

  // Checks a committed chunk's payload checksum by streaming it through `buffer` with
  // positional reads (no mapping: memory use is the buffer's size).
  Status VerifyChunk(uint32_t array, uint64_t chunk, format::MutableByteSpan buffer) const;

  // Picks up chunks committed since the file was opened (unsealed files only).
  Status Refresh();

 private:
  Status LoadFromIndex(uint64_t index_offset);
  Status LoadByScan();
  void AddFrame(const format::IndexEntry& e);
  std::string ChunkName(uint32_t array, uint64_t chunk) const;
  // The committed frame of a chunk (range-checked; kNotFound when missing), and its name.
  Result<const format::IndexEntry*> Locate(uint32_t array, uint64_t chunk, std::string* where) const;
  void Readahead(const format::IndexEntry* e, const ReadOptions& options) const;
  // Maps a chunk's payload and checks its checksum (when `verify`).
  Result<MappedRegion> MapPayload(const format::IndexEntry& e, const std::string& where, bool sequential,
                                  bool verify) const;

  File file_;
  uint64_t file_size_ = 0;
  format::FileHeader header_;
  format::Metadata metadata_;
  bool sealed_ = false;
  uint64_t tail_bytes_ = 0;
  uint64_t scan_end_ = 0;
  std::vector<format::IndexEntry> chunk_frames_;
  std::unordered_map<uint64_t, size_t> by_key_;  // (array << 40 | chunk) -> chunk_frames_ slot
  std::vector<uint64_t> committed_;
  std::vector<std::string> problems_;
};

// Reads and validates header and metadata of an open file (shared by reader, writer, verify).
struct ContainerPrelude {
  format::FileHeader header;
  format::Metadata metadata;
  std::string metadata_bytes;
};
Result<ContainerPrelude> ReadPrelude(const File& file, uint64_t file_size);

}  // namespace ltb::io
