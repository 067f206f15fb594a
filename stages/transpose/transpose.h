// `ltbake transpose IN -o OUT --mem-limit SIZE`: row blocks in, column blocks out. The
// logical matrix (and its content_hash) is unchanged; only the storage layout changes.
//
// Out of core (docs/TRANSPOSE.md): the output is produced in column panels that fit the
// memory limit, two at a time (one filled from the input while the other is written).
// Each panel reads exactly its column range of every input row, so every input byte is
// read once and every output byte written once, with no temporary file.
#pragma once

#include <cstdint>
#include <string>

#include "format/io/manifest.h"
#include "format/progress.h"
#include "format/status.h"

namespace ltb::stages {

struct TransposeOptions {
  std::string input;
  std::string output;
  uint64_t mem_limit = 1ull << 30;  // bytes for panel buffers and read tiles
  int jobs = 2;                     // reader threads (one more thread writes)
  bool zstd = false;
  bool overwrite = false;
  // Check every input chunk's checksum first (one sequential read of the input): the panel
  // passes read partial rows, which cannot be checked against a whole-chunk checksum.
  bool verify_input = true;
  // Write column chunks with O_DIRECT (io::WriterOptions::direct_io): the output bypasses
  // the page cache, whose copy bounds this stage on many machines.
  bool direct_io = true;
  // Write shard `index` of `count` (io::ShardPath(output, ...)) instead of the whole output.
  io::ShardSpec shard;
};

struct TransposeResult {
  uint64_t rows = 0, cols = 0;
  uint64_t block_cols = 0;  // columns per output chunk
  uint64_t panels = 0;      // panels this run processed
  uint64_t panel_cols = 0;  // columns per full panel
  uint64_t chunks_total = 0, chunks_written = 0, chunks_already_committed = 0;
  uint64_t zero_chunks_out = 0;  // all-zero output chunks (stored free)
  uint64_t bytes_read = 0;       // payload bytes read from the input by the panel passes
  uint64_t bytes_verified = 0;   // payload bytes read by the checksum pass
  uint64_t bytes_written = 0;    // payload bytes appended to the output
  uint64_t bytes_direct = 0;     // ... of which written with O_DIRECT
  uint64_t padding_bytes = 0;    // padding frames that align direct payloads
  std::string direct_fallback;   // why direct writes were off or stopped, if asked for
};

Result<TransposeResult> RunTranspose(const TransposeOptions& options, const Progress& progress);

}  // namespace ltb::stages
