#include "format/io/frame_scan.h"

#include <algorithm>

namespace ltb::io {

using format::kAlignment;
using format::kFrameHeaderSize;

namespace {

// Finds the next offset >= from (aligned) holding a decodable frame header, or 0.
Result<uint64_t> Resync(const File& file, uint64_t from, uint64_t file_size) {
  constexpr uint64_t kWindow = 1 << 20;
  std::vector<std::byte> buf;
  for (uint64_t base = from; base + kFrameHeaderSize <= file_size; base += kWindow) {
    uint64_t n = std::min<uint64_t>(kWindow + kFrameHeaderSize, file_size - base);
    buf.resize(n);
    LTB_RETURN_IF_ERROR(file.ReadAt(base, buf));
    for (uint64_t off = 0; off + kFrameHeaderSize <= n && off < kWindow; off += kAlignment) {
      if (format::LoadU32(&buf[off]) != format::kFrameMagic) continue;
      if (format::DecodeFrameHeader(format::ByteSpan(&buf[off], kFrameHeaderSize), base + off, file_size).ok()) {
        return base + off;
      }
    }
  }
  return uint64_t{0};
}

}  // namespace

Result<ScanResult> ScanFrames(const File& file, uint64_t first_frame_offset, uint64_t file_size) {
  ScanResult r;
  r.chain_end = first_frame_offset;
  uint64_t offset = first_frame_offset;
  std::array<std::byte, kFrameHeaderSize> hb;
  while (offset < file_size) {
    std::string reason;
    if (file_size - offset < kFrameHeaderSize) {
      reason = std::to_string(file_size - offset) + " bytes, too short for a frame header";
    } else {
      LTB_RETURN_IF_ERROR(file.ReadAt(offset, hb));
      auto h = format::DecodeFrameHeader(hb, offset, file_size);
      if (h.ok()) {
        r.frames.push_back({offset, *h});
        offset += h->FrameSize();
        r.chain_end = std::min(offset, file_size);
        continue;
      }
      reason = h.status().message();
    }
    LTB_ASSIGN_OR_RETURN(uint64_t next, Resync(file, offset + kAlignment, file_size));
    if (next == 0) {
      r.tail_reason = reason;
      break;
    }
    r.gaps.push_back({offset, next, reason});
    offset = next;
  }
  return r;
}

}  // namespace ltb::io
