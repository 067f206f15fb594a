#include "stages/sample/converged.h"

#include <algorithm>
#include <cmath>

namespace ltb::sample {

namespace {

constexpr double kBeta = 1.5;  // a stratified estimate's variance across an edge: ∝ n^−β
// The indirect term's paths double at most this often past DefaultPaths() (1024×): its noise
// falls only as 1/paths, so it needs far more doublings than a texel needs levels.
constexpr uint32_t kIndirectDoublings = 10;

void Size(const Sampler& s, ConvergedScratch& cs) {
  const uint64_t cols = 6ull * s.cube_res() * s.cube_res();
  cs.stats.resize(cols);
  cs.exact.resize(cols);
  cs.cv.resize(cols);
  cs.est.resize(cols);
  cs.var.resize(cols);
  cs.v.resize(cols);
  cs.ind.resize(cols);
  cs.select.resize(cols);
  cs.target.resize(cols);
}

// The level past which one more level gains less than λ per ray, for a texel of variance v
// at level 0 (spp0: level 0's spp), at most `top`.
uint32_t TargetLevel(double v, double lambda, uint32_t spp0, uint32_t top) {
  if (!(lambda > 0) || !(v > 0)) return 0;
  // Smallest ℓ with v·2^(−βℓ)(1 − 2^−β) ≤ λ·spp0·2^(ℓ+1).
  const double x = v * (1 - std::pow(2.0, -kBeta)) / (2 * lambda * spp0);
  const double l = x > 1 ? std::ceil(std::log2(x) / (kBeta + 1)) : 0.0;
  return static_cast<uint32_t>(std::min(l, static_cast<double>(top)));
}

// A texel's estimate from one level's samples: with the control variate (cv), the exact
// unoccluded value less the occluded samples' mean (exact where no sample is occluded), else
// the unoccluded samples' mean (Transport's, exact 0 where every sample is occluded).
double Estimate(const TexelStats& st, bool cv, double exact) { return cv ? exact - st.occ : st.vis; }
double EstimateVariance(const TexelStats& st, bool cv) { return cv ? st.occ_spread : st.vis_spread; }

// Over each face's 3×3 neighbourhoods (clipped at the face's edges): sums of x into out, and
// maxima of y into out; tmp is scratch. Separable, along u then along v.
template <typename T, typename Op>
void Separable3(const std::vector<T>& x, uint32_t res, std::vector<T>& out, std::vector<T>& tmp, Op op) {
  const uint64_t rr = uint64_t{res} * res, cols = x.size();
  out.resize(cols);
  tmp.resize(cols);
  for (uint64_t c = 0; c < cols; ++c) {
    const uint64_t u = c % res;
    T a = x[c];
    if (u > 0) a = op(a, x[c - 1]);
    if (u + 1 < res) a = op(a, x[c + 1]);
    tmp[c] = a;
  }
  for (uint64_t c = 0; c < cols; ++c) {
    const uint64_t t = c % rr / res;
    T a = tmp[c];
    if (t > 0) a = op(a, tmp[c - res]);
    if (t + 1 < res) a = op(a, tmp[c + res]);
    out[c] = a;
  }
}
void Box3(const std::vector<uint32_t>& x, uint32_t res, std::vector<uint32_t>& out, std::vector<uint32_t>& tmp) {
  Separable3(x, res, out, tmp, [](uint32_t a, uint32_t b) { return a + b; });
}
void Max3(const std::vector<double>& x, uint32_t res, std::vector<double>& out, std::vector<double>& tmp) {
  Separable3(x, res, out, tmp, [](double a, double b) { return std::max(a, b); });
}

// Level 0 of one row: every texel's stats, the estimator each texel uses at every level
// (cs.cv), its level-0 estimate and variance (cs.est, cs.var) and the variance its level is
// chosen by (cs.v). Returns the rays traced.
uint64_t LevelZero(const Sampler& s, uint64_t row, const RowPoint& rp, RowScratch& sc, ConvergedScratch& cs) {
  const uint64_t rays = s.DirectStats(row, rp, cs.stats.data(), sc);
  const bool exact = s.UnoccludedExact(rp, cs.exact.data());
  const uint32_t res = s.cube_res();
  const uint64_t cols = cs.stats.size();
  // Per texel: its samples above the horizon and unoccluded, then their sums over the face's
  // 3×3 neighbourhood (separable: along u, then along v).
  cs.n_active.resize(cols);
  cs.n_visible.resize(cols);
  for (uint64_t c = 0; c < cols; ++c) {
    cs.n_active[c] = cs.stats[c].active;
    cs.n_visible[c] = cs.stats[c].visible;
  }
  Box3(cs.n_active, res, cs.sum_active, cs.tmp_u);
  Box3(cs.n_visible, res, cs.sum_visible, cs.tmp_u);
  // Every texel's estimator from its neighbours' samples (not its own: the estimator must not
  // depend on them, or it is biased), then its estimate and variance.
  for (uint64_t c = 0; c < cols; ++c) {
    const uint64_t active = cs.sum_active[c] - cs.n_active[c], visible = cs.sum_visible[c] - cs.n_visible[c];
    cs.cv[c] = exact && active > 0 && 2 * visible >= active ? 1 : 0;
    cs.est[c] = Estimate(cs.stats[c], cs.cv[c] != 0, cs.exact[c]);
    cs.var[c] = EstimateVariance(cs.stats[c], cs.cv[c] != 0);
  }
  // The variance the level is chosen by: the largest in the neighbourhood (four samples often
  // show none of an edge a neighbour on it shows), and where the neighbourhood's samples saw
  // both sky and occluder, at least a half-covered texel's U²/(4·spp) (an edge between two
  // texels shows in neither's samples).
  Max3(cs.var, res, cs.v, cs.tmp_v);
  for (uint64_t c = 0; c < cols; ++c) {
    if (cs.sum_visible[c] > 0 && cs.sum_visible[c] < cs.sum_active[c]) {
      const double value = exact ? cs.exact[c] : cs.stats[c].vis + cs.stats[c].occ;
      cs.v[c] = std::max(cs.v[c], value * value / (4.0 * s.spp()));
    }
  }
  return rays;
}

// The indirect term's variance (Σ over texels of its mean's) after `paths` paths, from the
// sums of β and β² per texel.
double IndirectVariance(const std::vector<double>& sum, const std::vector<double>& sum2, uint64_t paths) {
  const double p = static_cast<double>(paths);
  double v = 0;
  for (size_t c = 0; c < sum.size(); ++c) v += std::max(0.0, sum2[c] / p - (sum[c] / p) * (sum[c] / p)) / p;
  return v;
}

// Doublings of the indirect term's paths past P0 that the rule of the texels' levels takes
// (one more doubling while it removes more than λ of variance per ray: half the variance
// for as many rays again), for variance v at P0 paths and `ray_cost` rays for those, at most top.
uint32_t IndirectDoublings(double v, double ray_cost, double lambda, uint32_t top) {
  if (!(lambda > 0) || !(v > 0) || !(ray_cost > 0)) return 0;
  // Smallest m with v·2^−m / 2 ≤ λ·ray_cost·2^m.
  const double x = v / (2 * lambda * ray_cost);
  const double m = x > 1 ? std::ceil(std::log2(x) / 2) : 0.0;
  return static_cast<uint32_t>(std::min(m, static_cast<double>(top)));
}

// The indirect term of one row into cs.ind (its variance returned in *var): DefaultPaths()
// paths, doubled while IndirectDoublings' rule, on the row's own measured variance and rays
// per path, asks for it (lambda 0: never). Returns the rays traced.
uint64_t ConvergeIndirect(const Sampler& s, uint64_t row, const RowPoint& rp, double lambda, uint32_t top,
                          ConvergedScratch& cs, double* var, uint64_t* paths_out) {
  const uint64_t p0 = s.DefaultPaths();
  cs.isum.assign(cs.ind.size(), 0.0);
  cs.isum2.assign(cs.ind.size(), 0.0);
  uint64_t rays = 0, done = 0, target = p0;
  for (uint32_t m = 0;; ++m) {
    rays += s.IndirectStats(row, rp, done, target, cs.isum.data(), cs.isum2.data(), &cs.guide);
    done = target;
    *var = IndirectVariance(cs.isum, cs.isum2, done);
    const double per_path = static_cast<double>(rays) / static_cast<double>(done);
    if (m >= top || !(lambda > 0) || !(*var / 2 > lambda * per_path * static_cast<double>(done))) break;
    target = 2 * done;
  }
  for (size_t c = 0; c < cs.ind.size(); ++c) cs.ind[c] = cs.isum[c] / static_cast<double>(done);
  *paths_out = done;
  return rays;
}

// The first-bounce guide of a row from its level-0 stats: each texel weighted by the mean of
// its occluded samples' values (the part of its direct term something blocks: where
// indirect light comes from), a quarter of the paths still cosine-sampled.
void BuildGuide(ConvergedScratch& cs) {
  constexpr double kCosineShare = 0.25;
  cs.guide.alpha = kCosineShare;
  cs.guide.cdf.resize(cs.stats.size());
  double total = 0;
  for (size_t c = 0; c < cs.stats.size(); ++c) cs.guide.cdf[c] = total += std::max(0.0, cs.stats[c].occ);
}

// The pilot texels' own level-0 variances summed by the variance their level is chosen by,
// in bins of 1/256 octave (a bin's texels take the level of its centre, within 0.3% of their
// own v): what the prediction needs, in memory bounded by the range of v (4.5 MB if it spanned
// every double; kilobytes in practice) instead of 8 bytes for each of up to 2048 × 6R² texels
// (400 MB at R = 64).
class VarianceHistogram {
 public:
  void Add(double v, double own) {
    const int64_t b = static_cast<int64_t>(std::floor(std::clamp(std::log2(v), -kRange, kRange) * kPerOctave));
    if (sums_.empty()) first_ = b;
    if (b < first_) {
      sums_.insert(sums_.begin(), static_cast<size_t>(first_ - b), 0.0);
      first_ = b;
    }
    const size_t i = static_cast<size_t>(b - first_);
    if (i >= sums_.size()) sums_.resize(i + 1, 0.0);
    sums_[i] += own;
  }
  bool empty() const { return sums_.empty(); }
  // Σ over the bins of their own variance times weight(v at the bin's centre).
  template <typename Weight>
  double Sum(Weight&& weight) const {
    double total = 0;
    for (size_t i = 0; i < sums_.size(); ++i) {
      if (sums_[i] != 0)
        total +=
            sums_[i] * weight(std::exp2((static_cast<double>(first_ + static_cast<int64_t>(i)) + 0.5) / kPerOctave));
    }
    return total;
  }

