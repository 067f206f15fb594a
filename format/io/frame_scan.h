// Walks the frame chain of a container from its first frame. Used by the reader (when
// there is no valid trailer), by the writer to resume, and by verify.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "format/io/file.h"
#include "format/layout.h"

namespace ltb::io {

struct ScanGap {
  uint64_t offset = 0;  // where the chain broke
  uint64_t resume = 0;  // next valid frame found after the damage
  std::string reason;   // why the frame at `offset` did not decode
};

struct ScanResult {
  std::vector<format::IndexEntry> frames;  // every valid frame, in file order
  std::vector<ScanGap> gaps;               // damaged regions with valid frames after them
  uint64_t chain_end = 0;                  // end of the last valid frame
  std::string tail_reason;                 // why the scan stopped before the end (if it did)
};

// Scans [first_frame_offset, file_size). When the chain breaks, searches the rest of the
// file at aligned offsets for a valid frame header; bytes after the last valid frame are
// the uncommitted tail (a writer killed mid-chunk leaves one).
Result<ScanResult> ScanFrames(const File& file, uint64_t first_frame_offset, uint64_t file_size);

}  // namespace ltb::io
