// `ltbake column-transform IN -o OUT`: the adaptive 4D step (Cheslack-Postava et al.
// 2007, §4.2). Input: column blocks from `transpose`, each column a W×H image. Every
// column is transformed to the depth whose N-term approximation has the least
// image-domain error (ColumnCompressor) and only the kept coefficients are stored.
//
// Output (docs/COLUMN-TRANSFORM.md): the matrix in column blocks, each column the kept
// coefficients of its Mallat layout at its depth (sparse chunks); side tables "depth"
// (u8 per column) and "column_stats" (f64 per column: energy, error, nonzeros), chunked
// like the matrix so each chunk commits with its tables; the row side tables of the input
// unchanged. Resumable, deterministic whatever --jobs.
//
// Output chunks are column groups (OutputBlockColumns): each frame and index entry costs
// ~170 bytes, and one chunk per column in the matrix and its three side tables was ~4 MB
// of a 6 MB file at 128², R = 32.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "format/io/manifest.h"
#include "format/progress.h"
#include "format/status.h"
#include "stages/wavelet/wavelet.h"

namespace ltb::stages {

struct DepthMode {
  enum class Kind { kAdaptive, kNone, kFull, kFixed } kind = Kind::kAdaptive;
  int fixed = 0;  // kFixed
};
// "adaptive", "none", "full" or a depth K >= 0.
Result<DepthMode> ParseDepthMode(const std::string& text);
std::string DepthModeName(const DepthMode& mode);

// How many coefficients each column keeps.
// The default is one budget of 5% of the matrix's coefficients: the same count per column
// (--keep 0.05, the paper's) gave 1.5–2× the relit error at equal nonzeros on the demo.
struct TermsMode {
  enum class Kind { kTerms, kKeep, kBudget, kTargetError } kind = Kind::kBudget;
  uint64_t terms = 0;         // kTerms: N per column
  double keep = 0.05;         // kKeep: fraction of each column's W·H
  std::string budget = "5%";  // kBudget: as given ("0.02", "2%", "150000", "64MiB"): stages::ParseBudget
  // kTargetError: the fewest nonzeros (one rate-distortion threshold, as the budget) whose
  // relative RMS error, as the energy histograms estimate it, is at most this (0 < e < 1).
  double target_error = 0;
};

struct ColumnTransformOptions {
  std::string input;
  std::string output;
  wavelet::Filter filter = wavelet::Filter::kLeGall53;
  DepthMode depth;
  TermsMode terms;
  int jobs = 2;
  uint64_t mem_limit = 1ull << 30;
  bool zstd = true;  // zstd over the sparse chunks where it saves 10%
  bool overwrite = false;
  // Columns per output chunk; 0 = OutputBlockColumns (the input's block is not kept).
  uint64_t block_cols = 0;
  // Write shard `index` of `count` (io::ShardPath(output, ...)) instead of the whole output.
  io::ShardSpec shard;
};

struct ColumnTransformResult {
  uint64_t rows = 0, cols = 0, width = 0, height = 0;
  int min_depth = 0, max_depth = 0;
  uint64_t chunks_total = 0, chunks_written = 0, chunks_already_committed = 0;
  int jobs_used = 0;
  // Over the whole output (read back from its side tables, so also right after a resume):
  uint64_t empty_columns = 0;
  uint64_t nonzeros = 0;
  double energy = 0, error = 0;           // Σ over columns, image domain
  std::vector<uint64_t> depth_histogram;  // columns per depth 0..max_depth (empty ones excluded)
  // Budget mode (and --target-error: the budget it found, and the histograms' estimate of
  // the error, which the reported error above replaces with the exact one):
  uint64_t budget = 0;
  double estimated_error = 0;
  double lambda = 0;
  uint64_t histogram_bytes = 0;
};

// Columns per output chunk by default: as many as fill kTargetChunkBytes of dense f32 (the
// job's working buffer), at least 1, at most `cols`, and for a sharded output small enough
// that every one of `nshards` shards gets about four chunks. Depends on the shape and the
// shard count only, so a resumed run (any --jobs, any --mem-limit) writes the same metadata.
inline constexpr uint64_t kTargetChunkBytes = 32ull << 20;
uint64_t OutputBlockColumns(uint64_t rows, uint64_t cols, uint64_t nshards);

Result<ColumnTransformResult> RunColumnTransform(const ColumnTransformOptions& options, const Progress& progress);

// Totals of a column-transform output from its side tables (also used by `inspect`).
Result<ColumnTransformResult> SummarizeColumnTransform(const std::string& path);

}  // namespace ltb::stages