 private:
  static constexpr double kPerOctave = 256, kRange = 1100;  // |log2 v| of a double's range
  int64_t first_ = 0;
  std::vector<double> sums_;
};

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
  const uint64_t cols = cs.est.size();
  // Every pilot texel's level-0 estimate's own variance (what the prediction counts) by the
  // variance its level is chosen by (a neighbourhood's largest, an upper bound).
  VarianceHistogram v0;
  std::vector<std::pair<double, double>> indirect;  // with bounces, every pilot row's indirect variance and rays
  double norm2 = 0;
  for (uint64_t row = stride / 2; row < rows; row += stride) {
    ++p.rows;
    const RowPoint rp = s.Primary(row);
    if (!rp.valid) continue;  // an all-zero row
    p.rays += LevelZero(s, row, rp, sc, cs);
    std::fill(cs.ind.begin(), cs.ind.end(), 0.0);
    if (s.bounces() > 0) {  // the indirect term at its first P0 paths: its variance and cost
      BuildGuide(cs);
      double v = 0;
      uint64_t paths = 0;
      const uint64_t r = ConvergeIndirect(s, row, rp, 0.0, 0, cs, &v, &paths);
      p.rays += r;
      if (v > 0) indirect.emplace_back(v, static_cast<double>(r));
    }
    for (size_t c = 0; c < cols; ++c) norm2 += (cs.est[c] + cs.ind[c]) * (cs.est[c] + cs.ind[c]);
    for (size_t c = 0; c < cols; ++c) {
      if (cs.v[c] > 0) v0.Add(cs.v[c], cs.var[c]);
    }
  }
  if (p.rows == 0 || !(norm2 > 0) || (v0.empty() && indirect.empty())) return p;
  p.mean_norm2 = norm2 / static_cast<double>(p.rows);
  // λ: bisection (in log) for the predicted variance of the pilot rows, Σ var·2^(−β·level),
  // to be T² times their squared norm. The prediction falls as λ does.
  const double want = tolerance * tolerance * norm2;
  const uint32_t top = levels - 1;
  auto predicted = [&](double lambda) {
    double total = v0.Sum([&](double v) { return std::pow(2.0, -kBeta * TargetLevel(v, lambda, s.spp(), top)); });
    for (const auto& [v, cost] : indirect) {
      total += v * std::pow(2.0, -1.0 * IndirectDoublings(v, cost, lambda, kIndirectDoublings));
    }
    return total;
  };
  auto largest_within = [&](double bound) {  // the largest λ (fewest rays) whose prediction is within bound
    double lo = 1e-300, hi = 1e300;
    for (int i = 0; i < 200 && hi / lo > 1.0001; ++i) {
      const double mid = std::sqrt(lo) * std::sqrt(hi);
      (predicted(mid) > bound ? hi : lo) = mid;
    }
    return hi;
  };
  // Where even every level at its top does not reach T, the levels go only as far as brings
  // the prediction within 5% of the least they can reach (not every texel and path to the
  // top for the last fraction of a percent); `sample` says so.
  const double least = predicted(1e-300);
  p.reachable = least <= want;
  p.least_error = std::sqrt(least / norm2);
  p.lambda = largest_within(p.reachable ? want : 1.05 * least);
  return p;
}

ConvergedRow TraceConverged(const std::vector<const Sampler*>& levels, uint64_t row, const RowPoint& rp,
                            const Pilot& pilot, float* out, RowScratch& sc, ConvergedScratch& cs) {
  const Sampler& first = *levels.front();
  const uint64_t cols = 6ull * first.cube_res() * first.cube_res();
  const uint32_t top = static_cast<uint32_t>(levels.size()) - 1;
  Size(first, cs);
  ConvergedRow r;
  r.rays = LevelZero(first, row, rp, sc, cs);
  if (first.bounces() > 0) BuildGuide(cs);  // before the levels overwrite the stats of the texels they trace
  // Per texel: Σ w_k est_k, Σ w_k, Σ w_k² var_k with w_k = 2^(βk).
  cs.sum.assign(cs.est.begin(), cs.est.end());
  cs.wsum.assign(cols, 1.0);
  cs.var_sum.assign(cs.var.begin(), cs.var.end());
  for (uint64_t c = 0; c < cols; ++c) cs.target[c] = TargetLevel(cs.v[c], pilot.lambda, first.spp(), top);
  for (uint32_t k = 1; k <= top; ++k) {
    uint64_t picked = 0;
    for (uint64_t c = 0; c < cols; ++c) {
      cs.select[c] = cs.target[c] == k ? 1 : 0;
      picked += cs.select[c];
    }
    if (picked == 0) continue;
    r.rays += levels[k]->DirectStats(row, rp, cs.stats.data(), sc, cs.select.data());
    const double w = std::pow(2.0, kBeta * k);
    for (uint64_t c = 0; c < cols; ++c) {
      if (cs.select[c] == 0) continue;
      cs.sum[c] += w * Estimate(cs.stats[c], cs.cv[c] != 0, cs.exact[c]);
      cs.wsum[c] += w;
      cs.var_sum[c] += w * w * EstimateVariance(cs.stats[c], cs.cv[c] != 0);
    }
    r.level = k;
  }
  std::fill(cs.ind.begin(), cs.ind.end(), 0.0);
  double err2 = 0;
  if (first.bounces() > 0) {
    uint64_t paths = 0;
    r.rays += ConvergeIndirect(first, row, rp, pilot.lambda, kIndirectDoublings, cs, &err2, &paths);
    r.level = std::max<uint32_t>(r.level, static_cast<uint32_t>(std::log2(paths / first.DefaultPaths())));
  }
  for (uint64_t c = 0; c < cols; ++c) {
    out[c] = static_cast<float>(cs.sum[c] / cs.wsum[c] + cs.ind[c]);
    err2 += cs.var_sum[c] / (cs.wsum[c] * cs.wsum[c]);
  }
  const double rms_norm = std::sqrt(pilot.mean_norm2);
  r.rel_error = rms_norm > 0 ? std::sqrt(err2) / rms_norm : 0.0;
  return r;
}

}  // namespace ltb::sample
