// Internal to the sample stage: converged sampling (`sample --tolerance T`, docs/SAMPLE.md
// "Converged sampling"). A row is traced in passes, each a full stratified estimate with its
// own random streams (pass k's sampler has seed PassSeed(seed, k); pass 0 the bake's own
// seed), until the estimated relative standard error of the row's response to a uniform
// white sky (Σ_c T_c, what the row relights to under smooth lighting) is at most T, or
// max_passes are spent. Deterministic for a seed and T: every decision is made on the row's
// own samples, in a fixed order.
#pragma once

#include <cstdint>
#include <vector>

#include "stages/sample/sampler.h"

namespace ltb::sample {

// The seed of pass k (k = 0: the seed itself).
uint64_t PassSeed(uint64_t seed, uint32_t k);

struct ConvergedRow {
  uint32_t passes = 0;
  uint64_t rays = 0;
  double rel_error = 0;  // the estimated relative error of the row's sky response (0 for a zero row)
};

// Scratch of one thread, reused from row to row.
struct ConvergedScratch {
  std::vector<double> est, var, sum, var_sum, ind, ind_sum, ind_sq;
};

// One row of T (6R² values into out) from passes[0..max_passes) (one sampler per pass, all
// alike but their seeds). The error estimate: the direct term's within-pass variance (from
// each texel's stratified samples), and with bounces the indirect term's spread between
// passes (so a bake with bounces takes at least two passes).
ConvergedRow TraceConverged(const std::vector<const Sampler*>& passes, uint64_t row, const RowPoint& rp,
                            double tolerance, float* out, RowScratch& sc, ConvergedScratch& cs);

}  // namespace ltb::sample
