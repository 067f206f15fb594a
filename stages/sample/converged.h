// Internal to the sample stage: converged sampling (`sample --tolerance T`, docs/SAMPLE.md
// "Converged sampling"). T is the relative RMS (Frobenius) error the matrix is sampled to:
// the relit image's relative error under lighting that varies from texel to texel (under
// smooth lighting it is smaller). Rays go where the error is, by texel: σ varies widely
// between texels (one wholly visible or wholly occluded has almost none, one a shadow edge
// crosses has most), far more than between rows.
//
// The estimator, per texel and level: Transport's mean of the unoccluded samples, or for a
// diffuse row point a control variate, U − mean((1 − V)·f), U the texel's exact unoccluded
// value (Sampler::UnoccludedExact, Lambert's formula). Both are unbiased; the control variate
// is exact (variance 0) where no sample is occluded, the plain mean where every sample is,
// so each texel takes the one its face's 3×3 neighbours (not itself: the choice must not
// depend on its own samples, or the estimate is biased) say fits: the control variate where
// at least half of the neighbours' samples saw the sky. Across a scene most texels of most
// rows are then exact, and the variance is where the shadow edges are.
//
// Levels, not passes: texel c is estimated at spp (level 0), and where that does not suffice
// once more, from scratch, at spp·2^k for the one level k its level-0 variance calls for (at
// most max_levels − 1), a fresh stratified set with its own seed (LevelSeed(seed, k)).
// Independent passes of spp samples would lose what stratification gives: across a shadow
// edge a stratified estimate's variance falls as n^−1.5, a mean of independent passes' only
// as n^−1 (and growing a texel level by level costs twice its last level). The texel's
// estimate combines its two levels with fixed weights 1 and 2^(1.5k) (inverse to that
// model's variances; fixed, so unbiased); its variance is the same combination of each
// level's estimate (the samples' spread over n: every stratum's difference counts, so it
// does not miss an edge that runs between the strata of a pair).
//
// Which level: the one past which one more level's drop in variance per ray,
// v_k (1 − 2^−1.5) / (spp·2^(k+1)) with v_k = v·2^(−1.5k), is below λ (the greedy optimum
// of total variance for the rays spent). v is the largest level-0 variance of the texel's
// face's 3×3 neighbourhood (four samples often show none of the variance of a texel an edge
// crosses; a neighbour on the same edge shows it), and where the neighbourhood's samples saw
// both sky and occluder, at least the variance of a half-covered texel's mean, U²/(4·spp) (an
// edge between two texels shows in neither's samples). λ is set once from a pilot (level 0
// of a fixed subset of rows) so that the predicted variance of the matrix is T² times its
// squared norm. Deterministic for a seed and T (the pilot's rows and every decision depend
// on nothing else), so a resumed or sharded bake decides alike.
//
// Bounces: a row's indirect term starts at the fixed bake's paths (DefaultPaths) and doubles,
// at most 2^10 times, while one more doubling removes more than λ of variance per ray (its
// variance from the escaping paths' β and β² per texel; the same λ, so the pilot's prediction
// counts it). Its first directions are guided (IndirectGuide): three quarters drawn from the
// texels by the occluded part of their level-0 direct samples — indirect light only comes
// in where something blocks the sky, and a cosine-sampled path that escapes at once is a
// wasted ray — a quarter from the cosine, so the mixture's density covers every direction
// and the estimate stays unbiased (the guide depends only on the direct samples, which are
// independent of the paths').
#pragma once

#include <cstdint>
#include <vector>

#include "stages/sample/sampler.h"

namespace ltb::sample {

// The seed of level k (k = 0: the seed itself).
uint64_t LevelSeed(uint64_t seed, uint32_t k);

// The pilot: level 0 of every stride-th row from stride/2 (rows/32 of them, at least 64 or
// all, at most 2048: a few percent of one pass), and λ for tolerance T over `levels` levels.
struct Pilot {
  uint64_t rows = 0, rays = 0;
  double mean_norm2 = 0;  // N², the mean squared row norm (rows that see no geometry count as 0)
  double lambda = 0;      // 0: no light seen (every texel stays at level 0)
  // Whether the levels can reach the tolerance at all (predicted), and the least relative
  // error they can reach (with every texel and path at its top).
  bool reachable = true;
  double least_error = 0;
};
Pilot PilotRows(const Sampler& s, uint64_t rows, uint32_t levels, double tolerance);

struct ConvergedRow {
  uint32_t level = 0;  // the highest level a texel of the row went to (0: spp alone)
  uint64_t rays = 0;
  double rel_error = 0;  // the row's estimated RMS error (direct term) over the RMS row norm N
};

// Scratch of one thread, reused from row to row.
struct ConvergedScratch {
  std::vector<TexelStats> stats;
  std::vector<double> exact, est, var, sum, wsum, var_sum, v, ind, isum, isum2;
  std::vector<uint32_t> target;
  std::vector<uint8_t> cv, select;
  std::vector<uint32_t> n_active, n_visible, sum_active, sum_visible, tmp_u;
  std::vector<double> tmp_v;
  IndirectGuide guide;
};

// One row of T (6R² values into out) from levels[k] (a sampler of spp·2^k, seed LevelSeed(k)).
ConvergedRow TraceConverged(const std::vector<const Sampler*>& levels, uint64_t row, const RowPoint& rp,
                            const Pilot& pilot, float* out, RowScratch& sc, ConvergedScratch& cs);

}  // namespace ltb::sample
