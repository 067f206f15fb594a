// `ltbake quantize IN -o OUT --bits 9`: §4.3 of Cheslack-Postava et al. 2007. Input: a
// column-transform output. Per column: coefficients at level l (ColumnCodec) are
// multiplied by 2^l (`--scaling level`, or left as they are with `--scaling none`), the
// column is normalised by its largest scaled magnitude M (stored per column, f64), then
// each coefficient is quantized to an integer q in [−Q, Q], Q = 2^(bits−1) − 1:
//   without dither  q = round(v / M · Q)               (|error| ≤ half a step)
//   with dither     q = floor(v / M · Q + u), u in [0, 1) from a hash of (seed, column,
//                   position): deterministic, never per thread (|error| < one step).
// Zeros are dropped; the rest is stored sparse (delta-coded positions, zigzag varints,
// zstd when it pays). Decoding: v = q / Q · M / 2^l.
#pragma once

#include <cstdint>
#include <string>

#include "format/io/manifest.h"

#include "format/progress.h"
#include "format/status.h"

namespace ltb::stages {

struct QuantizeOptions {
  std::string input;
  std::string output;
  int bits = 9;
  bool level_scaling = true;
  bool dither = true;
  uint64_t seed = 1;
  int jobs = 2;
  bool zstd = true;
  bool overwrite = false;
  // Write shard `index` of `count` (io::ShardPath(output, ...)) instead of the whole output.
  io::ShardSpec shard;
};

struct QuantizeResult {
  uint64_t rows = 0, cols = 0;
  uint64_t chunks_total = 0, chunks_written = 0, chunks_already_committed = 0;
  uint64_t nonzeros_in = 0;   // coefficients kept by column-transform
  uint64_t nonzeros_out = 0;  // after quantization (zeros dropped)
  uint64_t matrix_bytes = 0;  // stored payload bytes of the matrix chunks
  double BytesPerNonzero() const { return nonzeros_out ? static_cast<double>(matrix_bytes) / nonzeros_out : 0; }
};

Result<QuantizeResult> RunQuantize(const QuantizeOptions& options, const Progress& progress);

// The quantization of one value v (already scaled by 2^l) of a column with maximum
// magnitude m > 0: exposed for tests.
int32_t QuantizeValue(double v, double m, double levels, bool dither, uint64_t seed, uint64_t column, uint32_t position);

// Totals of a quantize output (used by the stage and by `inspect`).
Result<QuantizeResult> SummarizeQuantized(const std::string& path);

}  // namespace ltb::stages
