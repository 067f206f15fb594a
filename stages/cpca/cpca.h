// `ltbake cpca IN -o OUT --clusters K --basis S`: clustered principal component analysis
// of a row-block transport matrix (Sloan, Hall, Hart, Snyder 2003), out of core.
//
// Each row x (a point in D = 6R² dimensions, in the input's row basis) is approximated by
// the cluster c it is assigned to: x ≈ mean_c + Σ_i w_i basis_c,i, i < S, with orthonormal
// basis_c. The stage alternates (a) assigning every row to the cluster of least
// reconstruction error and (b) refitting each cluster's mean and principal directions,
// growing the basis dimension incrementally (0, step, 2·step, …, S) as the paper does to
// avoid poor local minima. Rows stream from the input block by block; the principal
// directions come from a streamed subspace iteration with a Nyström / Rayleigh–Ritz step
// per pass (docs/CPCA.md), so memory is O(K·D·(S + oversampling)), independent of the
// number of rows. Deterministic for any --jobs, input chunk size and interruption;
// resumable at pass boundaries through a checkpoint file beside the output.
//
// Dense-first (Huang & Ramamoorthi 2010, §6; docs/CPCA.md): on the output of a sparse bake,
// whose "sparse_kind" side array marks the rows traced densely (1) and those reconstructed
// from them (2), the seeded start and the growth levels run on the dense rows only; then
// every row is assigned and a few LBG passes at the full basis dimension run on all rows.
#pragma once

#include <cstdint>
#include <string>

#include "format/progress.h"
#include "format/status.h"

namespace ltb::stages {

// The side array a sparse bake writes beside its matrix: one u8 per row, 0 = the row sees
// no geometry (all zero), 1 = traced densely, 2 = reconstructed from dense rows.
inline constexpr const char* kSparseKindArray = "sparse_kind";
inline constexpr uint8_t kSparseKindDense = 1;

// Whether the growth levels run on the dense rows only. kAuto: when the input has a
// "sparse_kind" array with at least one dense row.
enum class DenseFirst { kAuto, kOn, kOff };

struct CpcaOptions {
  std::string input;
  std::string output;
  uint64_t clusters = 16;         // K
  uint64_t basis = 8;             // S principal directions per cluster
  uint64_t growth_step = 1;       // bases added per growth level (Sloan et al.: 1)
  uint64_t level_iterations = 2;  // passes per intermediate growth level
  uint64_t max_iterations = 30;   // cap on assignment/refit passes in total
  double tolerance = 1e-3;        // stop a level when the error improves by less (relative)
  uint64_t oversample = 8;        // extra directions tracked by the subspace iteration
  uint64_t sample_rows = 32768;   // rows held in memory for the seeded k-means++ start
  uint64_t seed = 1;
  DenseFirst dense_first = DenseFirst::kAuto;
  uint64_t final_iterations = 2;  // dense-first: LBG passes on all rows after the growth levels
  int jobs = 2;
  uint64_t mem_limit = 1ull << 30;
  bool overwrite = false;
};

struct CpcaResult {
  uint64_t rows = 0, dims = 0, clusters = 0, basis = 0;
  uint64_t iterations = 0;        // assignment/refit passes over the data
  double relative_rms_error = 0;  // ‖X − X̂‖_F / ‖X‖_F of the stored (f32) approximation
  double squared_error = 0, squared_norm = 0;
  uint64_t empty_clusters = 0;              // clusters without rows in the final assignment
  uint64_t model_bytes = 0, row_bytes = 0;  // stored payloads: means+bases, ids+weights
  uint64_t memory_bytes = 0;                // the stage's estimated peak buffer memory (incl. dense_cache_bytes)
  bool resumed = false;                     // continued from a checkpoint or a partial output
  bool already_complete = false;
  uint64_t chunks_written = 0, chunks_already_committed = 0;
  bool dense_first = false;  // the growth levels ran on the dense rows only
  uint64_t dense_rows = 0;   // rows the growth levels ran on when dense_first (else 0)
  // Dense-first: bytes of the dense rows held in memory for the dense passes (read from the
  // input once; 0 when they do not fit --mem-limit and every dense pass streams them), and
  // whether the k-means++ sample was taken from them too (they fit beside it).
  uint64_t dense_cache_bytes = 0;
  bool dense_cache_sample = false;
  // Rows read by the fit's passes (growth, final, evaluation, encoding; not the k-means++
  // sample), counted from the pass counts, so the same for a run interrupted and resumed.
  uint64_t rows_streamed = 0;
  // Wall seconds of this invocation: the seeded start and growth levels; the rest (final
  // passes, evaluation, writing the output).
  double seconds_dense = 0, seconds_final = 0;
};

Result<CpcaResult> RunCpca(const CpcaOptions& options, const Progress& progress);

// The checkpoint file the stage keeps beside OUT while it runs.
std::string CpcaCheckpointPath(const std::string& output);

}  // namespace ltb::stages
