#include "stages/sample/converged.h"

#include <algorithm>
#include <cmath>

namespace ltb::sample {

namespace {

constexpr double kBeta = 1.5;  // a stratified estimate's variance across an edge: ∝ n^−β

void Size(const Sampler& s, ConvergedScratch& cs) {
  const uint64_t cols = 6ull * s.cube_res() * s.cube_res();
  cs.est.resize(cols);
  cs.var.resize(cols);
  cs.v.resize(cols);
  cs.ind.resize(cols);
  cs.select.resize(cols);
  cs.target.resize(cols);
}

// The level past which one more level gains less than λ per ray, for a texel of variance v
// at level k (spp0: level 0's spp), at most `top`.
uint32_t TargetLevel(double v, uint32_t k, double lambda, uint32_t spp0, uint32_t top) {
  if (!(lambda > 0) || !(v > 0)) return k;
  const double v0 = v * std::pow(2.0, kBeta * k);  // the model's level-0 variance
  // Smallest ℓ with v0·2^(−βℓ)(1 − 2^−β) ≤ λ·spp0·2^(ℓ+1).
  const double x = v0 * (1 - std::pow(2.0, -kBeta)) / (2 * lambda * spp0);
  const double l = x > 1 ? std::ceil(std::log2(x) / (kBeta + 1)) : 0.0;
  return static_cast<uint32_t>(std::clamp(l, static_cast<double>(k), static_cast<double>(top)));
}

// cs.v: each texel's variance, the largest of its face's 3×3 neighbourhood in `var`.
void Dilate(const std::vector<double>& var, uint32_t res, std::vector<double>& v) {
  const uint64_t rr = uint64_t{res} * res;
  for (uint64_t c = 0; c < var.size(); ++c) {
    const uint64_t face = c / rr, t = c % rr / res, u = c % res;
    double m = 0;
    for (uint64_t tt = t > 0 ? t - 1 : 0; tt <= std::min<uint64_t>(res - 1, t + 1); ++tt) {
      for (uint64_t uu = u > 0 ? u - 1 : 0; uu <= std::min<uint64_t>(res - 1, u + 1); ++uu) {
        m = std::max(m, var[face * rr + tt * res + uu]);
      }
    }
    v[c] = m;
  }
}

}  // namespace

uint64_t LevelSeed(uint64_t seed, uint32_t k) {
  if (k == 0) return seed;
  // SplitMix64 of (seed, k): streams of different levels share no counter origin.
  return Mix64(seed + 0x9E3779B97F4A7C15ull * (uint64_t{k} + 1));
}

Pilot PilotRows(const Sampler& s, uint64_t rows, uint32_t levels, double tolerance) {
  Pilot p;
  const uint64_t count = std::clamp<uint64_t>(rows / 32, std::min<uint64_t>(rows, 64), 2048);
  const uint64_t stride = std::max<uint64_t>(1, rows / std::max<uint64_t>(count, 1));
  RowScratch sc;
  ConvergedScratch cs;
  Size(s, cs);
  std::vector<double> v0;  // every pilot texel's (dilated) level-0 variance
  double norm2 = 0;
  for (uint64_t row = stride / 2; row < rows; row += stride) {
    ++p.rows;
    const RowPoint rp = s.Primary(row);
    if (!rp.valid) continue;  // an all-zero row
    p.rays += s.DirectWithVariance(row, rp, cs.est.data(), cs.var.data(), sc);
    std::fill(cs.ind.begin(), cs.ind.end(), 0.0);
    if (s.bounces() > 0) p.rays += s.IndirectTerm(row, rp, s.DefaultPaths(), cs.ind.data());
    for (size_t c = 0; c < cs.est.size(); ++c) norm2 += (cs.est[c] + cs.ind[c]) * (cs.est[c] + cs.ind[c]);
    Dilate(cs.var, s.cube_res(), cs.v);
    for (size_t c = 0; c < cs.v.size(); ++c) {
      if (cs.v[c] > 0) v0.push_back(cs.v[c]);
    }
  }
  if (p.rows == 0 || !(norm2 > 0) || v0.empty()) return p;
  p.mean_norm2 = norm2 / static_cast<double>(p.rows);
  // λ: bisection (in log) for the predicted variance of the pilot rows, Σ v0·2^(−β·level),
  // to be T² times their squared norm. The prediction falls as λ does.
  const double want = tolerance * tolerance * norm2;
  const uint32_t top = levels - 1;
  auto predicted = [&](double lambda) {
    double total = 0;
    for (double v : v0) total += v * std::pow(2.0, -kBeta * TargetLevel(v, 0, lambda, s.spp(), top));
    return total;
  };
  double lo = 1e-300, hi = 1e300;
  for (int i = 0; i < 200 && hi / lo > 1.0001; ++i) {
    const double mid = std::sqrt(lo) * std::sqrt(hi);
    (predicted(mid) > want ? hi : lo) = mid;
  }
  p.lambda = hi;  // the largest λ (fewest rays) found whose prediction is within T²
  return p;
}

ConvergedRow TraceConverged(const std::vector<const Sampler*>& levels, uint64_t row, const RowPoint& rp, double lambda,
                            double rms_norm, float* out, RowScratch& sc, ConvergedScratch& cs) {
  const Sampler& first = *levels.front();
  const uint64_t cols = 6ull * first.cube_res() * first.cube_res();
  const uint32_t top = static_cast<uint32_t>(levels.size()) - 1;
  Size(first, cs);
  ConvergedRow r;
  r.rays = first.DirectWithVariance(row, rp, cs.est.data(), cs.var.data(), sc);
  // Per texel: Σ w_k est_k, Σ w_k, Σ w_k² var_k with w_k = 2^(βk).
  cs.sum.assign(cs.est.begin(), cs.est.end());
  cs.wsum.assign(cols, 1.0);
  cs.var_sum.assign(cs.var.begin(), cs.var.end());
  Dilate(cs.var, first.cube_res(), cs.v);
  for (uint64_t c = 0; c < cols; ++c) cs.target[c] = TargetLevel(cs.v[c], 0, lambda, first.spp(), top);
  for (uint32_t k = 1; k <= top; ++k) {
    uint64_t picked = 0;
    for (uint64_t c = 0; c < cols; ++c) {
      cs.select[c] = cs.target[c] == k ? 1 : 0;
      picked += cs.select[c];
    }
    if (picked == 0) continue;
    r.rays += levels[k]->DirectWithVariance(row, rp, cs.est.data(), cs.var.data(), sc, cs.select.data());
    const double w = std::pow(2.0, kBeta * k);
    for (uint64_t c = 0; c < cols; ++c) {
      if (cs.select[c] == 0) continue;
      cs.sum[c] += w * cs.est[c];
      cs.wsum[c] += w;
      cs.var_sum[c] += w * w * cs.var[c];
    }
    r.level = k;
  }
  std::fill(cs.ind.begin(), cs.ind.end(), 0.0);
  if (first.bounces() > 0) r.rays += first.IndirectTerm(row, rp, first.DefaultPaths(), cs.ind.data());
  double err2 = 0;
  for (uint64_t c = 0; c < cols; ++c) {
    out[c] = static_cast<float>(cs.sum[c] / cs.wsum[c] + cs.ind[c]);
    err2 += cs.var_sum[c] / (cs.wsum[c] * cs.wsum[c]);
  }
  r.rel_error = rms_norm > 0 ? std::sqrt(err2) / rms_norm : 0.0;
  return r;
}

}  // namespace ltb::sample
