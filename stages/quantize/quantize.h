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
//
// `--error-ratio R` (the default, R = 1.1) quantizes the whole matrix with ONE step Δ in
// units of each coefficient's synthesis norm (scaling "norm"), so a step costs the same
// image-domain error everywhere: at high rate the rate–distortion optimum for squared
// error (equal slopes). Rounding to the nearest step adds about Δ²/12 per kept
// coefficient; Δ is chosen so that this lifts column-transform's truncation error E (its
// column_stats) by the factor R in RMS:  N · Δ²/12 = (R² − 1) · E  for N kept
// coefficients. Values that round to 0 are dropped. Stored as the same decode formula with
// Q = 2^23 − 1 (bits 24) and M = Δ · Q for every column, so every reader decodes it.
// Measured on the bundled scene (bench/results/quantize_rd.md): the per-column maximum at
// 9 bits adds a floor; the step does not.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "format/io/manifest.h"
#include "format/progress.h"
#include "format/status.h"

namespace ltb::stages {

struct QuantizeOptions {
  std::string input;
  std::string output;
  int bits = 9;
  // > 1: one step for the matrix (see above; bits, level_scaling and dither are not used);
  // 0: the per-column maximum with `bits`.
  double error_ratio = 0;
  bool level_scaling = true;
  bool dither = false;  // --dither: adds RMS error (0.0114 against 0.0081 on the demo matrix)
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
  // --error-ratio: the step, and the truncation error E of the input and the quantization
  // error added (Σ of squared image-domain errors, exact for orthonormal filters).
  double step = 0, truncation_error = 0, quantization_error = 0, energy = 0;
  double BytesPerNonzero() const { return nonzeros_out ? static_cast<double>(matrix_bytes) / nonzeros_out : 0; }
};

Result<QuantizeResult> RunQuantize(const QuantizeOptions& options, const Progress& progress);

// The quantization of one value v (already scaled by 2^l) of a column with maximum
// magnitude m > 0: exposed for tests.
int32_t QuantizeValue(double v, double m, double levels, bool dither, uint64_t seed, uint64_t column,
                      uint32_t position);

// Whether Σ (round(v / step) · step − v)² over x, added in x's order, times `weight` is at
// most `bound` (the step search's decision; exposed for tests).
bool QuantizationErrorAtMost(const std::vector<double>& x, double step, double weight, double bound);

// The step of --error-ratio R for N kept coefficients with truncation error E and energy
// `energy` (a lossless input, E = 0, takes E = 1e-10 · energy: RMS 1e-5 of the signal).
double StepForErrorRatio(double ratio, double truncation_error, double energy, uint64_t kept);

// Totals of a quantize output (used by the stage and by `inspect`); nonzeros_out leaves out
// the chunks c with skip_nonzeros[c] (the stage counts those it writes as it writes them).
Result<QuantizeResult> SummarizeQuantized(const std::string& path, const std::vector<bool>& skip_nonzeros = {});

}  // namespace ltb::stages
