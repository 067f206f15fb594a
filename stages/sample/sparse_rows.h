// Internal to `ltbake sample --sparse` (docs/SPARSE.md; Huang & Ramamoorthi 2010): the parts
// of sparse precomputation that do not trace rays — the dense rows' adaptive angular
// sampling (§4.2), the local rank that places dense rows (§4.1), the choice of a sparse
// row's feature texels (§5.2), its reconstruction from dense neighbours by L1-regularised
// least squares (§5.1) and the spatial search for neighbours (§5.3). stages/sample/sparse.cpp
// drives them; tests/sample/sparse_rows_test.cpp checks them on synthetic rows.
#pragma once

#include <cstdint>
#include <glm/vec3.hpp>
#include <span>
#include <unordered_map>
#include <vector>

#include "stages/sample/l1_solver.h"

namespace ltb::sample::sparse {

// ---- Dense rows: adaptive angular sampling (§4.2) ----

// Half-width of the window whose sampled texels decide whether a texel is traced (7×7).
inline constexpr int kWindowHalf = 3;

// The first pass: texels (face, s, t) with s and t even — a quarter of them — among those
// with unoccluded[c] > 0 (not wholly below the horizon). select gets 6R² flags.
void GridSelection(uint32_t r, const double* unoccluded, std::vector<uint8_t>* select);

// The grid texels (even s and t) in the 7×7 window of every texel, across cube edges:
// offset (dx, dy) of texel (face, s, t) is the texel whose direction the face's plane
// extended to (s + dx, t + dy) points to, so a window near an edge continues on the
// neighbouring face. At most 16 per texel inside a face; repeats removed.
class WindowTable {
 public:
  explicit WindowTable(uint32_t r);
  std::span<const uint32_t> Of(uint64_t c) const { return {ids_.data() + start_[c], start_[c + 1] - start_[c]}; }

 private:
  std::vector<uint64_t> start_;
  std::vector<uint32_t> ids_;
};

// The second pass. For each texel c off the grid with unoccluded[c] > 0: the visible
// fractions v_j = value[j] / unoccluded[j] of the grid texels j with unoccluded[j] > 0 in
// c's window. When they are all equal (say to v), c is not traced
// and value[c] = unoccluded[c]·v; otherwise (or when the window holds none) select[c] = 1:
// c is a feature and must be traced. A texel with unoccluded[c] == 0 gets value 0. Reads
// value[j] only on the grid. Returns the number of features.
uint64_t SecondPass(const WindowTable& windows, const double* unoccluded, const std::vector<uint8_t>& grid,
                    double* value, std::vector<uint8_t>* select);

// ---- Local rank (§4.1) ----

// Box-filters a row of 6R² texels to 6·r_low² (r_low divides r).
void Downsample(const float* row, uint32_t r, uint32_t r_low, float* out);

// The numerical rank of the rows (each of m values): the number of singular values above
// rel_threshold × the largest (0 for all-zero rows).
int NumericalRank(std::span<const float* const> rows, uint64_t m, double rel_threshold);

// ---- Neighbours (§5.3) ----

// Points in a uniform grid of cells of a given size, for radius-restricted k-nearest
// queries with a normal filter. Deterministic: ties in distance go to the lower index.
class PointGrid {
 public:
  PointGrid(double cell, std::span<const glm::dvec3> points, std::span<const glm::dvec3> normals);
  // Up to k indices of points within `radius` of p whose normal m has n·m ≥ cos_min, the
  // nearest first. `skip` (an index or -1) is left out.
  void Query(const glm::dvec3& p, const glm::dvec3& n, double radius, uint32_t k, double cos_min, int64_t skip,
             std::vector<uint32_t>* out) const;
  size_t size() const { return points_.size(); }

 private:
  uint64_t Key(int64_t x, int64_t y, int64_t z) const;
  double cell_;
  std::span<const glm::dvec3> points_, normals_;
  std::unordered_map<uint64_t, std::vector<uint32_t>> cells_;
};

// ---- Sparse rows: features and reconstruction (§5.1, §5.2) ----

// A dense neighbour: its direct term (6R² values), its indirect term (or null without
// bounces) and its feature flags (6R² bytes, 1 where the texel was a feature).
struct DenseView {
  const float* direct = nullptr;
  const float* indirect = nullptr;
  const uint8_t* features = nullptr;
};

struct Scratch {
  std::vector<double> weight, a, b, alpha;
  std::vector<float> sum, sum_sq, row;
  std::vector<uint32_t> order;
  std::vector<uint8_t> count;
  L1Scratch l1;
};

// The feature texels of a sparse row: among the texels with relevant[c] != 0 (not wholly
// below the row's horizon), the `count` with the largest weight
//   w_c = variance over the neighbours of direct_k[c] × (1 + number of neighbours for which c was a feature),
// ties to the lower texel; only texels with w_c > 0, but at least min(count, min_count)
// texels, the rest by the neighbours' mean direct term. Sorted ascending.
void ChooseFeatures(std::span<const DenseView> nb, uint64_t cols, const uint8_t* relevant, uint32_t count,
                    uint32_t min_count, Scratch& sc, std::vector<uint32_t>* texels);

struct Fit {
  double residual = 0;  // ‖Aα − b‖ / ‖b‖ on the traced texels (0 when b = 0)
  L1Result solve;
};

// Solves α (L1-regularised least squares) so that Σ_k α_k direct_k matches the traced
// values b at `texels`, then writes the row: out[c] = Σ_k α_k (direct_k[c] + indirect_k[c]);
// at a traced texel the direct part is b itself, at a texel with relevant[c] == 0 there is
// none; every value is clamped at 0. sc.alpha holds α afterwards.
Fit Reconstruct(std::span<const DenseView> nb, uint64_t cols, const std::vector<uint32_t>& texels, const double* b,
                const uint8_t* relevant, const L1Options& options, Scratch& sc, float* out);

}  // namespace ltb::sample::sparse
