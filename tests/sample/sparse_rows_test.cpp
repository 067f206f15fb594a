// The ray-free parts of sparse precomputation (stages/sample/sparse_rows.h) on synthetic
// rows whose answers are known in closed form: the adaptive angular sampling on
// piecewise-constant visibility, the reconstruction of a row planted in its neighbours'
// span, the neighbour search against brute force, and the numerical rank against planted ranks.
#include "stages/sample/sparse_rows.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <glm/geometric.hpp>
#include <random>
#include <vector>

namespace ltb::sample::sparse {
namespace {

// A smooth positive "unoccluded" term per texel and a visibility that is 1 outside a disc
// on face `face` (centre (cs, ct), radius rad texels) and 0 inside.
struct Synthetic {
  uint32_t r;
  std::vector<double> unoccluded, exact;
  std::vector<uint8_t> visible;
};

Synthetic MakeDiscShadow(uint32_t r, int face, double cs, double ct, double rad) {
  Synthetic s{r, {}, {}, {}};
  const uint64_t rr = uint64_t{r} * r, cols = 6 * rr;
  s.unoccluded.resize(cols);
  s.exact.resize(cols);
  s.visible.resize(cols);
  for (uint64_t c = 0; c < cols; ++c) {
    const double x = static_cast<double>(c % rr % r) + 0.5, y = static_cast<double>(c % rr / r) + 0.5;
    const auto f = static_cast<int>(c / rr);
    // Face 5 is wholly "below the horizon"; the others carry a smooth positive term.
    s.unoccluded[c] = f == 5 ? 0.0 : 1.0 + 0.3 * std::sin(0.7 * x + f) * std::cos(0.4 * y);
    const bool in = f == face && std::hypot(x - cs, y - ct) < rad;
    s.visible[c] = in ? 0 : 1;
    s.exact[c] = in ? 0.0 : s.unoccluded[c];
  }
  return s;
}

TEST(SparseAngular, GridIsAQuarterOfTheTexelsAboveTheHorizon) {
  Synthetic s = MakeDiscShadow(16, 2, 8, 8, 3.3);
  std::vector<uint8_t> grid;
  GridSelection(16, s.unoccluded.data(), &grid);
  // Faces 0..4 are above the horizon: (16/2)² grid texels each.
  EXPECT_EQ(std::count(grid.begin(), grid.end(), uint8_t{1}), 5 * 8 * 8);
  for (uint64_t c = 0; c < grid.size(); ++c) {
    if (grid[c]) {
      EXPECT_GT(s.unoccluded[c], 0.0);
    }
  }
}

TEST(SparseAngular, EveryTexelNearAShadowEdgeIsTracedAndTheRestIsExact) {
  for (double rad : {2.6, 3.3, 5.1}) {
    const uint32_t r = 16;
    Synthetic s = MakeDiscShadow(r, 2, 7.3, 8.9, rad);
    std::vector<uint8_t> grid, second;
    GridSelection(r, s.unoccluded.data(), &grid);
    std::vector<double> value(s.exact.size(), -1.0);
    for (uint64_t c = 0; c < grid.size(); ++c) {
      if (grid[c]) value[c] = s.exact[c];  // "traced"
    }
    const uint64_t features = SecondPass(WindowTable(r), s.unoccluded.data(), grid, value.data(), &second);
    EXPECT_EQ(features, static_cast<uint64_t>(std::count(second.begin(), second.end(), uint8_t{1})));
    EXPECT_GT(features, 0u);
    const uint64_t rr = uint64_t{r} * r;
    for (uint64_t c = 0; c < s.exact.size(); ++c) {
      if (second[c]) {
        value[c] = s.exact[c];  // the second pass traces it
        continue;
      }
      // Not traced: the filled value must be the exact one, bit for bit.
      EXPECT_EQ(value[c], s.exact[c]) << "radius " << rad << " texel " << c;
      // A texel whose 4-neighbour on its face differs in visibility borders an edge: it
      // must be on the grid or a feature.
      const uint64_t face = c / rr, x = c % rr % r, y = c % rr / r;
      auto differs = [&](int64_t dx, int64_t dy) {
        const int64_t nx = static_cast<int64_t>(x) + dx, ny = static_cast<int64_t>(y) + dy;
        if (nx < 0 || ny < 0 || nx >= r || ny >= r) return false;
        return s.visible[face * rr + static_cast<uint64_t>(ny) * r + static_cast<uint64_t>(nx)] != s.visible[c];
      };
      if (s.unoccluded[c] > 0 && (differs(1, 0) || differs(-1, 0) || differs(0, 1) || differs(0, -1))) {
        EXPECT_TRUE(grid[c]) << "edge texel " << c << " was neither traced nor on the grid";
      }
    }
    // And far fewer than all texels were traced.
    const auto grid_n = static_cast<uint64_t>(std::count(grid.begin(), grid.end(), uint8_t{1}));
    EXPECT_LT(grid_n + features, 5 * rr / 2);
  }
}

TEST(SparseAngular, NoShadowNeedsNoSecondPass) {
  Synthetic s = MakeDiscShadow(8, 0, -100, -100, 1);  // the disc is off the face
  std::vector<uint8_t> grid, second;
  GridSelection(8, s.unoccluded.data(), &grid);
  std::vector<double> value(s.exact.size(), 0.0);
  for (uint64_t c = 0; c < grid.size(); ++c) value[c] = grid[c] ? s.exact[c] : 0.0;
  EXPECT_EQ(SecondPass(WindowTable(8), s.unoccluded.data(), grid, value.data(), &second), 0u);
  for (uint64_t c = 0; c < value.size(); ++c) EXPECT_EQ(value[c], s.exact[c]);
}

// Dense rows with a few shared shadow shapes and a sparse row planted in their span.
struct Planted {
  uint64_t cols;
  std::vector<std::vector<float>> direct, indirect;
  std::vector<std::vector<uint8_t>> features;
  std::vector<float> row;  // Σ α_k (direct_k + indirect_k), exactly in double then rounded
  std::vector<double> alpha;
};

Planted MakePlanted(uint64_t cols, int k, int support, bool bounces, uint32_t seed) {
  std::mt19937_64 g(seed);
  std::uniform_real_distribution<double> u(0, 1);
  Planted p{cols, {}, {}, {}, {}, {}};
  for (int j = 0; j < k; ++j) {
    std::vector<float> d(cols), ind(cols);
    std::vector<uint8_t> f(cols, 0);
    const double edge = u(g) * static_cast<double>(cols);
    for (uint64_t c = 0; c < cols; ++c) {
      const double smooth = 1.0 + 0.5 * std::sin(0.01 * static_cast<double>(c) * (1 + 0.1 * j));
      const bool lit = static_cast<double>(c) < edge || (c / 37) % (j + 2) != 0;
      d[c] = static_cast<float>(lit ? smooth : 0.0);
      ind[c] = bounces ? static_cast<float>(0.05 * (1 + std::cos(0.003 * static_cast<double>(c) + j))) : 0.0f;
      if (c > 0 && lit != (d[c - 1] > 0)) f[c] = 1;
    }
    p.direct.push_back(d);
    p.indirect.push_back(ind);
    p.features.push_back(f);
  }
  p.alpha.assign(static_cast<size_t>(k), 0.0);
  for (int i = 0; i < support; ++i) p.alpha[static_cast<size_t>(i * 3 % k)] = 0.2 + u(g);
  p.row.resize(cols);
  for (uint64_t c = 0; c < cols; ++c) {
    double s = 0;
    for (int j = 0; j < k; ++j) s += p.alpha[static_cast<size_t>(j)] * (double{p.direct[j][c]} + p.indirect[j][c]);
    p.row[c] = static_cast<float>(s);
  }
  return p;
}

TEST(SparseReconstruct, APlantedCombinationComesBackAtFloatPrecision) {
  for (bool bounces : {false, true}) {
    const uint64_t cols = 1536;
    Planted p = MakePlanted(cols, 12, 3, bounces, 11);
    std::vector<DenseView> nb;
    for (size_t j = 0; j < p.direct.size(); ++j) {
      nb.push_back({p.direct[j].data(), bounces ? p.indirect[j].data() : nullptr, p.features[j].data()});
    }
    std::vector<uint8_t> relevant(cols, 1);
    Scratch sc;
    std::vector<uint32_t> texels;
    ChooseFeatures(nb, cols, relevant.data(), 88, 32, sc, &texels);
    ASSERT_EQ(texels.size(), 88u);
    EXPECT_TRUE(std::is_sorted(texels.begin(), texels.end()));
    // The "traced" values: the planted row's direct part at the features.
    std::vector<double> b(texels.size());
    for (size_t i = 0; i < texels.size(); ++i) {
      double s = 0;
      for (size_t j = 0; j < nb.size(); ++j) s += p.alpha[j] * p.direct[j][texels[i]];
      b[i] = s;
    }
    L1Options opt;
    opt.lambda_rel = 1e-9;  // shrinkage far below f32 precision
    opt.tolerance = 1e-12;
    std::vector<float> out(cols);
    Fit fit = Reconstruct(nb, cols, texels, b.data(), relevant.data(), opt, sc, out.data());
    EXPECT_TRUE(fit.solve.converged);
    EXPECT_LT(fit.residual, 1e-7);  // the shrinkage of λ = 1e-9·λ_max, times the conditioning
    double err = 0, norm = 0;
    for (uint64_t c = 0; c < cols; ++c) {
      err += (double{out[c]} - p.row[c]) * (double{out[c]} - p.row[c]);
      norm += double{p.row[c]} * p.row[c];
    }
    // f32 accumulation of ≤ 12 terms of magnitude ≤ ~2·max α: a few ulp per value.
    EXPECT_LT(std::sqrt(err / norm), 1e-6) << "bounces " << bounces;
  }
}

TEST(SparseReconstruct, TexelsBelowTheHorizonGetNoDirectTermAndValuesAreClamped) {
  const uint64_t cols = 96;
  std::vector<float> d1(cols, 1.0f), d2(cols, 2.0f), ind(cols, 0.25f);
  std::vector<uint8_t> f(cols, 0), relevant(cols, 1);
  for (uint64_t c = 0; c < 20; ++c) relevant[c] = 0;
  std::vector<DenseView> nb = {{d1.data(), ind.data(), f.data()}, {d2.data(), ind.data(), f.data()}};
  std::vector<uint32_t> texels = {40, 50, 60};
  std::vector<double> b = {-3.0, -3.0, -3.0};  // a row the fit can only match with negative weights
  L1Options opt;
  Scratch sc;
  std::vector<float> out(cols, 7.0f);
  Reconstruct(nb, cols, texels, b.data(), relevant.data(), opt, sc, out.data());
  for (uint64_t c = 0; c < cols; ++c) EXPECT_GE(out[c], 0.0f);
  // Below the horizon only the indirect part remains: Σ α_k · 0.25 (α negative here: 0).
  for (uint64_t c = 0; c < 20; ++c) EXPECT_EQ(out[c], 0.0f);
}

TEST(SparseNeighbours, GridQueryEqualsBruteForce) {
  std::mt19937_64 g(3);
  std::uniform_real_distribution<double> u(-1, 1);
  std::vector<glm::dvec3> pts(3000), nor(3000);
  for (size_t i = 0; i < pts.size(); ++i) {
    pts[i] = {u(g), u(g), 0.2 * u(g)};
    nor[i] = glm::dvec3(0, 0, i % 4 == 0 ? -1.0 : 1.0);
  }
  for (double cell : {0.05, 0.2, 1.0}) {
    PointGrid grid(cell, pts, nor);
    for (int q = 0; q < 200; ++q) {
      const glm::dvec3 p(u(g), u(g), 0.0), n(0, 0, 1);
      for (double radius : {0.03, 0.15, 0.6}) {
        std::vector<uint32_t> got;
        grid.Query(p, n, radius, 16, 0.5, q % 2 == 0 ? 5 : -1, &got);
        std::vector<std::pair<double, uint32_t>> all;
        for (uint32_t i = 0; i < pts.size(); ++i) {
          if (q % 2 == 0 && i == 5) continue;
          const glm::dvec3 d = pts[i] - p;
          const double d2 = d.x * d.x + d.y * d.y + d.z * d.z;
          if (d2 <= radius * radius && glm::dot(n, nor[i]) >= 0.5) all.emplace_back(d2, i);
        }
        std::sort(all.begin(), all.end());
        std::vector<uint32_t> want;
        for (size_t i = 0; i < std::min<size_t>(16, all.size()); ++i) want.push_back(all[i].second);
        EXPECT_EQ(got, want) << "cell " << cell << " radius " << radius;
      }
    }
  }
}

TEST(SparseRank, PlantedRanksAreFound) {
  std::mt19937_64 g(5);
  std::normal_distribution<double> n01;
  const uint64_t m = 384;
  for (int rank : {1, 3, 7}) {
    std::vector<std::vector<float>> basis(static_cast<size_t>(rank), std::vector<float>(m));
    for (auto& b : basis)
      for (auto& x : b) x = static_cast<float>(n01(g));
    std::vector<std::vector<float>> rows(16, std::vector<float>(m, 0.0f));
    for (auto& row : rows) {
      for (const auto& b : basis) {
        const double w = n01(g);
        for (uint64_t c = 0; c < m; ++c) row[c] += static_cast<float>(w * b[c]);
      }
    }
    std::vector<const float*> ptrs;
    for (const auto& row : rows) ptrs.push_back(row.data());
    EXPECT_EQ(NumericalRank(ptrs, m, 0.02), rank);
  }
  std::vector<float> zero(m, 0.0f);
  std::vector<const float*> z = {zero.data(), zero.data()};
  EXPECT_EQ(NumericalRank(z, m, 0.02), 0);
}

}  // namespace
}  // namespace ltb::sample::sparse
