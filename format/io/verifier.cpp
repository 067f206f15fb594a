#include "format/io/verifier.h"

#include <xxhash.h>

#include <set>

#include "format/array_spec.h"
#include "format/chunk_codec.h"
#include "format/content_hash.h"
#include "format/io/array_summary.h"
#include "format/io/container_reader.h"
#include "format/io/frame_scan.h"
#include "format/io/manifest.h"
#include "format/io/mapped_region.h"

namespace ltb::io {

using namespace ltb::format;

namespace {

bool RangeIsZero(const File& f, uint64_t offset, uint64_t length, std::string* error) {
  std::array<std::byte, 4096> buf;
  while (length > 0) {
    uint64_t n = std::min<uint64_t>(length, buf.size());
    Status s = f.ReadAt(offset, MutableByteSpan(buf.data(), n));
    if (!s.ok()) {
      *error = s.message();
      return false;
    }
    for (uint64_t i = 0; i < n; ++i)
      if (buf[i] != std::byte{0}) {
        *error = "nonzero padding byte at offset " + std::to_string(offset + i);
        return false;
      }
    offset += n;
    length -= n;
  }
  return true;
}

// XXH3-64 of a byte range (format::Checksum of it), read with pread through `buffer`. Not a
// mapping: a region the file no longer covers, or a hole a full tmpfs cannot back with a
// page (an interrupted seal's zero-extended index frame), is an error here, not a SIGBUS.
Result<uint64_t> ChecksumRange(const File& f, uint64_t offset, uint64_t length, std::vector<std::byte>& buffer) {
  constexpr uint64_t kBufferBytes = 256 << 10;
  if (buffer.size() < std::min(length, kBufferBytes)) buffer.resize(std::min(length, kBufferBytes));
  XXH3_state_t* st = XXH3_createState();
  if (st == nullptr) return Internal("XXH3_createState failed");
  XXH3_64bits_reset(st);
  Status s;
  while (length > 0 && s.ok()) {
    const uint64_t n = std::min<uint64_t>(length, buffer.size());
    s = f.ReadAt(offset, MutableByteSpan(buffer.data(), n));
    if (s.ok()) XXH3_64bits_update(st, buffer.data(), n);
    offset += n;
    length -= n;
  }
  const uint64_t h = XXH3_64bits_digest(st);
  XXH3_freeState(st);
  if (!s.ok()) return s;
  return h;
}

// One verification of a container file, check by check in file order: header and
// metadata, the frame chain, each frame (chunk frames in depth), then the seal (trailer
// and index). Each check adds what it finds to the report; those returning false found
// damage that ends the verification.
class Verification {
 public:
  Verification(const std::string& path, int threads) : threads_(threads) { r_.path = path; }
  VerifyReport Run();

 private:
  bool ReadPreludeChecked();
  bool ScanChain();
  void CheckFrame(const IndexEntry& e);
  void CheckChunkFrame(const IndexEntry& e, const std::string& where);
  bool CheckChunkPayload(const FrameHeader& h, const ArraySpec& a, uint64_t payload_offset, const std::string& where);
  bool CheckTrailer();
  void CheckSeal(bool trailer_ok);
  void CheckIndexEntries();
  void CheckContentHashes();

