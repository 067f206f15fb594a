// Internal to `ltbake cpca` (stages/cpca/cpca.h): fitting the model to rows streamed from
// the input — the seeded k-means++ start, the assignment/refit passes growing the basis
// level by level, checkpointed at every pass boundary, and the final evaluation and
// encoding with the f32-rounded model.
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

// The basis dimensions the fit grows through: 0, step, 2·step, …, s.
std::vector<uint64_t> Levels(uint64_t s, uint64_t step);

struct Params {
  uint64_t k, s, p, n_rows, d, sample_rows;
  std::vector<uint64_t> levels;
};

// Where a fit ends: the model as stored and the final assignment's totals.
struct FitOutcome {
  Model rounded;  // every value rounded to f32
  uint64_t passes = 0;
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
  // Rows streamed so far, counting the passes of earlier runs (for progress).
  uint64_t rows_done() const { return rows_done_; }

 private:
  struct FitState;
  Status Initialise(Model* m);
  std::vector<uint64_t> SampleRows() const;
  std::vector<uint64_t> SeedCentres(const RowMat& x) const;
  Status Lloyd(const RowMat& x, Model* m, std::vector<uint32_t>* id) const;
  Status InitialDirections(const RowMat& x, const std::vector<uint32_t>& id, Model* m) const;
  // One assignment + refit pass at basis dimension n. Returns Σ squared error of the
  // assignment (against the model before the refit).
  Result<double> Pass(Model* m, uint64_t n, uint64_t pass_index);
  // The final assignment with the f32-rounded model: Σ squared error of what is stored,
  // Σ ‖x‖², and the cluster sizes.
  Status Evaluate(const Model& rounded, double* err, double* norm, std::vector<uint64_t>* sizes);
  Result<bool> Resume(const std::string& cp_path, const nlohmann::json& identity, Model* m, FitState* st) const;
  Status Iterate(const std::string& cp_path, const nlohmann::json& identity, Model* m, FitState* st);

  void ReportRows(uint64_t done) const { progress_.Report(done, (o_.max_iterations + 2) * pr_.n_rows, "rows"); }
  const CpcaOptions& o_;
  const io::ContainerReader& in_;
  const Params& pr_;
  const Progress& progress_;
  uint64_t rows_done_ = 0;
};

}  // namespace ltb::stages::cpca_internal
