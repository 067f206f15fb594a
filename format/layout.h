// Fixed-size on-disk structures of the .ltm container and their codecs (byte spans in,
// structs out). No I/O here; see format/io/ for files and mappings. Spec: docs/FORMAT.md.
#pragma once

#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "format/bytes.h"
#include "format/status.h"

namespace ltb::format {

inline constexpr std::array<unsigned char, 8> kFileMagic = {0x89, 'L', 'T', 'M', '\r', '\n', 0x1a, '\n'};
inline constexpr uint64_t kHeaderSize = 64;
inline constexpr uint64_t kFrameHeaderSize = 64;
inline constexpr uint64_t kTrailerSize = 64;
inline constexpr uint64_t kAlignment = 64;                 // every frame and payload starts on this boundary
inline constexpr uint64_t kMaxMetadataBytes = 1ull << 20;  // metadata is descriptive; tables go in chunks
inline constexpr uint32_t kFrameMagic = 0x464D544C;        // "LTMF"
inline constexpr std::array<unsigned char, 8> kTrailerMagic = {'L', 'T', 'M', 'T', 'R', 'A', 'I', 'L'};

// kPadding (written with the optional flag, so every 1.x reader skips it): zeros that put
// the next frame's payload on a kDirectAlignment boundary for direct I/O. kContentHash
// (optional too): the writer's record of every array's content_hash sum, written at
// sealing directly before the index frame.
enum class FrameType : uint16_t { kChunk = 1, kIndex = 2, kPadding = 3, kContentHash = 4 };
inline constexpr uint64_t kDirectAlignment = 4096;
inline constexpr uint16_t kFrameFlagOptional = 1;  // readers skip unknown optional frames

// Chunk payload encodings (docs/FORMAT.md "Frames"). kSparse and kSparseZstd arrived in
// format 1.1 (kMinorSparse), kCoded (i32 chunks only) in 1.2 (kMinorCoded); an older reader
// refuses them as unknown encodings.
enum class Encoding : uint16_t { kRaw = 0, kZero = 1, kZstd = 2, kSparse = 3, kSparseZstd = 4, kCoded = 5 };
const char* EncodingName(Encoding e);
bool IsKnownEncoding(uint16_t e);

struct FileHeader {
  uint16_t major = 0;
  uint16_t minor = 0;
  uint64_t required_features = 0;
  uint64_t optional_features = 0;
  uint64_t metadata_length = 0;
  uint64_t metadata_checksum = 0;

  // Offset of the first frame: after header and metadata, aligned.
  uint64_t FirstFrameOffset() const { return AlignUp(kHeaderSize + metadata_length, kAlignment); }
};

std::array<std::byte, kHeaderSize> EncodeFileHeader(const FileHeader& h);
// Checks magic, version (refusing a newer major with a message naming both versions),
// required features, header checksum, and that the metadata fits in file_size.
Result<FileHeader> DecodeFileHeader(ByteSpan bytes, uint64_t file_size);

struct FrameHeader {
  uint16_t type = 0;
  uint16_t flags = 0;
  uint64_t payload_length = 0;  // stored bytes, before padding
  uint32_t array = 0;
  uint16_t encoding = 0;
  uint64_t chunk_index = 0;
  uint64_t decoded_length = 0;
  uint64_t payload_checksum = 0;

  // Header plus payload padded to kAlignment. Call only on decoded (range-checked) headers.
  uint64_t FrameSize() const { return kFrameHeaderSize + AlignUp(payload_length, kAlignment); }
};

std::array<std::byte, kFrameHeaderSize> EncodeFrameHeader(const FrameHeader& h);
// Checks magic, header checksum and reserved fields, and that the frame starting at
// frame_offset fits in file_size. Does not check the payload.
Result<FrameHeader> DecodeFrameHeader(ByteSpan bytes, uint64_t frame_offset, uint64_t file_size);

struct Trailer {
  uint64_t index_offset = 0;
  uint64_t file_length = 0;
};
std::array<std::byte, kTrailerSize> EncodeTrailer(const Trailer& t);
Result<Trailer> DecodeTrailer(ByteSpan bytes, uint64_t file_size);

// Index payload: u64 count, then count × (u64 frame offset, 64-byte frame header copy).
inline constexpr uint64_t kIndexEntrySize = 8 + kFrameHeaderSize;
struct IndexEntry {
  uint64_t frame_offset = 0;
  FrameHeader header;
};
std::vector<std::byte> EncodeIndex(const std::vector<IndexEntry>& entries);
// Every entry's frame must lie inside [first_frame_offset, file_size).
Result<std::vector<IndexEntry>> DecodeIndex(ByteSpan payload, uint64_t first_frame_offset, uint64_t file_size);

// Content-hash frame payload: u32 version (1), u32 count (= the metadata's arrays), then
// count × u64 content_hash sum (ContentHasher::sum) of each array in metadata order.
inline constexpr uint32_t kContentHashRecordVersion = 1;
std::vector<std::byte> EncodeContentHashRecord(const std::vector<uint64_t>& sums);
// Fails unless the payload is exactly a version-1 record of `arrays` sums.
Result<std::vector<uint64_t>> DecodeContentHashRecord(ByteSpan payload, size_t arrays);
// The size of a file's content-hash frame: it ends where the index frame starts, so a
// reader of a sealed file finds it at index_offset − ContentHashFrameSize(arrays).
inline uint64_t ContentHashFrameSize(size_t arrays) { return kFrameHeaderSize + AlignUp(8 + 8 * arrays, kAlignment); }

}  // namespace ltb::format
