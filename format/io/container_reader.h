// Opens an .ltm container, or a stage manifest of shard files (format/io/manifest.h) as the
// one matrix it describes, and reads its committed chunks. A sealed file is opened
// through its index; an unsealed one (being written, or left by a killed writer) by
// scanning its frames. Only committed chunks are visible; a chunk that was never
// committed is reported missing, never read as zeros.
#pragma once

#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <unordered_map>
#include <unordered_set>
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
  // A manifest is checked as it opens: every shard present, sealed and complete, of the
  // manifest's size and fingerprint, with the manifest's metadata, the shards' chunks
  // partitioning every array. A failure names the shard and what to do.
  static Result<ContainerReader> Open(const std::string& path);

  // A manifest: its shards, in order (empty for a container).
  bool is_manifest() const { return !parts_.empty(); }
  // The container file holding a chunk: its shard for a manifest, else this reader.
  const ContainerReader& Holder(uint32_t array, uint64_t chunk) const {
    const ContainerReader* p = PartOf(array, chunk);
    return p != nullptr ? *p : *this;
  }
  const File& file() const { return file_; }
  const std::vector<std::shared_ptr<const ContainerReader>>& shards() const { return parts_; }

  const std::string& path() const { return file_.path(); }
  const format::FileHeader& header() const { return header_; }
  const format::Metadata& metadata() const { return metadata_; }
  uint64_t file_size() const { return file_size_; }  // a manifest: its own size plus its shards'
  bool sealed() const { return sealed_; }
  // Every chunk of every array is committed.
  bool complete() const;
  uint64_t committed(uint32_t array) const { return committed_.at(array); }

  // The content_hash sum the writer recorded for `array` when it sealed the file (its
  // content-hash frame), or nothing: the file is not sealed, was written before the frame
  // existed (2026-11-26), or its record is damaged. A manifest: the sum of its shards'
  // records, when every shard has one. Trusted as written; `verify` recomputes it.
  std::optional<uint64_t> RecordedHashSum(uint32_t array) const;
  // RecordedHashSum as a content_hash (16 hex digits), or "" when there is none.
  std::string RecordedContentHash(uint32_t array) const;

  // The frame of a committed chunk, or nullptr when it is missing.
  const format::IndexEntry* Find(uint32_t array, uint64_t chunk) const;
  // Chunk frames in file order (a manifest: each shard's, shard after shard; offsets are
  // within the shard file).
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

  // The chunk as stored (payload copied, checksum verified): for copying chunks between
  // containers without decoding them.
  Result<format::EncodedChunk> ReadEncoded(uint32_t array, uint64_t chunk) const;

  // Picks up chunks committed since the file was opened (unsealed files only).
  Status Refresh();

 private:
  Status LoadFromIndex(uint64_t index_offset);
  Status LoadByScan();
  Status LoadManifest();  // in manifest.cpp
  void LoadContentHashRecord(uint64_t index_offset);
  // A manifest's shard holding the chunk, or nullptr (a container, or a missing chunk).
  const ContainerReader* PartOf(uint32_t array, uint64_t chunk) const;
  // A shard's error, prefixed with "MANIFEST: shard I of N".
  Status InShard(const ContainerReader* part, const Status& s) const;
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
  std::unordered_set<uint64_t> duplicated_;      // keys committed more than once: never read
  std::vector<uint64_t> committed_;
  std::vector<std::string> problems_;
  std::vector<std::shared_ptr<const ContainerReader>> parts_;  // a manifest's shards
  std::vector<uint32_t> frame_part_;                           // per chunk_frames_ slot
  std::vector<uint64_t> recorded_sums_;                        // the content-hash frame's, or empty
};

// A fingerprint of what the file holds: its metadata and every committed chunk's
// (array, chunk, encoding, checksum). Cheap (the index only); changes with any chunk.
std::string IndexFingerprint(const ContainerReader& reader);

// Reads and validates header and metadata of an open file (shared by reader, writer, verify).
struct ContainerPrelude {
  format::FileHeader header;
  format::Metadata metadata;
  std::string metadata_bytes;
};
Result<ContainerPrelude> ReadPrelude(const File& file, uint64_t file_size);

}  // namespace ltb::io
