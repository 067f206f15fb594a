#include "stages/sample/converged.h"

#include <algorithm>
#include <cmath>

namespace ltb::sample {

uint64_t PassSeed(uint64_t seed, uint32_t k) {
  if (k == 0) return seed;
  // splitmix64 of (seed, k): streams of different passes share no counter origin.
  uint64_t z = seed + 0x9E3779B97F4A7C15ull * (uint64_t{k} + 1);
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
  return z ^ (z >> 31);
}

ConvergedRow TraceConverged(const std::vector<const Sampler*>& passes, uint64_t row, const RowPoint& rp,
                            double tolerance, float* out, RowScratch& sc, ConvergedScratch& cs) {
  const Sampler& first = *passes.front();
  const uint64_t cols = 6ull * first.cube_res() * first.cube_res();
  const bool bounces = first.bounces() > 0;
  cs.est.resize(cols);
  cs.var.resize(cols);
  cs.sum.assign(cols, 0.0);
  cs.var_sum.assign(cols, 0.0);
  if (bounces) {
    cs.ind.resize(cols);
    cs.ind_sum.assign(cols, 0.0);
    cs.ind_sq.assign(cols, 0.0);
  }
  ConvergedRow r;
  const double tol2 = tolerance * tolerance;
  for (const Sampler* s : passes) {
    r.rays += s->DirectWithVariance(row, rp, cs.est.data(), cs.var.data(), sc);
    for (uint64_t c = 0; c < cols; ++c) {
      cs.sum[c] += cs.est[c];
      cs.var_sum[c] += cs.var[c];
    }
    if (bounces) {
      std::fill(cs.ind.begin(), cs.ind.end(), 0.0);
      r.rays += s->IndirectTerm(row, rp, s->DefaultPaths(), cs.ind.data());
      for (uint64_t c = 0; c < cols; ++c) {
        cs.ind_sum[c] += cs.ind[c];
        cs.ind_sq[c] += cs.ind[c] * cs.ind[c];
      }
    }
    const double p = static_cast<double>(++r.passes);
    // The row's response to a uniform white sky, Σ_c T_c, and its variance: the texels'
    // estimates are independent, so Σ_c of their variances — Σ var_k / p² for the mean of p
    // passes (direct, within each pass) plus, with bounces, the indirect term's sample
    // variance between passes over p.
    double total = 0, err2 = 0;
    for (uint64_t c = 0; c < cols; ++c) {
      total += cs.sum[c] / p;
      err2 += cs.var_sum[c] / (p * p);
      if (bounces) {
        total += cs.ind_sum[c] / p;
        if (p > 1) err2 += std::max(0.0, cs.ind_sq[c] - cs.ind_sum[c] * cs.ind_sum[c] / p) / (p * (p - 1));
      }
    }
    r.rel_error = total > 0 ? std::sqrt(err2) / total : 0.0;
    if ((!bounces || p > 1) && err2 <= tol2 * total * total) break;
  }
  const double p = static_cast<double>(r.passes);
  for (uint64_t c = 0; c < cols; ++c) {
    out[c] = static_cast<float>(cs.sum[c] / p + (bounces ? cs.ind_sum[c] / p : 0.0));
  }
  return r;
}

}  // namespace ltb::sample
