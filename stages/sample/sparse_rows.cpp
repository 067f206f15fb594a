#include "stages/sample/sparse_rows.h"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <numeric>

namespace ltb::sample::sparse {

void GridSelection(uint32_t r, const double* unoccluded, std::vector<uint8_t>* select) {
  const uint64_t rr = uint64_t{r} * r, cols = 6 * rr;
  select->assign(cols, 0);
  for (uint64_t c = 0; c < cols; ++c) {
    const uint64_t s = c % rr % r, t = c % rr / r;
    (*select)[c] = (s % 2 == 0 && t % 2 == 0 && unoccluded[c] > 0) ? 1 : 0;
  }
}

uint64_t SecondPass(uint32_t r, const double* unoccluded, const std::vector<uint8_t>& grid, double* value,
                    std::vector<uint8_t>* select) {
  const uint64_t rr = uint64_t{r} * r, cols = 6 * rr;
  select->assign(cols, 0);
  uint64_t features = 0;
  const int64_t ri = r;
  for (uint64_t c = 0; c < cols; ++c) {
    if (grid[c]) continue;
    if (!(unoccluded[c] > 0)) {
      value[c] = 0;
      continue;
    }
    const uint64_t face = c / rr;
    const int64_t s = static_cast<int64_t>(c % rr % r), t = static_cast<int64_t>(c % rr / r);
    bool any = false, uniform = true;
    double v0 = 0;
    for (int64_t y = std::max<int64_t>(0, t - kWindowHalf); y <= std::min(ri - 1, t + kWindowHalf) && uniform; ++y) {
      for (int64_t x = std::max<int64_t>(0, s - kWindowHalf); x <= std::min(ri - 1, s + kWindowHalf); ++x) {
        const uint64_t j = face * rr + static_cast<uint64_t>(y) * r + static_cast<uint64_t>(x);
        if (!grid[j]) continue;
        const double v = value[j] / unoccluded[j];
        if (!any) {
          any = true;
          v0 = v;
        } else if (v != v0) {
          uniform = false;
          break;
        }
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

void PackBits(const std::vector<uint8_t>& flags, uint8_t* packed) {
  std::fill_n(packed, PackedBytes(flags.size()), uint8_t{0});
  for (uint64_t c = 0; c < flags.size(); ++c) {
    if (flags[c]) packed[c >> 3] = static_cast<uint8_t>(packed[c >> 3] | (1u << (c & 7)));
  }
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
  Eigen::MatrixXd gram(k, k);
  for (Eigen::Index i = 0; i < k; ++i) {
    for (Eigen::Index j = 0; j <= i; ++j) {
      double s = 0;
      const float* a = rows[static_cast<size_t>(i)];
      const float* b = rows[static_cast<size_t>(j)];
      for (uint64_t c = 0; c < m; ++c) s += static_cast<double>(a[c]) * b[c];
      gram(i, j) = gram(j, i) = s;
    }
  }
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
  for (int64_t x = cx - span; x <= cx + span; ++x) {
    for (int64_t y = cy - span; y <= cy + span; ++y) {
      for (int64_t z = cz - span; z <= cz + span; ++z) {
        auto it = cells_.find(Key(x, y, z));
        if (it == cells_.end()) continue;
        for (uint32_t i : it->second) {
          if (static_cast<int64_t>(i) == skip) continue;
          const glm::dvec3 d = points_[i] - p;
          const double d2 = d.x * d.x + d.y * d.y + d.z * d.z;
          if (d2 > r2) continue;
          const glm::dvec3& m = normals_[i];
          if (n.x * m.x + n.y * m.y + n.z * m.z < cos_min) continue;
          found.emplace_back(d2, i);
        }
      }
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
  sc.weight.assign(cols, 0.0);
  sc.b.assign(cols, 0.0);  // the neighbours' mean, for the texels without weight
  sc.a.assign(cols, 0.0);  // Σ x²
  std::vector<double>& w = sc.weight;
  std::vector<double>& mean = sc.b;
  std::vector<double>& sq = sc.a;
  for (const DenseView& v : nb) {
    const float* d = v.direct;
    for (uint64_t c = 0; c < cols; ++c) {
      const double x = d[c];
      mean[c] += x;
      sq[c] += x * x;
    }
  }
  std::vector<uint32_t>& order = sc.order;
  order.clear();
  for (uint64_t c = 0; c < cols; ++c) {
    mean[c] *= inv;
    if (!relevant[c]) continue;
    const double var = std::max(0.0, sq[c] * inv - mean[c] * mean[c]);
    uint32_t feat = 0;
    for (const DenseView& v : nb) feat += Bit(v.features, c) ? 1 : 0;
    w[c] = var * (1.0 + feat);
    order.push_back(static_cast<uint32_t>(c));
  }
  // The largest weights first, ties to the lower texel.
  auto by_weight = [&](uint32_t x, uint32_t y) { return w[x] != w[y] ? w[x] > w[y] : x < y; };
  const size_t take = std::min<size_t>(count, order.size());
  std::partial_sort(order.begin(), order.begin() + static_cast<std::ptrdiff_t>(take), order.end(), by_weight);
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
  // The row in double: Σ α_k direct_k over relevant texels, + Σ α_k indirect_k everywhere.
  std::vector<double>& row = sc.weight;
  row.assign(cols, 0.0);
  for (size_t j = 0; j < k; ++j) {
    const double a = sc.alpha[j];
    if (a == 0) continue;
    const float* d = nb[j].direct;
    for (uint64_t c = 0; c < cols; ++c) row[c] += relevant[c] ? a * d[c] : 0.0;
  }
  for (size_t i = 0; i < m; ++i) row[texels[i]] = b[i];
  for (size_t j = 0; j < k; ++j) {
    const double a = sc.alpha[j];
    if (a == 0 || nb[j].indirect == nullptr) continue;
    const float* d = nb[j].indirect;
    for (uint64_t c = 0; c < cols; ++c) row[c] += a * d[c];
  }
  for (uint64_t c = 0; c < cols; ++c) out[c] = static_cast<float>(std::max(0.0, row[c]));
  return fit;
}

}  // namespace ltb::sample::sparse
