#include "format/io/container_reader.h"

#include <fcntl.h>
#include <xxhash.h>

#include <algorithm>
#include <tuple>

#include "format/chunk_codec.h"
#include "format/content_hash.h"
#include "format/io/frame_scan.h"
#include "format/io/manifest.h"

namespace ltb::io {

using namespace ltb::format;

namespace {
uint64_t Key(uint32_t array, uint64_t chunk) { return (uint64_t{array} << 40) | chunk; }
}  // namespace

Result<ContainerPrelude> ReadPrelude(const File& file, uint64_t file_size) {
  ContainerPrelude p;
  std::array<std::byte, kHeaderSize> hb{};
  if (file_size >= kHeaderSize) LTB_RETURN_IF_ERROR(file.ReadAt(0, hb));
  LTB_ASSIGN_OR_RETURN(p.header,
                       DecodeFileHeader(ByteSpan(hb.data(), file_size >= kHeaderSize ? kHeaderSize : 0), file_size));
  // DecodeFileHeader has checked metadata_length against the cap and the file size.
  p.metadata_bytes.resize(p.header.metadata_length);
  LTB_RETURN_IF_ERROR(file.ReadAt(
      kHeaderSize, MutableByteSpan(reinterpret_cast<std::byte*>(p.metadata_bytes.data()), p.metadata_bytes.size())));
  ByteSpan mb(reinterpret_cast<const std::byte*>(p.metadata_bytes.data()), p.metadata_bytes.size());
  uint64_t actual = Checksum(mb);
  if (actual != p.header.metadata_checksum) {
    return DataLoss("metadata checksum mismatch: expected=" + Hex64(p.header.metadata_checksum) +
                    ", actual=" + Hex64(actual));
  }
  auto m = ParseMetadata(mb);
  if (!m.ok()) return m.status().WithContext("metadata");
  p.metadata = std::move(m).value();
  return p;
}

Result<ContainerReader> ContainerReader::Open(const std::string& path) {
  ContainerReader r;
  LTB_ASSIGN_OR_RETURN(r.file_, File::Open(path, File::Mode::kRead));
  LTB_ASSIGN_OR_RETURN(r.file_size_, r.file_.Size());
  if (LooksLikeManifest(path)) {
    LTB_RETURN_IF_ERROR(r.LoadManifest());
    return r;
  }
  auto prelude = ReadPrelude(r.file_, r.file_size_);
  if (!prelude.ok()) return prelude.status().WithContext(path);
  r.header_ = prelude->header;
  r.metadata_ = std::move(prelude->metadata);
  r.committed_.assign(r.metadata_.arrays.size(), 0);

  // A valid trailer means the file is sealed: read its index instead of scanning.
  bool loaded = false;
  if (r.file_size_ >= r.header_.FirstFrameOffset() + kTrailerSize) {
    std::array<std::byte, kTrailerSize> tb;
    LTB_RETURN_IF_ERROR(r.file_.ReadAt(r.file_size_ - kTrailerSize, tb));
    auto trailer = DecodeTrailer(tb, r.file_size_);
    if (trailer.ok() && trailer->index_offset >= r.header_.FirstFrameOffset()) {
      Status s = r.LoadFromIndex(trailer->index_offset);
      if (s.ok()) {
        r.sealed_ = true;
        loaded = true;
      } else {
        // Fall back to scanning; the damaged index is a problem to report.
        r.problems_.push_back("index: " + s.message() + " (read the file by scanning its frames instead)");
        r.chunk_frames_.clear();
        r.by_key_.clear();
        r.duplicated_.clear();
        r.committed_.assign(r.metadata_.arrays.size(), 0);
      }
    }
  }
  if (!loaded) {
    Status s = r.LoadByScan();
    if (!s.ok()) return s.WithContext(path);
  }
  return r;
}

Status ContainerReader::LoadFromIndex(uint64_t index_offset) {
  std::array<std::byte, kFrameHeaderSize> hb;
  LTB_RETURN_IF_ERROR(file_.ReadAt(index_offset, hb));
  LTB_ASSIGN_OR_RETURN(FrameHeader h, DecodeFrameHeader(hb, index_offset, file_size_));
  if (h.type != static_cast<uint16_t>(FrameType::kIndex)) return DataLoss("trailer does not point at an index frame");
  std::vector<std::byte> payload(h.payload_length);  // bounded by the file size (checked above)
  LTB_RETURN_IF_ERROR(file_.ReadAt(index_offset + kFrameHeaderSize, payload));
  uint64_t actual = Checksum(payload);
  if (actual != h.payload_checksum) {
    return DataLoss("index payload checksum mismatch: expected=" + Hex64(h.payload_checksum) +
                    ", actual=" + Hex64(actual));
  }
  LTB_ASSIGN_OR_RETURN(std::vector<IndexEntry> entries, DecodeIndex(payload, header_.FirstFrameOffset(), index_offset));
  for (const IndexEntry& e : entries) AddFrame(e);
  scan_end_ = index_offset;
  LoadContentHashRecord(index_offset);
  return Status::Ok();
}

// The content-hash frame ends where the index frame starts. Anything else there (a file
// written before the frame existed, damage) leaves the record empty: readers then compute
// content_hash from the chunks, as before.
void ContainerReader::LoadContentHashRecord(uint64_t index_offset) {
  const uint64_t size = ContentHashFrameSize(metadata_.arrays.size());
  if (index_offset < header_.FirstFrameOffset() + size) return;
  const uint64_t at = index_offset - size;
  std::array<std::byte, kFrameHeaderSize> hb;
  if (!file_.ReadAt(at, hb).ok()) return;
  auto h = DecodeFrameHeader(hb, at, file_size_);
  if (!h.ok() || h->type != static_cast<uint16_t>(FrameType::kContentHash) || h->FrameSize() != size) return;
  std::vector<std::byte> payload(h->payload_length);  // at most 8 + 8·255 bytes (FrameSize checked)
  if (!file_.ReadAt(at + kFrameHeaderSize, payload).ok() || Checksum(payload) != h->payload_checksum) return;
  auto sums = DecodeContentHashRecord(payload, metadata_.arrays.size());
  if (sums.ok()) recorded_sums_ = std::move(sums).value();
}

std::optional<uint64_t> ContainerReader::RecordedHashSum(uint32_t array) const {
  if (array >= metadata_.arrays.size()) return std::nullopt;
  if (!parts_.empty()) {
    uint64_t sum = 0;
    for (const auto& p : parts_) {
      auto s = p->RecordedHashSum(array);
      if (!s) return std::nullopt;
      sum += *s;
    }
    return sum;
  }
  if (!sealed_ || recorded_sums_.empty()) return std::nullopt;
  return recorded_sums_[array];
}

std::string ContainerReader::RecordedContentHash(uint32_t array) const {
  auto sum = RecordedHashSum(array);
  if (!sum) return "";
  ContentHasher h;
  h.AddSum(*sum);
  return h.Finish(metadata_.arrays[array]);
}

Status ContainerReader::LoadByScan() {
  LTB_ASSIGN_OR_RETURN(ScanResult scan, ScanFrames(file_, header_.FirstFrameOffset(), file_size_));
  for (const ScanGap& g : scan.gaps) {
    problems_.push_back("damaged region at offset " + std::to_string(g.offset) + " (" + g.reason +
                        "); next valid frame at offset " + std::to_string(g.resume));
  }
  for (const IndexEntry& e : scan.frames) {
    if (e.header.type == static_cast<uint16_t>(FrameType::kChunk)) {
      AddFrame(e);
    } else if (e.header.type == static_cast<uint16_t>(FrameType::kIndex)) {
      // An index without a valid trailer: sealing was interrupted, or the trailer is damaged.
    } else if ((e.header.flags & kFrameFlagOptional) == 0) {
      return Unimplemented("frame at offset " + std::to_string(e.frame_offset) + " has type " +
                           std::to_string(e.header.type) +
                           ", which this build does not know and which is not optional — upgrade ltbake");
    }
  }
  scan_end_ = scan.chain_end;
  tail_bytes_ = file_size_ - std::min(file_size_, scan.chain_end);
  return Status::Ok();
}

void ContainerReader::AddFrame(const IndexEntry& e) {
  const FrameHeader& h = e.header;
  std::string where = "frame at offset " + std::to_string(e.frame_offset);
  if (h.type != static_cast<uint16_t>(FrameType::kChunk)) return;
  if (h.array >= metadata_.arrays.size()) {
    problems_.push_back(where + ": array " + std::to_string(h.array) + " does not exist (the metadata lists " +
                        std::to_string(metadata_.arrays.size()) + ")");
    return;
  }
  const ArraySpec& a = metadata_.arrays[h.array];
  if (h.chunk_index >= a.ChunkCount()) {
    problems_.push_back(where + ": chunk " + std::to_string(h.chunk_index) + " of array \"" + a.name +
                        "\" is out of range (it has " + std::to_string(a.ChunkCount()) + " chunks)");
    return;
  }
  if (!metadata_.Owns(h.array, h.chunk_index)) {
    problems_.push_back(where + ": " + ChunkName(h.array, h.chunk_index) + " belongs to another shard (this is shard " +
                        std::to_string(metadata_.shard->index) + " of " + std::to_string(metadata_.shard->count) + ")");
    return;
  }
  Status len = CheckChunkLengths(h, a.ChunkBytes(h.chunk_index));
  if (!len.ok()) {
    problems_.push_back(where + ": " + ChunkName(h.array, h.chunk_index) + ": " + len.message());
    return;
  }
  uint64_t key = Key(h.array, h.chunk_index);
  if (by_key_.count(key) != 0) {
    problems_.push_back(where + ": " + ChunkName(h.array, h.chunk_index) +
                        " committed twice (neither copy is read: which one is right is unknown)");
    duplicated_.insert(key);
    return;
  }
  by_key_[key] = chunk_frames_.size();
  chunk_frames_.push_back(e);
  committed_[h.array] += 1;
}

std::string ContainerReader::ChunkName(uint32_t array, uint64_t chunk) const {
  const ArraySpec& a = metadata_.arrays[array];
  ChunkExtent e = a.Extent(chunk);
  std::string range = a.layout == Layout::kRows
                          ? "rows " + std::to_string(e.row0) + "-" + std::to_string(e.row0 + e.rows - 1)
                          : "cols " + std::to_string(e.col0) + "-" + std::to_string(e.col0 + e.cols - 1);
  return "array \"" + a.name + "\" chunk " + std::to_string(chunk) + " (" + range + ")";
}

bool ContainerReader::complete() const {
  for (size_t i = 0; i < metadata_.arrays.size(); ++i)
    if (committed_[i] != metadata_.OwnedChunks(static_cast<uint32_t>(i))) return false;
  return true;
}

const IndexEntry* ContainerReader::Find(uint32_t array, uint64_t chunk) const {
  auto it = by_key_.find(Key(array, chunk));
  return it == by_key_.end() ? nullptr : &chunk_frames_[it->second];
}

Result<const IndexEntry*> ContainerReader::Locate(uint32_t array, uint64_t chunk, std::string* where) const {
  if (array >= metadata_.arrays.size()) return InvalidArgument("no array " + std::to_string(array));
  const ArraySpec& a = metadata_.arrays[array];
  if (chunk >= a.ChunkCount()) {
    return InvalidArgument(path() + ": chunk " + std::to_string(chunk) + " of array \"" + a.name + "\" out of range (" +
                           std::to_string(a.ChunkCount()) + " chunks)");
  }
  const IndexEntry* e = Find(array, chunk);
  *where = path() + ": " + ChunkName(array, chunk);
  if (duplicated_.count(Key(array, chunk)) != 0) {
    return DataLoss(*where +
                    " is committed twice in the file (a damaged or forged file: no ltbake writer does that); which "
                    "copy is right is unknown, so neither is read. Run `ltbake verify " +
                    path() + "` and rewrite the file with the stage that made it");
  }
  if (e == nullptr) {
    return NotFound(*where +
                    " is missing (never committed; the file is incomplete — rerun the stage that writes it to resume)");
  }
  return e;
}

void ContainerReader::Readahead(const IndexEntry* e, const ReadOptions& options) const {
  if (!options.sequential || options.readahead_chunks == 0) return;
  // chunk_frames_ is in file order; ask the kernel for the next frames of the same array.
  // Only those: stages interleave arrays in the file (sample writes a row block's matrix
  // chunk beside its side-table chunks), and reading a side table in order must not pull
  // the matrix chunks between its frames into the page cache (at R = 64 that read the
  // whole 4.6 GB matrix before transpose started, to be evicted again in a 2 GiB cgroup).
  constexpr size_t kScan = 64;  // frames looked at beyond this one
  const size_t slot = static_cast<size_t>(e - chunk_frames_.data());
  size_t found = 0;
  for (size_t k = slot + 1; k < chunk_frames_.size() && k <= slot + kScan && found < options.readahead_chunks; ++k) {
    const IndexEntry& next = chunk_frames_[k];
    if (next.header.array != e->header.array) continue;
    const uint64_t to = std::min(next.frame_offset + next.header.FrameSize(), file_size_);
    ::posix_fadvise(file_.fd(), static_cast<off_t>(next.frame_offset), static_cast<off_t>(to - next.frame_offset),
                    POSIX_FADV_WILLNEED);
    ++found;
  }
}

Result<MappedRegion> ContainerReader::MapPayload(const IndexEntry& e, const std::string& where, bool sequential,
                                                 bool verify) const {
  uint64_t payload_offset = e.frame_offset + kFrameHeaderSize;
  auto region = MappedRegion::Map(file_.fd(), payload_offset, e.header.payload_length, sequential);
  if (!region.ok()) return region.status().WithContext(where);
  if (verify) {
    uint64_t actual = Checksum(region->bytes());
    if (actual != e.header.payload_checksum) {
      return DataLoss(where + " at offset " + std::to_string(payload_offset) + ": checksum mismatch: expected=" +
                      Hex64(e.header.payload_checksum) + ", actual=" + Hex64(actual));
    }
  }
  return region;
}

const ContainerReader* ContainerReader::PartOf(uint32_t array, uint64_t chunk) const {
  if (parts_.empty()) return nullptr;
  auto it = by_key_.find(Key(array, chunk));
  return it == by_key_.end() ? nullptr : parts_[frame_part_[it->second]].get();
}

Status ContainerReader::InShard(const ContainerReader* part, const Status& s) const {
  if (s.ok()) return s;
  const auto& info = part->metadata().shard;
  return s.WithContext(path() + ": shard " + std::to_string(info ? info->index : 0) + " of " +
                       std::to_string(parts_.size()));
}

Result<Chunk> ContainerReader::ReadChunk(uint32_t array, uint64_t chunk, const ReadOptions& options) const {
  if (const ContainerReader* part = PartOf(array, chunk)) {
    auto r = part->ReadChunk(array, chunk, options);
    if (!r.ok()) return InShard(part, r.status());
    return r;
  }
  std::string where;
  LTB_ASSIGN_OR_RETURN(const IndexEntry* e, Locate(array, chunk, &where));
  const ArraySpec& a = metadata_.arrays[array];
  const FrameHeader& h = e->header;
  Readahead(e, options);
  Chunk c;
  c.encoding_ = static_cast<Encoding>(h.encoding);
  c.extent_ = a.Extent(chunk);
  switch (c.encoding_) {
    case Encoding::kZero:
      c.owned_.assign(h.decoded_length, std::byte{0});
      return c;
    case Encoding::kRaw: {
      LTB_ASSIGN_OR_RETURN(c.region_, MapPayload(*e, where, options.sequential, options.verify_checksum));
      return c;
    }
    case Encoding::kZstd:
    case Encoding::kSparse:
    case Encoding::kSparseZstd:
    case Encoding::kCoded: {
      // Refused before the dense buffer is allocated.
      if (c.encoding_ != Encoding::kZstd && c.extent_.Elements() > kMaxSparseElements) {
        return DataLoss(where + ": a chunk of " + std::to_string(c.extent_.Elements()) +
                        " elements cannot be sparse (at most " + std::to_string(kMaxSparseElements) + ")");
      }
      if (c.encoding_ == Encoding::kCoded) {
        Status s = CheckCodedChunkShape(a.dtype, CodedLineLength(a.layout, c.extent_), c.extent_.Elements());
        if (!s.ok()) return s.WithContext(where);
      }
      // Decoded payloads are always checked: decoding damaged bytes could mislead.
      LTB_ASSIGN_OR_RETURN(MappedRegion region, MapPayload(*e, where, options.sequential, true));
      c.owned_.resize(h.decoded_length);  // checked against the metadata's chunk size at open
      Status s = c.encoding_ == Encoding::kZstd     ? DecodeZstd(region.bytes(), c.owned_)
                 : c.encoding_ == Encoding::kSparse ? DecodeSparseInto(region.bytes(), a.dtype, c.owned_)
                 : c.encoding_ == Encoding::kSparseZstd
                     ? DecodeSparseZstdInto(region.bytes(), a.dtype, c.owned_)
                     : DecodeCodedInto(region.bytes(), CodedLineLength(a.layout, c.extent_), c.owned_);
      if (!s.ok()) return s.WithContext(where);
      return c;
    }
  }
  return Internal(where + ": unhandled encoding");
}

Result<SparseChunk> ContainerReader::ReadSparse(uint32_t array, uint64_t chunk, const ReadOptions& options) const {
  if (const ContainerReader* part = PartOf(array, chunk)) {
    auto r = part->ReadSparse(array, chunk, options);
    if (!r.ok()) return InShard(part, r.status());
    return r;
  }
  std::string where;
  LTB_ASSIGN_OR_RETURN(const IndexEntry* e, Locate(array, chunk, &where));
  const ArraySpec& a = metadata_.arrays[array];
  const Encoding encoding = static_cast<Encoding>(e->header.encoding);
  SparseChunk out;
  out.extent = a.Extent(chunk);
  out.dtype = a.dtype;
  const uint64_t elements = out.extent.Elements();
  if (encoding == Encoding::kSparse || encoding == Encoding::kSparseZstd) {
    Readahead(e, options);
    LTB_ASSIGN_OR_RETURN(MappedRegion region, MapPayload(*e, where, options.sequential, true));
    Status s = encoding == Encoding::kSparse ? DecodeSparsePayload(region.bytes(), a.dtype, elements, &out)
                                             : DecodeSparseZstdPayload(region.bytes(), a.dtype, elements, &out);
    if (!s.ok()) return s.WithContext(where);
    return out;
  }
  if (encoding == Encoding::kCoded) {
    if (Status s = CheckCodedChunkShape(a.dtype, CodedLineLength(a.layout, out.extent), elements); !s.ok()) {
      return s.WithContext(where);
    }
    Readahead(e, options);
    LTB_ASSIGN_OR_RETURN(MappedRegion region, MapPayload(*e, where, options.sequential, true));
    Status s = DecodeCodedPayload(region.bytes(), CodedLineLength(a.layout, out.extent), elements, &out);
    if (!s.ok()) return s.WithContext(where);
    return out;
  }
  if (elements > kMaxSparseElements) {
    return InvalidArgument(where + " has " + std::to_string(elements) +
                           " elements, more than a sparse chunk indexes (" + std::to_string(kMaxSparseElements) +
                           "); read it with ReadChunk");
  }
  if (encoding == Encoding::kZero) return out;
  LTB_ASSIGN_OR_RETURN(Chunk dense, ReadChunk(array, chunk, options));
  Status s = SparseFromDense(dense.bytes(), a.dtype, &out);
  if (!s.ok()) return s.WithContext(where);
  return out;
}

Status ContainerReader::VerifyChunk(uint32_t array, uint64_t chunk, MutableByteSpan buffer) const {
  if (const ContainerReader* part = PartOf(array, chunk)) return InShard(part, part->VerifyChunk(array, chunk, buffer));
  const IndexEntry* e = Find(array, chunk);
  if (e == nullptr) return NotFound(path() + ": " + ChunkName(array, chunk) + " is missing");
  if (buffer.empty()) return InvalidArgument("VerifyChunk needs a non-empty buffer");
  XXH3_state_t* st = XXH3_createState();
  XXH3_64bits_reset(st);
  uint64_t offset = e->frame_offset + kFrameHeaderSize, left = e->header.payload_length;
  Status s;
  while (left > 0 && s.ok()) {
    uint64_t n = std::min<uint64_t>(left, buffer.size());
    s = file_.ReadAt(offset, buffer.subspan(0, n));
    if (s.ok()) XXH3_64bits_update(st, buffer.data(), n);
    offset += n;
    left -= n;
  }
  uint64_t actual = XXH3_64bits_digest(st);
  XXH3_freeState(st);
  LTB_RETURN_IF_ERROR(s);
  if (actual != e->header.payload_checksum) {
    return DataLoss(path() + ": " + ChunkName(array, chunk) + " at offset " +
                    std::to_string(e->frame_offset + kFrameHeaderSize) +
                    ": checksum mismatch: expected=" + Hex64(e->header.payload_checksum) + ", actual=" + Hex64(actual));
  }
  return Status::Ok();
}

Result<EncodedChunk> ContainerReader::ReadEncoded(uint32_t array, uint64_t chunk) const {
  if (const ContainerReader* part = PartOf(array, chunk)) {
    auto r = part->ReadEncoded(array, chunk);
    if (!r.ok()) return InShard(part, r.status());
    return r;
  }
  std::string where;
  LTB_ASSIGN_OR_RETURN(const IndexEntry* e, Locate(array, chunk, &where));
  EncodedChunk out;
  out.encoding = static_cast<Encoding>(e->header.encoding);
  out.decoded_length = e->header.decoded_length;
  out.dtype = metadata_.arrays[array].dtype;
  out.line_length = CodedLineLength(metadata_.arrays[array].layout, metadata_.arrays[array].Extent(chunk));
  out.checksum = e->header.payload_checksum;
  if (e->header.payload_length > 0) {
    LTB_ASSIGN_OR_RETURN(MappedRegion region, MapPayload(*e, where, true, true));
    out.owned.assign(region.bytes().begin(), region.bytes().end());
  }
  out.payload = out.owned;
  return out;
}

std::string IndexFingerprint(const ContainerReader& reader) {
  struct Entry {
    uint32_t array;
    uint64_t chunk;
    uint16_t encoding;
    uint64_t checksum;
  };
  std::vector<Entry> entries;
  for (const auto& e : reader.chunk_frames()) {
    entries.push_back({e.header.array, e.header.chunk_index, e.header.encoding, e.header.payload_checksum});
  }
  std::sort(entries.begin(), entries.end(),
            [](const Entry& a, const Entry& b) { return std::tie(a.array, a.chunk) < std::tie(b.array, b.chunk); });
  XXH3_state_t* st = XXH3_createState();
  XXH3_64bits_reset(st);
  std::string meta = SerializeMetadata(reader.metadata().json);
  XXH3_64bits_update(st, meta.data(), meta.size());
  for (const Entry& e : entries) {
    XXH3_64bits_update(st, &e.array, sizeof e.array);
    XXH3_64bits_update(st, &e.chunk, sizeof e.chunk);
    XXH3_64bits_update(st, &e.encoding, sizeof e.encoding);
    XXH3_64bits_update(st, &e.checksum, sizeof e.checksum);
  }
  uint64_t h = XXH3_64bits_digest(st);
  XXH3_freeState(st);
  return Hex64(h).substr(2);
}

Status ContainerReader::Refresh() {
  if (sealed_) return Status::Ok();
  auto reopened = Open(path());
  if (!reopened.ok()) return reopened.status();
  *this = std::move(reopened).value();
  return Status::Ok();
}

}  // namespace ltb::io
