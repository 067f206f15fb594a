// Internal to `ltbake sample --sparse` (docs/SPARSE.md): what the bake (sparse.cpp) and its
// --sparse auto pilot (sparse_auto.cpp) share — the resolved parameters, the rows' primary
// points, a dense row's trace and a sparse row's reconstruction.
#pragma once

#include <chrono>
#include <cstdint>
#include <nlohmann/json.hpp>
#include <span>
#include <vector>

#include "stages/sample/sample_internal.h"
#include "stages/sample/sampler.h"
#include "stages/sample/sparse_rows.h"

namespace ltb::stages::sample_internal::sparse_bake {

using sample::RowPoint;
using sample::RowScratch;
using sample::Sampler;
namespace sp = sample::sparse;

constexpr double kRadiusFactor = 0.04;   // default radius: this × the rows' bounding-box diagonal
constexpr double kNormalCos = 0.5;       // neighbours' normals within 60° of the row's
constexpr uint32_t kRankRes = 8;         // local rank on the cubemap box-filtered to 6·8²
constexpr double kRankThreshold = 0.02;  // singular values above 2% of the largest count
constexpr uint32_t kMinFeatures = 32;    // a sparse row traces at least this many texels
constexpr double kMinWeight = 0.25;      // placement weight of a candidate whose neighbours have rank 0
// The fit stops when its KKT violation is below this × λ_max, or after this many sweeps.
constexpr double kL1Tolerance = 1e-4;
constexpr int kL1MaxSweeps = 200;

enum RowKind : uint8_t { kNone = 0, kDense = 1, kSparse = 2 };

inline double Seconds(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

struct Params {
  uint64_t cols = 0, dense = 0, dense_block = 0;
  std::vector<uint64_t> rounds;  // dense rows per round
  double radius = 0;
  uint32_t features = 0, neighbours = 0;
  sample::L1Options l1;
};

// Per row: the primary point; the rows that see geometry.
struct RowPoints {
  std::vector<RowPoint> pt;
  std::vector<uint64_t> valid;
};

// The primary point of every row (in parallel); the rows that see geometry.
Result<RowPoints> PrimaryPoints(const Sampler& sampler, const Prepared& p, int jobs, const Progress& progress);

// The options resolved against the scene: dense rows and their rounds, radius, features.
Params Resolve(const SampleOptions& o, const Prepared& p, const RowPoints& rows);

// ---- Dense rows ----

struct DenseScratch {
  const sp::WindowTable* windows = nullptr;
  RowScratch sc;
  std::vector<double> unoccluded, value, indirect;
  std::vector<uint8_t> grid, second;
};

struct DenseRowResult {
  uint64_t rays = 0, traced = 0;
};

// One dense row (§4.2): the unoccluded term of every texel (no rays), the regular grid,
// then the texels whose window disagrees; the indirect term with a quarter of the paths.
// direct (and indirect, unless null) get 6R² values, features (unless null) the flags.
DenseRowResult TraceDenseRow(const Sampler& s, uint64_t row, const RowPoint& rp, uint64_t cols, DenseScratch& ds,
                             float* direct, float* indirect, uint8_t* features);

// What both phases read: the options, the scene, its rows and the resolved parameters.
struct Context {
  const SampleOptions& o;
  const Prepared& p;
  const Sampler& s;
  const RowPoints& pts;
  const Params& pr;
  const sp::WindowTable& windows;
  const Progress& progress;
};

// ---- Sparse rows ----

// What became of a row phase 2 reconstructs.
struct SparseRowOutcome {
  RowKind kind = kSparse;  // kDense: traced like a dense row instead (residual: the failed fit's, or 1)
  float residual = 0;
  uint32_t traced = 0;  // texels traced
  uint64_t rays = 0;
};

// The dense neighbours of a row (indices into the grid's points): within the radius, twice
// and four times it when fewer than two are found; at most pr.neighbours, the nearest first.
void DenseNeighbours(const Context& c, const sp::PointGrid& grid, const RowPoint& rp, std::vector<uint32_t>* nb);

// Phase 2's work on one row that is not dense (§5): its neighbours among the dense rows of
// `grid` (views[i] is the grid's point i), its feature texels traced, the fit, and out (6R²
// values) written; traced like a dense row instead when no dense row is near, or when the
// fit misses its own traced texels by more than --max-residual.
SparseRowOutcome ReconstructRow(const Context& c, const sp::PointGrid& grid, std::span<const sp::DenseView> views,
                                uint64_t row, const RowPoint& rp, float* out);

// ---- --sparse auto (sparse_auto.cpp) ----

// The pilot's decision, or the one recorded in the output an earlier run started for the same
// scene, R, spp, bounces and seed: sparse when its predicted CPU time is at most the margin of the full bake's.
Result<SparseAuto> DecideSparse(const Context& c);

// The record in the output's provenance ("sparse_auto"), and back.
nlohmann::json SparseAutoJson(const SparseAuto& d);
Result<SparseAuto> SparseAutoFromJson(const nlohmann::json& j);

}  // namespace ltb::stages::sample_internal::sparse_bake
