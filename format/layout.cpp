#include "format/layout.h"

#include <cstring>

#include "format/version.h"

namespace ltb::format {
namespace {

std::string VersionString(uint16_t major, uint16_t minor) {
  return std::to_string(major) + "." + std::to_string(minor);
}

bool AllZero(ByteSpan bytes) {
  for (std::byte b : bytes)
    if (b != std::byte{0}) return false;
  return true;
}

}  // namespace

const char* EncodingName(Encoding e) {
  switch (e) {
    case Encoding::kRaw:
      return "raw";
    case Encoding::kZero:
      return "zero";
    case Encoding::kZstd:
      return "zstd";
    case Encoding::kSparse:
      return "sparse";
    case Encoding::kSparseZstd:
      return "sparse-zstd";
    case Encoding::kCoded:
      return "sparse-coded";
  }
  return "unknown";
}

bool IsKnownEncoding(uint16_t e) { return e <= static_cast<uint16_t>(Encoding::kCoded); }

// File header, 64 bytes:
//   0 magic[8]  8 major u16  10 minor u16  12 header_size u32  16 required_features u64
//  24 optional_features u64  32 metadata_length u64  40 metadata_checksum u64
//  48 reserved u64 (0)  56 header_checksum u64 = XXH3-64(bytes 0..55)
std::array<std::byte, kHeaderSize> EncodeFileHeader(const FileHeader& h) {
  std::array<std::byte, kHeaderSize> b{};
  std::memcpy(b.data(), kFileMagic.data(), kFileMagic.size());
  StoreU16(&b[8], h.major);
  StoreU16(&b[10], h.minor);
  StoreU32(&b[12], static_cast<uint32_t>(kHeaderSize));
  StoreU64(&b[16], h.required_features);
  StoreU64(&b[24], h.optional_features);
  StoreU64(&b[32], h.metadata_length);
  StoreU64(&b[40], h.metadata_checksum);
  StoreU64(&b[56], Checksum(ByteSpan(b.data(), 56)));
  return b;
}

Result<FileHeader> DecodeFileHeader(ByteSpan bytes, uint64_t file_size) {
  if (bytes.size() < kHeaderSize || file_size < kHeaderSize) {
    return DataLoss("file is " + std::to_string(file_size) + " bytes, shorter than the " + std::to_string(kHeaderSize) +
                    "-byte .ltm header; it is not an .ltm container or was truncated");
  }
  if (std::memcmp(bytes.data(), kFileMagic.data(), kFileMagic.size()) != 0) {
    return InvalidArgument("not an .ltm container (bad magic at offset 0)");
  }
  FileHeader h;
  h.major = LoadU16(&bytes[8]);
  h.minor = LoadU16(&bytes[10]);
  // The version is checked before the checksum: a newer major may lay out its header differently.
  if (h.major > kFormatMajor) {
    return Unimplemented("written by .ltm format " + VersionString(h.major, h.minor) + "; this build of ltbake " +
                         kToolVersion + " reads up to " + VersionString(kFormatMajor, kFormatMinor) + " (major " +
                         std::to_string(kFormatMajor) + ".x) — upgrade ltbake");
  }
  if (h.major < 1) {
    return DataLoss("header names format version " + VersionString(h.major, h.minor) +
                    ", which never existed (damaged header?)");
  }
  uint32_t header_size = LoadU32(&bytes[12]);
  if (header_size != kHeaderSize) {
    return DataLoss("header_size field is " + std::to_string(header_size) + ", expected " +
                    std::to_string(kHeaderSize));
  }
  uint64_t stored = LoadU64(&bytes[56]);
  uint64_t actual = Checksum(bytes.subspan(0, 56));
  if (stored != actual) {
    return DataLoss("header checksum mismatch: expected=" + Hex64(stored) + ", actual=" + Hex64(actual));
  }
  if (LoadU64(&bytes[48]) != 0) return DataLoss("header reserved field at offset 48 is not zero");
  h.required_features = LoadU64(&bytes[16]);
  h.optional_features = LoadU64(&bytes[24]);
  h.metadata_length = LoadU64(&bytes[32]);
  h.metadata_checksum = LoadU64(&bytes[40]);
  uint64_t unknown = h.required_features & ~kKnownRequiredFeatures;
  if (unknown != 0) {
    return Unimplemented("file requires format features " + Hex64(unknown) +
                         " that this build does not know (written by a newer ltbake, format " +
                         VersionString(h.major, h.minor) + ") — upgrade ltbake");
  }
  if (h.metadata_length > kMaxMetadataBytes) {
    return DataLoss("metadata length " + std::to_string(h.metadata_length) + " exceeds the cap of " +
                    std::to_string(kMaxMetadataBytes) + " bytes");
  }
  if (h.metadata_length > file_size - kHeaderSize) {
    return DataLoss("metadata length " + std::to_string(h.metadata_length) + " runs past the end of the " +
                    std::to_string(file_size) + "-byte file (truncated?)");
  }
  return h;
}

// Frame header, 64 bytes:
//   0 magic u32 "LTMF"  4 type u16  6 flags u16  8 payload_length u64  16 array u32
//  20 encoding u16  22 reserved u16 (0)  24 chunk_index u64  32 decoded_length u64
//  40 payload_checksum u64  48 reserved u64 (0)  56 header_checksum u64 = XXH3-64(bytes 0..55)
std::array<std::byte, kFrameHeaderSize> EncodeFrameHeader(const FrameHeader& h) {
  std::array<std::byte, kFrameHeaderSize> b{};
  StoreU32(&b[0], kFrameMagic);
  StoreU16(&b[4], h.type);
  StoreU16(&b[6], h.flags);
  StoreU64(&b[8], h.payload_length);
  StoreU32(&b[16], h.array);
  StoreU16(&b[20], h.encoding);
  StoreU64(&b[24], h.chunk_index);
  StoreU64(&b[32], h.decoded_length);
  StoreU64(&b[40], h.payload_checksum);
  StoreU64(&b[56], Checksum(ByteSpan(b.data(), 56)));
  return b;
}

Result<FrameHeader> DecodeFrameHeader(ByteSpan bytes, uint64_t frame_offset, uint64_t file_size) {
  if (bytes.size() < kFrameHeaderSize) return DataLoss("frame header truncated");
  if (LoadU32(&bytes[0]) != kFrameMagic) {
    return DataLoss(AllZero(bytes.subspan(0, kFrameHeaderSize)) ? "no frame header (zero bytes)" : "bad frame magic");
  }
  uint64_t stored = LoadU64(&bytes[56]);
  uint64_t actual = Checksum(bytes.subspan(0, 56));
  if (stored != actual) {
    return DataLoss("frame header checksum mismatch: expected=" + Hex64(stored) + ", actual=" + Hex64(actual));
  }
  if (LoadU16(&bytes[22]) != 0 || LoadU64(&bytes[48]) != 0) return DataLoss("frame header reserved field not zero");
  FrameHeader h;
  h.type = LoadU16(&bytes[4]);
  h.flags = LoadU16(&bytes[6]);
  h.payload_length = LoadU64(&bytes[8]);
  h.array = LoadU32(&bytes[16]);
  h.encoding = LoadU16(&bytes[20]);
  h.chunk_index = LoadU64(&bytes[24]);
  h.decoded_length = LoadU64(&bytes[32]);
  h.payload_checksum = LoadU64(&bytes[40]);
  uint64_t end;
  if (AddOverflows(frame_offset, kFrameHeaderSize, &end) || AddOverflows(end, h.payload_length, &end) ||
      end > file_size) {
    return DataLoss("frame payload of " + std::to_string(h.payload_length) + " bytes runs past the end of the " +
                    std::to_string(file_size) + "-byte file");
  }
  return h;
}

// Trailer, 64 bytes at the very end of a sealed file:
//   0 magic[8] "LTMTRAIL"  8 index_offset u64  16 file_length u64  24..55 reserved (0)
//  56 checksum u64 = XXH3-64(bytes 0..55)
std::array<std::byte, kTrailerSize> EncodeTrailer(const Trailer& t) {
  std::array<std::byte, kTrailerSize> b{};
  std::memcpy(b.data(), kTrailerMagic.data(), kTrailerMagic.size());
  StoreU64(&b[8], t.index_offset);
  StoreU64(&b[16], t.file_length);
  StoreU64(&b[56], Checksum(ByteSpan(b.data(), 56)));
  return b;
}

Result<Trailer> DecodeTrailer(ByteSpan bytes, uint64_t file_size) {
  if (bytes.size() < kTrailerSize) return DataLoss("trailer truncated");
  if (std::memcmp(bytes.data(), kTrailerMagic.data(), kTrailerMagic.size()) != 0) {
    return DataLoss("no trailer (file not sealed)");
  }
  uint64_t stored = LoadU64(&bytes[56]);
  uint64_t actual = Checksum(bytes.subspan(0, 56));
  if (stored != actual) {
    return DataLoss("trailer checksum mismatch: expected=" + Hex64(stored) + ", actual=" + Hex64(actual));
  }
  if (!AllZero(bytes.subspan(24, 32))) return DataLoss("trailer reserved bytes not zero");
  Trailer t;
  t.index_offset = LoadU64(&bytes[8]);
  t.file_length = LoadU64(&bytes[16]);
  if (t.file_length != file_size) {
    return DataLoss("trailer records a file length of " + std::to_string(t.file_length) + " bytes, the file has " +
                    std::to_string(file_size));
  }
  if (t.index_offset % kAlignment != 0 || t.index_offset > file_size - kTrailerSize) {
    return DataLoss("trailer index offset " + std::to_string(t.index_offset) + " is outside the file");
  }
  return t;
}

std::vector<std::byte> EncodeIndex(const std::vector<IndexEntry>& entries) {
  std::vector<std::byte> out(8 + entries.size() * kIndexEntrySize);
  StoreU64(out.data(), entries.size());
  std::byte* p = out.data() + 8;
  for (const IndexEntry& e : entries) {
    StoreU64(p, e.frame_offset);
    auto h = EncodeFrameHeader(e.header);
    std::memcpy(p + 8, h.data(), h.size());
    p += kIndexEntrySize;
  }
  return out;
}

Result<std::vector<IndexEntry>> DecodeIndex(ByteSpan payload, uint64_t first_frame_offset, uint64_t file_size) {
  if (payload.size() < 8) return DataLoss("index payload shorter than its 8-byte count");
  uint64_t count = LoadU64(payload.data());
  // The count is checked against the payload size before anything is allocated.
  if (count > (payload.size() - 8) / kIndexEntrySize || 8 + count * kIndexEntrySize != payload.size()) {
    return DataLoss("index claims " + std::to_string(count) + " entries but its payload is " +
                    std::to_string(payload.size()) + " bytes");
  }
  std::vector<IndexEntry> entries;
  entries.reserve(count);
  for (uint64_t i = 0; i < count; ++i) {
    const std::byte* p = payload.data() + 8 + i * kIndexEntrySize;
    IndexEntry e;
    e.frame_offset = LoadU64(p);
    if (e.frame_offset < first_frame_offset || e.frame_offset % kAlignment != 0 ||
        e.frame_offset > file_size - kFrameHeaderSize) {
      return DataLoss("index entry " + std::to_string(i) + " points at offset " + std::to_string(e.frame_offset) +
                      ", outside the frame area");
    }
    auto h = DecodeFrameHeader(ByteSpan(p + 8, kFrameHeaderSize), e.frame_offset, file_size);
    if (!h.ok()) return h.status().WithContext("index entry " + std::to_string(i));
    e.header = *h;
    entries.push_back(e);
  }
  return entries;
}

std::vector<std::byte> EncodeContentHashRecord(const std::vector<uint64_t>& sums) {
  std::vector<std::byte> out(8 + 8 * sums.size());
  StoreU32(out.data(), kContentHashRecordVersion);
  StoreU32(out.data() + 4, static_cast<uint32_t>(sums.size()));
  for (size_t i = 0; i < sums.size(); ++i) StoreU64(out.data() + 8 + 8 * i, sums[i]);
  return out;
}

Result<std::vector<uint64_t>> DecodeContentHashRecord(ByteSpan payload, size_t arrays) {
  if (payload.size() < 8) return DataLoss("content-hash record shorter than its 8-byte head");
  const uint32_t version = LoadU32(payload.data()), count = LoadU32(payload.data() + 4);
  if (version != kContentHashRecordVersion) {
    return DataLoss("content-hash record version " + std::to_string(version) + " (this build knows " +
                    std::to_string(kContentHashRecordVersion) + ")");
  }
  if (count != arrays || payload.size() != 8 + 8 * uint64_t{count}) {
    return DataLoss("content-hash record lists " + std::to_string(count) + " arrays in " +
                    std::to_string(payload.size()) + " bytes; the metadata has " + std::to_string(arrays));
  }
  std::vector<uint64_t> sums(count);
  for (size_t i = 0; i < count; ++i) sums[i] = LoadU64(payload.data() + 8 + 8 * i);
  return sums;
}

}  // namespace ltb::format
