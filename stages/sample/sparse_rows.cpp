#include "stages/sample/sparse_rows.h"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>

#include "stages/common/cubemap.h"

namespace ltb::sample::sparse {

void GridSelection(uint32_t r, const double* unoccluded, std::vector<uint8_t>* select) {
  const uint64_t rr = uint64_t{r} * r, cols = 6 * rr;
  select->assign(cols, 0);
  for (uint64_t c = 0; c < cols; ++c) {
    const uint64_t s = c % rr % r, t = c % rr / r;
    (*select)[c] = (s % 2 == 0 && t % 2 == 0 && unoccluded[c] > 0) ? 1 : 0;
  }
}

WindowTable::WindowTable(uint32_t r) {
  const uint64_t cols = 6ull * r * r, rr = uint64_t{r} * r;
  start_.reserve(cols + 1);
  start_.push_back(0);
  std::vector<uint32_t> window;
  for (uint64_t c = 0; c < cols; ++c) {
    const cubemap::Texel x = cubemap::ColumnToTexel(c, r);
    window.clear();
    for (int dy = -kWindowHalf; dy <= kWindowHalf; ++dy) {
      for (int dx = -kWindowHalf; dx <= kWindowHalf; ++dx) {
        const double u = 2.0 * (x.s + dx + 0.5) / r - 1.0, v = 2.0 * (x.t + dy + 0.5) / r - 1.0;
        uint64_t id = 0;
        if (u > -1 && u < 1 && v > -1 && v < 1) {
          id = x.face * rr + static_cast<uint64_t>(x.t + dy) * r + static_cast<uint64_t>(x.s + dx);
        } else {
          id = cubemap::Column(cubemap::DirectionToTexel(cubemap::FaceDirection(x.face, u, v), r), r);
        }
        const uint64_t s = id % rr % r, t = id % rr / r;
        if (s % 2 == 0 && t % 2 == 0) window.push_back(static_cast<uint32_t>(id));
      }
    }
    std::sort(window.begin(), window.end());
    window.erase(std::unique(window.begin(), window.end()), window.end());
    ids_.insert(ids_.end(), window.begin(), window.end());
    start_.push_back(ids_.size());
  }
}

uint64_t SecondPass(const WindowTable& windows, const double* unoccluded, const std::vector<uint8_t>& grid,
                    double* value, std::vector<uint8_t>* select) {
  const uint64_t cols = grid.size();
  select->assign(cols, 0);
  uint64_t features = 0;
  // The visible fraction of every sampled grid texel; NaN marks "not sampled".
  thread_local std::vector<double> frac;
  frac.assign(cols, std::numeric_limits<double>::quiet_NaN());
  for (uint64_t c = 0; c < cols; ++c) {
    if (grid[c]) frac[c] = value[c] / unoccluded[c];
  }
  for (uint64_t c = 0; c < cols; ++c) {
    if (grid[c]) continue;
    if (!(unoccluded[c] > 0)) {
      value[c] = 0;
      continue;
    }
    bool any = false, uniform = true;
    double v0 = 0;
    for (uint32_t j : windows.Of(c)) {
      const double v = frac[j];
      if (std::isnan(v)) continue;
      if (!any) {
        any = true;
        v0 = v;
      } else if (v != v0) {
        uniform = false;
        break;
      }
    }
    if (any && uniform) {
      value[c] = v0 == 1.0 ? unoccluded[c] : unoccluded[c] * v0;
    } else {
      (*select)[c] = 1;
      ++features;
    }
  }
  return features;
}

void Downsample(const float* row, uint32_t r, uint32_t r_low, float* out) {
  const uint32_t f = r / r_low;
  const uint64_t rr = uint64_t{r} * r, ll = uint64_t{r_low} * r_low;
  std::fill_n(out, 6 * ll, 0.0f);
  for (uint64_t face = 0; face < 6; ++face) {
    for (uint32_t t = 0; t < r; ++t) {
      const float* src = row + face * rr + uint64_t{t} * r;
      float* dst = out + face * ll + uint64_t{t / f} * r_low;
      for (uint32_t s = 0; s < r; ++s) dst[s / f] += src[s];
    }
  }
}

int NumericalRank(std::span<const float* const> rows, uint64_t m, double rel_threshold) {
  const auto k = static_cast<Eigen::Index>(rows.size());
  if (k == 0) return 0;
  thread_local Eigen::MatrixXf x;
  x.resize(static_cast<Eigen::Index>(m), k);
  for (Eigen::Index i = 0; i < k; ++i) {
    x.col(i) = Eigen::Map<const Eigen::VectorXf>(rows[static_cast<size_t>(i)], static_cast<Eigen::Index>(m));
  }
  const Eigen::MatrixXd gram = (x.transpose() * x).cast<double>();
  Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eig(gram, Eigen::EigenvaluesOnly);
  const Eigen::VectorXd& ev = eig.eigenvalues();  // ascending; the squared singular values
  const double top = ev(k - 1);
  if (!(top > 0)) return 0;
  const double limit = top * rel_threshold * rel_threshold;
  int rank = 0;
  for (Eigen::Index i = 0; i < k; ++i) rank += ev(i) > limit ? 1 : 0;
  return rank;
}

PointGrid::PointGrid(double cell, std::span<const glm::dvec3> points, std::span<const glm::dvec3> normals)
    : cell_(cell), points_(points), normals_(normals) {
  for (size_t i = 0; i < points.size(); ++i) {
    const glm::dvec3 q = points[i] / cell_;
    cells_[Key(static_cast<int64_t>(std::floor(q.x)), static_cast<int64_t>(std::floor(q.y)),
               static_cast<int64_t>(std::floor(q.z)))]
        .push_back(static_cast<uint32_t>(i));
  }
}

uint64_t PointGrid::Key(int64_t x, int64_t y, int64_t z) const {
  auto part = [](int64_t v) { return static_cast<uint64_t>(v) & 0x1FFFFFull; };
  return part(x) | (part(y) << 21) | (part(z) << 42);
}

void PointGrid::Query(const glm::dvec3& p, const glm::dvec3& n, double radius, uint32_t k, double cos_min, int64_t skip,
                      std::vector<uint32_t>* out) const {
  out->clear();
  thread_local std::vector<std::pair<double, uint32_t>> found;
  found.clear();
  const glm::dvec3 q = p / cell_;
  const auto span = static_cast<int64_t>(std::ceil(radius / cell_));
  const auto cx = static_cast<int64_t>(std::floor(q.x)), cy = static_cast<int64_t>(std::floor(q.y)),
             cz = static_cast<int64_t>(std::floor(q.z));
  const double r2 = radius * radius;
  auto visit = [&](int64_t x, int64_t y, int64_t z) {
    auto it = cells_.find(Key(x, y, z));
    if (it == cells_.end()) return;
    for (uint32_t i : it->second) {
      if (static_cast<int64_t>(i) == skip) continue;
      const glm::dvec3 d = points_[i] - p;
      const double d2 = d.x * d.x + d.y * d.y + d.z * d.z;
      if (d2 > r2) continue;
      const glm::dvec3& m = normals_[i];
      if (n.x * m.x + n.y * m.y + n.z * m.z < cos_min) continue;
      found.emplace_back(d2, i);
    }
  };
  // Shells of cells by Chebyshev distance: a point in shell s + 1 is at least s·cell away,
  // so once k points lie within that, farther shells cannot change the answer.
  for (int64_t sh = 0; sh <= span; ++sh) {
    for (int64_t x = cx - sh; x <= cx + sh; ++x) {
      for (int64_t y = cy - sh; y <= cy + sh; ++y) {
        const bool face = x == cx - sh || x == cx + sh || y == cy - sh || y == cy + sh;
        if (face) {
          for (int64_t z = cz - sh; z <= cz + sh; ++z) visit(x, y, z);
        } else {
          visit(x, y, cz - sh);
          if (sh > 0) visit(x, y, cz + sh);
        }
      }
    }
    if (found.size() >= k) {
      std::nth_element(found.begin(), found.begin() + (k - 1), found.end());
      const double limit = static_cast<double>(sh) * cell_;
      if (found[k - 1].first <= limit * limit) break;
    }
  }
  const size_t keep = std::min<size_t>(k, found.size());
  std::partial_sort(found.begin(), found.begin() + static_cast<std::ptrdiff_t>(keep), found.end());
  for (size_t i = 0; i < keep; ++i) out->push_back(found[i].second);
}

void ChooseFeatures(std::span<const DenseView> nb, uint64_t cols, const uint8_t* relevant, uint32_t count,
                    uint32_t min_count, Scratch& sc, std::vector<uint32_t>* texels) {
  texels->clear();
  const double inv = nb.empty() ? 0.0 : 1.0 / static_cast<double>(nb.size());
  // Sums in f32 (vectorised): the weights only rank texels.
  sc.sum.assign(cols, 0.0f);
  sc.sum_sq.assign(cols, 0.0f);
  sc.count.assign(cols, 0);
  sc.weight.assign(cols, 0.0);
  sc.b.resize(cols);
  float* __restrict sum = sc.sum.data();
  float* __restrict sq = sc.sum_sq.data();
  uint8_t* __restrict feat = sc.count.data();
  for (const DenseView& v : nb) {
    const float* __restrict d = v.direct;
    const uint8_t* __restrict f = v.features;
#pragma omp simd
    for (uint64_t c = 0; c < cols; ++c) {
      sum[c] += d[c];
      sq[c] += d[c] * d[c];
      feat[c] = static_cast<uint8_t>(feat[c] + f[c]);
    }
  }
  double* __restrict w = sc.weight.data();
  double* __restrict mean = sc.b.data();
  std::vector<uint32_t>& order = sc.order;
  order.clear();
  for (uint64_t c = 0; c < cols; ++c) {
    mean[c] = sum[c] * inv;
    if (!relevant[c]) continue;
    const double var = std::max(0.0, sq[c] * inv - mean[c] * mean[c]);
    w[c] = var * (1.0 + feat[c]);
    order.push_back(static_cast<uint32_t>(c));
  }
  // The largest weights first, ties to the lower texel.
  auto by_weight = [&](uint32_t x, uint32_t y) { return w[x] != w[y] ? w[x] > w[y] : x < y; };
  const size_t take = std::min<size_t>(count, order.size());
  if (take < order.size()) {
    std::nth_element(order.begin(), order.begin() + static_cast<std::ptrdiff_t>(take), order.end(), by_weight);
  }
  std::sort(order.begin(), order.begin() + static_cast<std::ptrdiff_t>(take), by_weight);
  size_t n = 0;
  while (n < take && w[order[n]] > 0) texels->push_back(order[n++]);
  const size_t floor = std::min<size_t>(take, min_count);
  if (texels->size() < floor) {
    // Too few informative texels (the neighbours agree nearly everywhere): add the
    // brightest of the rest, which fix the row's scale.
    auto by_mean = [&](uint32_t x, uint32_t y) { return mean[x] != mean[y] ? mean[x] > mean[y] : x < y; };
    std::vector<uint32_t> rest(order.begin() + static_cast<std::ptrdiff_t>(n), order.end());
    const size_t more = std::min(rest.size(), floor - texels->size());
    std::partial_sort(rest.begin(), rest.begin() + static_cast<std::ptrdiff_t>(more), rest.end(), by_mean);
    texels->insert(texels->end(), rest.begin(), rest.begin() + static_cast<std::ptrdiff_t>(more));
  }
  std::sort(texels->begin(), texels->end());
}

Fit Reconstruct(std::span<const DenseView> nb, uint64_t cols, const std::vector<uint32_t>& texels, const double* b,
                const uint8_t* relevant, const L1Options& options, Scratch& sc, float* out) {
  const size_t m = texels.size(), k = nb.size();
  sc.a.resize(m * k);
  for (size_t j = 0; j < k; ++j) {
    for (size_t i = 0; i < m; ++i) sc.a[j * m + i] = nb[j].direct[texels[i]];
  }
  sc.alpha.assign(k, 0.0);
  Fit fit;
  fit.solve =
      SolveL1LeastSquares(sc.a.data(), static_cast<int>(m), static_cast<int>(k), b, options, sc.l1, sc.alpha.data());
  double bb = 0;
  for (size_t i = 0; i < m; ++i) bb += b[i] * b[i];
  fit.residual = bb > 0 ? fit.solve.residual / std::sqrt(bb) : 0.0;
  // The row: Σ α_k direct_k over relevant texels, + Σ α_k indirect_k everywhere (f32,
  // vectorised; at most 64 terms, so the sum's relative rounding stays near 64 ulp).
  sc.row.assign(cols, 0.0f);
  float* __restrict row = sc.row.data();
  for (size_t j = 0; j < k; ++j) {
    const auto a = static_cast<float>(sc.alpha[j]);
    if (a == 0) continue;
    const float* __restrict d = nb[j].direct;
#pragma omp simd
    for (uint64_t c = 0; c < cols; ++c) row[c] += a * d[c];
  }
  for (uint64_t c = 0; c < cols; ++c) row[c] = relevant[c] ? row[c] : 0.0f;
  for (size_t i = 0; i < m; ++i) row[texels[i]] = static_cast<float>(b[i]);
  for (size_t j = 0; j < k; ++j) {
    const auto a = static_cast<float>(sc.alpha[j]);
    if (a == 0 || nb[j].indirect == nullptr) continue;
    const float* __restrict d = nb[j].indirect;
#pragma omp simd
    for (uint64_t c = 0; c < cols; ++c) row[c] += a * d[c];
  }
#pragma omp simd
  for (uint64_t c = 0; c < cols; ++c) out[c] = std::max(0.0f, row[c]);
  return fit;
}

}  // namespace ltb::sample::sparse
