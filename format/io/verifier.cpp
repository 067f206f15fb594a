#include "format/io/verifier.h"

#include <xxhash.h>

#include <set>

#include "format/array_spec.h"
#include "format/chunk_codec.h"
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

}  // namespace

VerifyReport VerifyContainer(const std::string& path) {
  if (LooksLikeManifest(path)) return VerifyManifest(path);
  VerifyReport r;
  r.path = path;
  auto file = File::Open(path, File::Mode::kRead);
  if (!file.ok()) {
    r.problems.push_back(file.status().message());
    return r;
  }
  auto size_or = file->Size();
  if (!size_or.ok()) {
    r.problems.push_back(size_or.status().message());
    return r;
  }
  uint64_t size = *size_or;
  auto prelude = ReadPrelude(*file, size);
  if (!prelude.ok()) {
    r.problems.push_back(prelude.status().message());
    return r;
  }
  r.readable = true;
  const Metadata& meta = prelude->metadata;
  for (uint32_t a = 0; a < meta.arrays.size(); ++a) r.chunks_expected += meta.OwnedChunks(a);
  uint64_t first = prelude->header.FirstFrameOffset();
  std::string err;
  if (first > size) {
    r.problems.push_back("file ends at " + std::to_string(size) + " inside the metadata padding (truncated)");
    return r;
  }
  if (!RangeIsZero(*file, kHeaderSize + prelude->header.metadata_length,
                   first - kHeaderSize - prelude->header.metadata_length, &err)) {
    r.problems.push_back("metadata padding: " + err);
  }

  auto scan = ScanFrames(*file, first, size);
  if (!scan.ok()) {
    r.problems.push_back(scan.status().message());
    return r;
  }
  for (const ScanGap& g : scan->gaps) {
    r.problems.push_back("offset " + std::to_string(g.offset) + ": " + g.reason + " (" +
                         std::to_string(g.resume - g.offset) + " unreadable bytes; next valid frame at offset " +
                         std::to_string(g.resume) + ")");
  }

  std::set<uint64_t> seen;
  std::vector<std::byte> buffer;  // for positional reads of payloads
  std::vector<IndexEntry> chunk_frames;
  const IndexEntry* index_frame = nullptr;
  const IndexEntry* partial_index = nullptr;  // last frame: an index whose payload does not verify
  for (const IndexEntry& e : scan->frames) {
    const FrameHeader& h = e.header;
    std::string where = "frame at offset " + std::to_string(e.frame_offset);
    if (h.type == static_cast<uint16_t>(FrameType::kChunk) && h.array < meta.arrays.size()) {
      where += " (array \"" + meta.arrays[h.array].name + "\" chunk " + std::to_string(h.chunk_index) + ")";
    }
    uint64_t payload_offset = e.frame_offset + kFrameHeaderSize;
    uint64_t padded_end = std::min(size, e.frame_offset + h.FrameSize());
    if (index_frame != nullptr) {
      r.problems.push_back(where + ": frame after the index frame at offset " +
                           std::to_string(index_frame->frame_offset));
    }
    if (!RangeIsZero(*file, payload_offset + h.payload_length, padded_end - payload_offset - h.payload_length, &err)) {
      r.problems.push_back(where + ": payload padding: " + err);
    }
    auto sum = ChecksumRange(*file, payload_offset, h.payload_length, buffer);
    if (!sum.ok()) {
      r.problems.push_back(where + ": " + sum.status().message());
      continue;
    }
    const uint64_t actual = *sum;
    if (actual != h.payload_checksum && h.type == static_cast<uint16_t>(FrameType::kIndex) &&
        &e == &scan->frames.back() && scan->chain_end == size) {
      partial_index = &e;  // judged below, once the trailer is known: an interrupted seal, or damage
      continue;
    }
    if (actual != h.payload_checksum) {
      r.problems.push_back(where + ": payload checksum mismatch: expected=" + Hex64(h.payload_checksum) +
                           ", actual=" + Hex64(actual));
      continue;
    }
    if (h.type == static_cast<uint16_t>(FrameType::kIndex)) {
      index_frame = &e;
      continue;
    }
    if (h.type == static_cast<uint16_t>(FrameType::kPadding)) continue;  // zeros (checked by the checksum)
    if (h.type != static_cast<uint16_t>(FrameType::kChunk)) {
      if (h.flags & kFrameFlagOptional) {
        r.notes.push_back(where + ": skipped optional frame of unknown type " + std::to_string(h.type));
      } else {
        r.problems.push_back(where + ": unknown frame type " + std::to_string(h.type) +
                             " that is not optional (written by a newer ltbake?)");
      }
      continue;
    }
    if (h.array >= meta.arrays.size()) {
      r.problems.push_back(where + ": array " + std::to_string(h.array) + " does not exist");
      continue;
    }
    const ArraySpec& a = meta.arrays[h.array];
    if (h.chunk_index >= a.ChunkCount()) {
      r.problems.push_back(where + ": out of range (" + std::to_string(a.ChunkCount()) + " chunks)");
      continue;
    }
    if (!meta.Owns(h.array, h.chunk_index)) {
      r.problems.push_back(where + ": chunk " + std::to_string(h.chunk_index) + " of array \"" + a.name +
                           "\" belongs to another shard (this is shard " + std::to_string(meta.shard->index) + " of " +
                           std::to_string(meta.shard->count) + ")");
      continue;
    }
    Status len = CheckChunkLengths(h, a.ChunkBytes(h.chunk_index));
    if (!len.ok()) {
      r.problems.push_back(where + ": " + len.message());
      continue;
    }
    // Compressed payloads are parsed through a mapping, only once their checksum has been
    // read back with pread (so every byte of it is on disk) and the file still covers them.
    MappedRegion region;
    if (h.encoding == static_cast<uint16_t>(Encoding::kZstd) ||
        h.encoding == static_cast<uint16_t>(Encoding::kSparse) ||
        h.encoding == static_cast<uint16_t>(Encoding::kSparseZstd)) {
      auto now = file->Size();
      if (!now.ok() || *now < payload_offset + h.payload_length) {
        r.problems.push_back(where + ": the file shrank to " + (now.ok() ? std::to_string(*now) : "?") +
                             " bytes while being verified (is a writer still working on it?)");
        continue;
      }
      auto mapped = MappedRegion::Map(file->fd(), payload_offset, h.payload_length, true);
      if (!mapped.ok()) {
        r.problems.push_back(where + ": " + mapped.status().message());
        continue;
      }
      region = std::move(mapped).value();
    }
    if (h.encoding == static_cast<uint16_t>(Encoding::kZstd)) {
      auto n = ZstdDecodedSize(region.bytes(), h.decoded_length);
      if (!n.ok() || *n != h.decoded_length) {
        r.problems.push_back(where + ": " +
                             (n.ok() ? "zstd payload decodes to " + std::to_string(*n) + " bytes, expected " +
                                           std::to_string(h.decoded_length)
                                     : n.status().message()));
        continue;
      }
    }
    if (h.encoding == static_cast<uint16_t>(Encoding::kSparse) ||
        h.encoding == static_cast<uint16_t>(Encoding::kSparseZstd)) {
      // Parsed as a stream (zstd through a fixed window): nothing is materialized.
      Status s = CheckSparsePayload(static_cast<Encoding>(h.encoding), region.bytes(), a.dtype,
                                    a.Extent(h.chunk_index).Elements());
      if (!s.ok()) {
        r.problems.push_back(where + ": " + s.message());
        continue;
      }
    }
    uint64_t key = (uint64_t{h.array} << 40) | h.chunk_index;
    if (!seen.insert(key).second) {
      r.problems.push_back(where + ": committed twice");
      continue;
    }
    chunk_frames.push_back(e);
    r.chunks_ok++;
  }

  // Seal: a valid trailer pointing at the index frame, whose entries match the scan.
  bool trailer_ok = false;
  if (size >= first + kTrailerSize) {
    std::array<std::byte, kTrailerSize> tb;
    if (file->ReadAt(size - kTrailerSize, tb).ok()) {
      auto t = DecodeTrailer(tb, size);
      if (t.ok()) {
        trailer_ok = true;
        if (index_frame == nullptr || index_frame->frame_offset != t->index_offset) {
          r.problems.push_back("trailer points at offset " + std::to_string(t->index_offset) +
                               ", where there is no valid index frame");
        } else if (scan->chain_end != size - kTrailerSize) {
          r.problems.push_back("bytes between the index frame and the trailer at offset " +
                               std::to_string(scan->chain_end));
        } else {
          r.sealed = true;
        }
      }
    }
  }
  // The writer zero-extends the index frame's region, writes its header, then its payload,
  // then the trailer. A file that ends with the index frame and has no trailer was being
  // sealed when its writer stopped: that is an uncommitted tail (resuming redoes the seal),
  // not damage. Bytes after the index frame that are not a valid trailer are damage.
  bool index_is_tail = !trailer_ok && scan->chain_end == size;
  if (partial_index != nullptr) {
    if (index_is_tail) {
      r.notes.push_back("index frame at offset " + std::to_string(partial_index->frame_offset) +
                        " is incomplete: sealing was interrupted; resuming the writer redoes it");
      r.uncommitted_tail_bytes = size - partial_index->frame_offset;
    } else {
      r.problems.push_back("frame at offset " + std::to_string(partial_index->frame_offset) +
                           ": index payload checksum mismatch");
    }
  } else if (index_frame != nullptr) {
    if (index_is_tail) {
      r.notes.push_back("index frame at offset " + std::to_string(index_frame->frame_offset) +
                        " has no trailer: sealing was interrupted; resuming the writer redoes it");
      r.uncommitted_tail_bytes = size - index_frame->frame_offset;
    } else if (!trailer_ok) {
      r.problems.push_back("index frame at offset " + std::to_string(index_frame->frame_offset) +
                           " but no valid trailer at the end of the file (damaged or truncated)");
    }
    // Read, not mapped (see ChecksumRange); its length is within the file (DecodeFrameHeader).
    std::vector<std::byte> index(index_frame->header.payload_length);
    Status read = file->ReadAt(index_frame->frame_offset + kFrameHeaderSize, index);
    auto entries =
        read.ok() ? DecodeIndex(index, first, index_frame->frame_offset) : Result<std::vector<IndexEntry>>(read);
    if (!entries.ok()) {
      r.problems.push_back("index frame at offset " + std::to_string(index_frame->frame_offset) + ": " +
                           entries.status().message());
    } else {
      std::set<std::pair<uint64_t, uint64_t>> listed, scanned;
      for (const IndexEntry& e : *entries) listed.insert({e.frame_offset, e.header.payload_checksum});
      for (const IndexEntry& e : scan->frames)
        if (e.header.type == static_cast<uint16_t>(FrameType::kChunk))
          scanned.insert({e.frame_offset, e.header.payload_checksum});
      if (listed != scanned) {
        r.problems.push_back("index lists " + std::to_string(listed.size()) + " chunk frames, the scan found " +
                             std::to_string(scanned.size()) + " (or at other offsets)");
      }
    }
  } else if (!r.sealed) {
    r.uncommitted_tail_bytes = size - std::min(size, scan->chain_end);
  }
  if (r.sealed && r.chunks_ok != r.chunks_expected) {
    r.problems.push_back("sealed file has " + std::to_string(r.chunks_ok) + " intact chunks of " +
                         std::to_string(r.chunks_expected));
  }
  r.complete = r.sealed && r.problems.empty() && r.chunks_ok == r.chunks_expected;
  return r;
}

}  // namespace ltb::io
