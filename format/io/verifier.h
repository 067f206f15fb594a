// Checks every checksum and structural invariant of a container and lists every problem
// with its offset and chunk. The structural pass uses a small constant plus the frame
// table (zstd and sparse payloads are decoded in a streaming fashion, never materialized).
// Then, on a complete file, it recomputes every array's content_hash from the decoded
// chunks (`threads` chunks at a time, each at most kVerifyHashChunkBytes decoded) and
// compares it with the hash the writer recorded, if any.
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
  // Per array (metadata order), of a complete file: the content_hash recomputed from the
  // chunks ("" when not recomputed: a chunk over kVerifyHashChunkBytes, noted), and the one
  // the writer recorded ("" when the file has no record). A difference is a problem.
  std::vector<std::string> content_hash, recorded_content_hash;
  std::vector<uint64_t> hash_sum;  // the recomputed sums behind content_hash (0 where not recomputed)
};

// Chunks larger than this (decoded) are not decoded to recompute content_hash, so a
// hostile chunk size costs no memory; ltbake's stages write chunks far below it.
inline constexpr uint64_t kVerifyHashChunkBytes = uint64_t{1} << 30;

// Never fails: every problem, including one that stops the check early, is in the report.
VerifyReport VerifyContainer(const std::string& path, int threads = 1);

}  // namespace ltb::io
