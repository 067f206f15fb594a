// Checks every checksum and structural invariant of a container and lists every problem
// with its offset and chunk. Memory use is bounded by a small constant plus the frame
// table (zstd and sparse payloads are decoded in a streaming fashion, never materialized).
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "format/status.h"

namespace ltb::io {

struct VerifyReport {
  std::string path;
  bool readable = false;  // header and metadata decoded
  bool sealed = false;    // valid index and trailer
  bool complete = false;  // sealed and every chunk of every array present
  uint64_t chunks_expected = 0;
  uint64_t chunks_ok = 0;               // committed chunks whose payload verified
  uint64_t uncommitted_tail_bytes = 0;  // left by a writer that stopped mid-chunk
  std::vector<std::string> problems;    // damage: each names offset and chunk
  std::vector<std::string> notes;       // not damage (e.g. skipped optional frames)
};

// Never fails: every problem, including one that stops the check early, is in the report.
VerifyReport VerifyContainer(const std::string& path);

}  // namespace ltb::io