  VerifyReport r_;
  int threads_ = 1;
  std::vector<uint64_t> recorded_sums_;  // the last valid content-hash frame's
  File file_;
  uint64_t size_ = 0;
  ContainerPrelude prelude_;
  uint64_t first_ = 0;  // the first frame's offset
  ScanResult scan_;
  std::set<uint64_t> seen_;
  std::vector<std::byte> buffer_;  // for positional reads of payloads
  std::vector<IndexEntry> chunk_frames_;
  const IndexEntry* index_frame_ = nullptr;
  const IndexEntry* partial_index_ = nullptr;  // last frame: an index whose payload does not verify
};

// The file, its header and metadata, and the zero padding after the metadata.
bool Verification::ReadPreludeChecked() {
  auto file = File::Open(r_.path, File::Mode::kRead);
  if (!file.ok()) {
    r_.problems.push_back(file.status().message());
    return false;
  }
  file_ = std::move(file).value();
  auto size_or = file_.Size();
  if (!size_or.ok()) {
    r_.problems.push_back(size_or.status().message());
    return false;
  }
  size_ = *size_or;
  auto prelude = ReadPrelude(file_, size_);
  if (!prelude.ok()) {
    r_.problems.push_back(prelude.status().message());
    return false;
  }
  prelude_ = std::move(prelude).value();
  r_.readable = true;
  const Metadata& meta = prelude_.metadata;
  for (uint32_t a = 0; a < meta.arrays.size(); ++a) r_.chunks_expected += meta.OwnedChunks(a);
  first_ = prelude_.header.FirstFrameOffset();
  std::string err;
  if (first_ > size_) {
    r_.problems.push_back("file ends at " + std::to_string(size_) + " inside the metadata padding (truncated)");
    return false;
  }
  if (!RangeIsZero(file_, kHeaderSize + prelude_.header.metadata_length,
                   first_ - kHeaderSize - prelude_.header.metadata_length, &err)) {
    r_.problems.push_back("metadata padding: " + err);
  }
  return true;
}

// The frame chain, and every damaged region in it.
bool Verification::ScanChain() {
  auto scan = ScanFrames(file_, first_, size_);
  if (!scan.ok()) {
    r_.problems.push_back(scan.status().message());
    return false;
  }
  scan_ = std::move(scan).value();
  for (const ScanGap& g : scan_.gaps) {
    r_.problems.push_back("offset " + std::to_string(g.offset) + ": " + g.reason + " (" +
                          std::to_string(g.resume - g.offset) + " unreadable bytes; next valid frame at offset " +
                          std::to_string(g.resume) + ")");
  }
  return true;
}

// Any frame: its place, its padding, its payload checksum and its type.
void Verification::CheckFrame(const IndexEntry& e) {
  const Metadata& meta = prelude_.metadata;
  const FrameHeader& h = e.header;
  std::string where = "frame at offset " + std::to_string(e.frame_offset);
  if (h.type == static_cast<uint16_t>(FrameType::kChunk) && h.array < meta.arrays.size()) {
    where += " (array \"" + meta.arrays[h.array].name + "\" chunk " + std::to_string(h.chunk_index) + ")";
  }
  uint64_t payload_offset = e.frame_offset + kFrameHeaderSize;
  uint64_t padded_end = std::min(size_, e.frame_offset + h.FrameSize());
  std::string err;
  if (index_frame_ != nullptr) {
    r_.problems.push_back(where + ": frame after the index frame at offset " +
                          std::to_string(index_frame_->frame_offset));
  }
  if (!RangeIsZero(file_, payload_offset + h.payload_length, padded_end - payload_offset - h.payload_length, &err)) {
    r_.problems.push_back(where + ": payload padding: " + err);
  }
  auto sum = ChecksumRange(file_, payload_offset, h.payload_length, buffer_);
  if (!sum.ok()) {
    r_.problems.push_back(where + ": " + sum.status().message());
    return;
  }
  const uint64_t actual = *sum;
  if (actual != h.payload_checksum && h.type == static_cast<uint16_t>(FrameType::kIndex) &&
      &e == &scan_.frames.back() && scan_.chain_end == size_) {
    partial_index_ = &e;  // judged below, once the trailer is known: an interrupted seal, or damage
    return;
  }
  if (actual != h.payload_checksum) {
    r_.problems.push_back(where + ": payload checksum mismatch: expected=" + Hex64(h.payload_checksum) +
                          ", actual=" + Hex64(actual));
    return;
  }
  if (h.type == static_cast<uint16_t>(FrameType::kIndex)) {
    index_frame_ = &e;
    return;
  }
  if (h.type == static_cast<uint16_t>(FrameType::kPadding)) return;  // zeros (checked by the checksum)
  if (h.type == static_cast<uint16_t>(FrameType::kContentHash)) {
    // Its size follows from the metadata; a claim of any other size is not read (nor allocated).
    const size_t arrays = prelude_.metadata.arrays.size();
    Result<std::vector<uint64_t>> sums =
        DataLoss("content-hash frame of " + std::to_string(h.payload_length) + " bytes; " + std::to_string(arrays) +
                 " arrays take " + std::to_string(8 + 8 * arrays));
    if (h.payload_length == 8 + 8 * arrays) {
      std::vector<std::byte> payload(h.payload_length);
      Status read = file_.ReadAt(payload_offset, payload);
      sums = read.ok() ? DecodeContentHashRecord(payload, arrays) : Result<std::vector<uint64_t>>(read);
    }
    if (!sums.ok()) {
      r_.problems.push_back(where + ": " + sums.status().message());
    } else {
      recorded_sums_ = std::move(sums).value();
    }
    return;
  }
  if (h.type != static_cast<uint16_t>(FrameType::kChunk)) {
    if (h.flags & kFrameFlagOptional) {
      r_.notes.push_back(where + ": skipped optional frame of unknown type " + std::to_string(h.type));
    } else {
      r_.problems.push_back(where + ": unknown frame type " + std::to_string(h.type) +
                            " that is not optional (written by a newer ltbake?)");
    }
    return;
  }
  CheckChunkFrame(e, where);
}

// A chunk frame whose checksum verified: a chunk of an array this file owns, of the right
// lengths, with a payload that parses, committed once.
void Verification::CheckChunkFrame(const IndexEntry& e, const std::string& where) {
  const Metadata& meta = prelude_.metadata;
  const FrameHeader& h = e.header;
  if (h.array >= meta.arrays.size()) {
    r_.problems.push_back(where + ": array " + std::to_string(h.array) + " does not exist");
    return;
  }
  const ArraySpec& a = meta.arrays[h.array];
  if (h.chunk_index >= a.ChunkCount()) {
    r_.problems.push_back(where + ": out of range (" + std::to_string(a.ChunkCount()) + " chunks)");
    return;
  }
  if (!meta.Owns(h.array, h.chunk_index)) {
    r_.problems.push_back(where + ": chunk " + std::to_string(h.chunk_index) + " of array \"" + a.name +
                          "\" belongs to another shard (this is shard " + std::to_string(meta.shard->index) + " of " +
                          std::to_string(meta.shard->count) + ")");
    return;
  }
  Status len = CheckChunkLengths(h, a.ChunkBytes(h.chunk_index));
  if (!len.ok()) {
    r_.problems.push_back(where + ": " + len.message());
    return;
  }
  if (!CheckChunkPayload(h, a, e.frame_offset + kFrameHeaderSize, where)) return;
  uint64_t key = (uint64_t{h.array} << 40) | h.chunk_index;
  if (!seen_.insert(key).second) {
    r_.problems.push_back(where + ": committed twice");
    return;
  }
  chunk_frames_.push_back(e);
  r_.chunks_ok++;
}

// A zstd, sparse or coded payload parses (raw and zero payloads have nothing more to check).
bool Verification::CheckChunkPayload(const FrameHeader& h, const ArraySpec& a, uint64_t payload_offset,
                                     const std::string& where) {
  // Compressed payloads are parsed through a mapping, only once their checksum has been
  // read back with pread (so every byte of it is on disk) and the file still covers them.
  MappedRegion region;
  if (h.encoding == static_cast<uint16_t>(Encoding::kZstd) || h.encoding == static_cast<uint16_t>(Encoding::kSparse) ||
      h.encoding == static_cast<uint16_t>(Encoding::kSparseZstd) ||
      h.encoding == static_cast<uint16_t>(Encoding::kCoded)) {
    auto now = file_.Size();
    if (!now.ok() || *now < payload_offset + h.payload_length) {
      r_.problems.push_back(where + ": the file shrank to " + (now.ok() ? std::to_string(*now) : "?") +
                            " bytes while being verified (is a writer still working on it?)");
      return false;
    }
    auto mapped = MappedRegion::Map(file_.fd(), payload_offset, h.payload_length, true);
    if (!mapped.ok()) {
      r_.problems.push_back(where + ": " + mapped.status().message());
      return false;
    }
    region = std::move(mapped).value();
  }
  if (h.encoding == static_cast<uint16_t>(Encoding::kZstd)) {
    auto n = ZstdDecodedSize(region.bytes(), h.decoded_length);
    if (!n.ok() || *n != h.decoded_length) {
      r_.problems.push_back(where + ": " +
                            (n.ok() ? "zstd payload decodes to " + std::to_string(*n) + " bytes, expected " +
                                          std::to_string(h.decoded_length)
                                    : n.status().message()));
      return false;
    }
  }
  if (h.encoding == static_cast<uint16_t>(Encoding::kSparse) ||
      h.encoding == static_cast<uint16_t>(Encoding::kSparseZstd)) {
    // Parsed as a stream (zstd through a fixed window): nothing is materialized.
    Status s = CheckSparsePayload(static_cast<Encoding>(h.encoding), region.bytes(), a.dtype,
                                  a.Extent(h.chunk_index).Elements());
    if (!s.ok()) {
      r_.problems.push_back(where + ": " + s.message());
      return false;
    }
  }
  if (h.encoding == static_cast<uint16_t>(Encoding::kCoded)) {
    // Decoded with two lines of state; nothing is materialized.
    const ChunkExtent extent = a.Extent(h.chunk_index);
    Status s = CheckCodedChunkShape(a.dtype, CodedLineLength(a.layout, extent), extent.Elements());
    if (s.ok()) s = CheckCodedPayload(region.bytes(), CodedLineLength(a.layout, extent), extent.Elements());
    if (!s.ok()) {
      r_.problems.push_back(where + ": " + s.message());
      return false;
    }
  }
  return true;
}

// Seal: a valid trailer pointing at the index frame, whose entries match the scan. True
// when the file ends with a valid trailer (sealed or not).
bool Verification::CheckTrailer() {
  bool trailer_ok = false;
  if (size_ >= first_ + kTrailerSize) {
    std::array<std::byte, kTrailerSize> tb;
    if (file_.ReadAt(size_ - kTrailerSize, tb).ok()) {
      auto t = DecodeTrailer(tb, size_);
      if (t.ok()) {
        trailer_ok = true;
        if (index_frame_ == nullptr || index_frame_->frame_offset != t->index_offset) {
          r_.problems.push_back("trailer points at offset " + std::to_string(t->index_offset) +
                                ", where there is no valid index frame");
        } else if (scan_.chain_end != size_ - kTrailerSize) {
          r_.problems.push_back("bytes between the index frame and the trailer at offset " +
                                std::to_string(scan_.chain_end));
        } else {
          r_.sealed = true;
        }
      }
    }
  }
  return trailer_ok;
}

// The index frame (or its interrupted seal) and the uncommitted tail.
void Verification::CheckSeal(bool trailer_ok) {
  // The writer zero-extends the index frame's region, writes its header, then its payload,
  // then the trailer. A file that ends with the index frame and has no trailer was being
  // sealed when its writer stopped: that is an uncommitted tail (resuming redoes the seal),
  // not damage. Bytes after the index frame that are not a valid trailer are damage.
  bool index_is_tail = !trailer_ok && scan_.chain_end == size_;
  if (partial_index_ != nullptr) {
    if (index_is_tail) {
      r_.notes.push_back("index frame at offset " + std::to_string(partial_index_->frame_offset) +
                         " is incomplete: sealing was interrupted; resuming the writer redoes it");
      r_.uncommitted_tail_bytes = size_ - partial_index_->frame_offset;
    } else {
      r_.problems.push_back("frame at offset " + std::to_string(partial_index_->frame_offset) +
                            ": index payload checksum mismatch");
    }
  } else if (index_frame_ != nullptr) {
    if (index_is_tail) {
      r_.notes.push_back("index frame at offset " + std::to_string(index_frame_->frame_offset) +
                         " has no trailer: sealing was interrupted; resuming the writer redoes it");
      r_.uncommitted_tail_bytes = size_ - index_frame_->frame_offset;
    } else if (!trailer_ok) {
      r_.problems.push_back("index frame at offset " + std::to_string(index_frame_->frame_offset) +
                            " but no valid trailer at the end of the file (damaged or truncated)");
    }
    CheckIndexEntries();
  } else if (!r_.sealed) {
    r_.uncommitted_tail_bytes = size_ - std::min(size_, scan_.chain_end);
  }
}

// The index frame's entries against the chunk frames the scan found.
void Verification::CheckIndexEntries() {
  // Read, not mapped (see ChecksumRange); its length is within the file (DecodeFrameHeader).
  std::vector<std::byte> index(index_frame_->header.payload_length);
  Status read = file_.ReadAt(index_frame_->frame_offset + kFrameHeaderSize, index);
  auto entries =
      read.ok() ? DecodeIndex(index, first_, index_frame_->frame_offset) : Result<std::vector<IndexEntry>>(read);
  if (!entries.ok()) {
    r_.problems.push_back("index frame at offset " + std::to_string(index_frame_->frame_offset) + ": " +
                          entries.status().message());
  } else {
    std::set<std::pair<uint64_t, uint64_t>> listed, scanned;
    for (const IndexEntry& e : *entries) listed.insert({e.frame_offset, e.header.payload_checksum});
    for (const IndexEntry& e : scan_.frames)
      if (e.header.type == static_cast<uint16_t>(FrameType::kChunk))
        scanned.insert({e.frame_offset, e.header.payload_checksum});
    if (listed != scanned) {
      r_.problems.push_back("index lists " + std::to_string(listed.size()) + " chunk frames, the scan found " +
                            std::to_string(scanned.size()) + " (or at other offsets)");
    }
  }
}

VerifyReport Verification::Run() {
  if (!ReadPreludeChecked()) return r_;
  if (!ScanChain()) return r_;
  for (const IndexEntry& e : scan_.frames) CheckFrame(e);
  CheckSeal(CheckTrailer());
  if (r_.sealed && r_.chunks_ok != r_.chunks_expected) {
    r_.problems.push_back("sealed file has " + std::to_string(r_.chunks_ok) + " intact chunks of " +
                          std::to_string(r_.chunks_expected));
  }
  r_.complete = r_.sealed && r_.problems.empty() && r_.chunks_ok == r_.chunks_expected;
  if (r_.complete) CheckContentHashes();
  r_.complete = r_.complete && r_.problems.empty();
  return r_;
}

// Every array's content_hash from its decoded chunks, against the writer's record.
void Verification::CheckContentHashes() {
  const Metadata& meta = prelude_.metadata;
  r_.content_hash.assign(meta.arrays.size(), "");
  r_.recorded_content_hash.assign(meta.arrays.size(), "");
  r_.hash_sum.assign(meta.arrays.size(), 0);
  auto reader = ContainerReader::Open(r_.path);
  if (!reader.ok()) {
    r_.problems.push_back("cannot reopen to recompute content_hash: " + reader.status().message());
    return;
  }
  for (uint32_t a = 0; a < meta.arrays.size(); ++a) {
    const ArraySpec& spec = meta.arrays[a];
    if (!recorded_sums_.empty()) {
      ContentHasher rec;
      rec.AddSum(recorded_sums_[a]);
      r_.recorded_content_hash[a] = rec.Finish(spec);
    }
    if (spec.ChunkBytes(0) > kVerifyHashChunkBytes) {
      r_.notes.push_back("array \"" + spec.name + "\": content_hash not recomputed (chunks of " +
                         std::to_string(spec.ChunkBytes(0)) + " bytes, over verify's " +
                         std::to_string(kVerifyHashChunkBytes) + "-byte limit per chunk)");
      continue;
    }
    auto summary = SummarizeArray(*reader, a, threads_);
    if (!summary.ok()) {
      r_.problems.push_back("array \"" + spec.name +
                            "\": cannot recompute content_hash: " + summary.status().message());
      continue;
    }
    r_.content_hash[a] = summary->content_hash;
    r_.hash_sum[a] = summary->hash_sum;
    if (!r_.recorded_content_hash[a].empty() && r_.recorded_content_hash[a] != summary->content_hash) {
      r_.problems.push_back("array \"" + spec.name + "\": the writer recorded content_hash " +
                            r_.recorded_content_hash[a] + ", but the chunks hash to " + summary->content_hash +
                            " (the content-hash frame is wrong; rewrite the file)");
    }
  }
}

}  // namespace

VerifyReport VerifyContainer(const std::string& path, int threads) {
  if (LooksLikeManifest(path)) return VerifyManifest(path, threads);
  return Verification(path, threads).Run();
}

}  // namespace ltb::io
