// Internal to `ltbake cpca` (stages/cpca/cpca.h): fitting the model to rows streamed from
// the input — the seeded k-means++ start, the assignment/refit passes growing the basis
// level by level (on the dense rows only in dense-first mode, read once and held in memory
// when they fit, then a few passes on all rows), checkpointed at every pass boundary, and
// the final evaluation and encoding with the f32-rounded model.
#pragma once

#include <cstdint>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "format/io/container_reader.h"
#include "format/progress.h"
#include "format/status.h"
#include "stages/cpca/cpca.h"
#include "stages/cpca/cpca_math.h"

namespace ltb::stages::cpca_internal {

// Rows per assignment GEMM. Fixed, and every pass partitions the rows the same way
// (blocks aligned at row 0), so a row's arithmetic never depends on --jobs, the input's
// chunking or where a run was interrupted.
inline constexpr uint64_t kSubRows = 256;

// Rows per pass block (the unit of streaming and of per-cluster accumulation): about
// 8 MiB of doubles, a multiple of kSubRows; depends only on D.
uint64_t PassBlockRows(uint64_t d);

// Pass blocks read and assigned together, in parallel (then accumulated one after another,
// so the arithmetic is that of one block at a time): enough that a pass block of fewer
// sub-blocks than --jobs (D > 2048: one) still keeps every thread busy.
uint64_t PassGroupBlocks(uint64_t d, int jobs);

// The basis dimensions the fit grows through: 0, step, 2·step, …, s.
std::vector<uint64_t> Levels(uint64_t s, uint64_t step);

struct Params {
  uint64_t k, s, p, n_rows, d, sample_rows;
  std::vector<uint64_t> levels;
  // Dense-first: the seeded start and the growth levels use only the n_dense rows whose
  // sparse_kind (array kind_array of the input) is kSparseKindDense; then
  // final_iterations passes at dimension s run on all rows.
  bool dense_first = false;
  uint64_t n_dense = 0, final_iterations = 0;
  int kind_array = -1;
  // Dense-first, when they fit --mem-limit: the dense rows are read from the input once and
  // held in memory (f32, as stored) for the dense passes; sample_from_cache: gathered before
  // the k-means++ sample, which is then read from them (both fit at once), else gathered at
  // the first dense pass, after the sample is freed.
  bool dense_cache = false, sample_from_cache = false;
  uint64_t group_blocks = 1;  // PassGroupBlocks, or 1 when the extra blocks do not fit
};

// Where a fit ends: the model as stored and the final assignment's totals.
struct FitOutcome {
  Model rounded;                               // every value rounded to f32
  uint64_t passes = 0;                         // every assignment/refit pass
  uint64_t final_passes = 0;                   // of which on all rows after the dense growth levels
  double seconds_dense = 0;                    // this invocation's wall seconds of the start and growth levels
  double squared_error = 0, squared_norm = 0;  // Σ of the stored approximation, Σ ‖x‖²
  std::vector<uint64_t> sizes;                 // rows per cluster
  bool resumed = false;                        // continued from the checkpoint
};

class CpcaFitter {
 public:
  CpcaFitter(const CpcaOptions& o, const io::ContainerReader& in, const Params& pr, const Progress& progress)
      : o_(o), in_(in), pr_(pr), progress_(progress) {}

  // The whole fit: resumes from the checkpoint at cp_path when it belongs to `identity`
  // (else initialises), alternates assignment and refit, then evaluates the rounded model;
  // the checkpoint is rewritten at every pass boundary.
  Result<FitOutcome> Fit(const std::string& cp_path, const nlohmann::json& identity);

  // Assigns rows [row0, row0+n) (row0 a multiple of kSubRows) with the rounded model
  // (Assigner built from it at dimension S): ids, f32 weights and per-row squared error of
  // the decoded approximation. x receives the last sub-block's rows.
  Status Encode(const Assigner& a, const Model& rounded, uint64_t row0, uint64_t n, std::vector<double>* x,
                uint32_t* ids, float* weights, double* err) const;
  // Rows streamed so far, counting the passes of earlier runs (for progress), and the
  // total expected when every pass runs.
  uint64_t rows_done() const { return rows_done_; }
  uint64_t rows_total() const;

 private:
  struct FitState;
  // Dense-first: the dense rows in row order, as read from the input (f32, checked finite),
  // and their row numbers; held from their first read to the end of the growth levels.
  struct DenseCache {
    std::vector<uint64_t> rows;
    std::vector<float> values;  // rows.size() × D
    bool filled = false;
  };
  // Fills cache_ (once per invocation; a resumed run gathers again): one read of the side
  // array and of every input chunk holding dense rows.
  Status GatherDense();
  // Cached dense rows [i, i + n) as doubles (exactly the values the input holds).
  void CachedRows(uint64_t i, uint64_t n, double* out) const;
  Status Initialise(Model* m);
  Result<std::vector<uint64_t>> SampleRows() const;
  std::vector<uint64_t> SeedCentres(const RowMat& x) const;
  Status Lloyd(const RowMat& x, Model* m, std::vector<uint32_t>* id) const;
  Status InitialDirections(const RowMat& x, const std::vector<uint32_t>& id, Model* m) const;
  // One assignment + refit pass at basis dimension n over all rows, or over the dense
  // rows only (from cache_ when planned). Returns Σ squared error of the assignment
  // (against the model before the refit).
  Result<double> Pass(Model* m, uint64_t n, uint64_t pass_index, bool dense_only);
  // The final assignment with the f32-rounded model: Σ squared error of what is stored,
  // Σ ‖x‖², and the cluster sizes.
  Status Evaluate(const Model& rounded, double* err, double* norm, std::vector<uint64_t>* sizes);
  Result<bool> Resume(const std::string& cp_path, const nlohmann::json& identity, Model* m, FitState* st) const;
  Status Iterate(const std::string& cp_path, const nlohmann::json& identity, Model* m, FitState* st);
  Status FinalPasses(const std::string& cp_path, const nlohmann::json& identity, Model* m, FitState* st);
  // Rows the passes counted in st have read.
  uint64_t RowsStreamed(const FitState& st) const;

  void ReportRows(uint64_t done) const { progress_.Report(done, rows_total(), "rows"); }
  const CpcaOptions& o_;
  const io::ContainerReader& in_;
  const Params& pr_;
  const Progress& progress_;
  uint64_t rows_done_ = 0;
  DenseCache cache_;
};

}  // namespace ltb::stages::cpca_internal
