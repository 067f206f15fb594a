// The Haar triple product (stages/triple/haar_triple.h) against closed forms and brute force:
// the tripling coefficient theorem against numerical integration of every triple of basis
// functions evaluated from their continuous definition (Ng et al. 2004, Eq. 17-18), the
// count of non-zero coefficients against the paper's Eq. 19, the forward transform against
// projections onto those basis functions, and the linear and sublinear algorithms against
// the pixel-basis integral.
#include "stages/triple/haar_triple.h"

#include <gtest/gtest.h>

#include <bit>
#include <cmath>
#include <random>
#include <vector>

namespace ltb::triple {
namespace {

// A basis function's value on each pixel of an R × R face, from Eq. 17-18 at the pixel
// centre (the functions are constant on pixels): independent of the transform's code.
std::vector<double> BasisImage(const HaarBasis& b, uint64_t res) {
  std::vector<double> img(res * res, 0.0);
  for (uint64_t y = 0; y < res; ++y) {
    for (uint64_t x = 0; x < res; ++x) {
      const double u = (x + 0.5) / res, v = (y + 0.5) / res;
      if (b.level < 0) {
        img[y * res + x] = 1.0;
        continue;
      }
      const double scale = std::ldexp(1.0, b.level);
      const double lu = scale * u - b.i, lv = scale * v - b.j;  // in the mother's unit square?
      if (lu < 0 || lu >= 1 || lv < 0 || lv >= 1) continue;
      const double sx = lu >= 0.5 ? 1 : -1, sy = lv >= 0.5 ? 1 : -1;
      const double mother = b.type == 0 ? sy : b.type == 1 ? sx : sx * sy;
      img[y * res + x] = scale * mother;
    }
  }
  return img;
}

std::vector<double> Random(uint64_t n, std::mt19937_64& rng, double lo = -1, double hi = 1) {
  std::uniform_real_distribution<double> d(lo, hi);
  std::vector<double> v(n);
  for (double& x : v) x = d(rng);
  return v;
}

TEST(HaarTriple, BasisIndicesRoundTrip) {
  for (uint64_t k = 0; k < 1024; ++k) EXPECT_EQ(IndexOf(BasisOf(k)), k) << k;
  EXPECT_EQ(BasisOf(0).level, -1);
  const HaarBasis b = BasisOf(1 + 3 * SquareIndex(2, 3, 1) + 2);
  EXPECT_EQ(b.level, 2);
  EXPECT_EQ(b.i, 3u);
  EXPECT_EQ(b.j, 1u);
  EXPECT_EQ(b.type, 2);
}

TEST(HaarTriple, ForwardIsTheProjectionOntoTheBasisAndInverts) {
  std::mt19937_64 rng(1);
  for (uint64_t res : {2u, 4u, 8u, 16u}) {
    const std::vector<double> f = Random(res * res, rng);
    const HaarFace h = HaarFace::Forward(f, res);
    for (uint64_t k = 0; k < res * res; ++k) {
      const std::vector<double> psi = BasisImage(BasisOf(k), res);
      double dot = 0;
      for (uint64_t p = 0; p < f.size(); ++p) dot += f[p] * psi[p];
      EXPECT_NEAR(h.c[k], dot / static_cast<double>(res * res), 1e-14) << "R " << res << " coefficient " << k;
    }
    const std::vector<double> back = h.Inverse();
    for (uint64_t p = 0; p < f.size(); ++p) EXPECT_NEAR(back[p], f[p], 1e-13) << p;
  }
}

// The theorem, for every triple of basis functions of R = 2, 4 and 8 (N³ = 262144 at
// R = 8): the brute-force integral equals TriplingCoefficient; and the non-zero ones number
// 2 − N + 3N·log4(N) (Eq. 19) counted as the paper's sum enumerates them: case 2 in all six
// orders, case 3 once per identical pair and third function (here: the pair in the last
// two places).
TEST(HaarTriple, TriplingCoefficientTheoremAgainstBruteForce) {
  for (uint64_t res : {2u, 4u, 8u}) {
    const uint64_t n = res * res;
    std::vector<std::vector<double>> img(n);
    std::vector<HaarBasis> basis(n);
    for (uint64_t k = 0; k < n; ++k) {
      basis[k] = BasisOf(k);
      img[k] = BasisImage(basis[k], res);
    }
    uint64_t nonzero = 0, wrong = 0;
    for (uint64_t a = 0; a < n; ++a) {
      for (uint64_t b = 0; b < n; ++b) {
        std::vector<double> ab(n);
        for (uint64_t p = 0; p < n; ++p) ab[p] = img[a][p] * img[b][p];
        for (uint64_t c = 0; c < n; ++c) {
          double sum = 0;
          for (uint64_t p = 0; p < n; ++p) sum += ab[p] * img[c][p];
          const double brute = sum / static_cast<double>(n);
          const double theorem = TriplingCoefficient(basis[a], basis[b], basis[c]);
          if (std::fabs(brute - theorem) > 1e-12) {
            if (++wrong <= 5)
              ADD_FAILURE() << "R " << res << ": C(" << a << "," << b << "," << c << ") = " << brute
                            << " by integration, " << theorem << " by the theorem";
          }
          const bool counted = b == c || (a != b && b != c && a != c);
          nonzero += theorem != 0 && counted;
        }
      }
    }
    EXPECT_EQ(wrong, 0u) << "R " << res;
    const double log4n = std::log2(static_cast<double>(n)) / 2;
    EXPECT_EQ(static_cast<double>(nonzero), 2 - static_cast<double>(n) + 3 * static_cast<double>(n) * log4n)
        << "R " << res << ": non-zero tripling coefficients (Eq. 19)";
  }
}

// A realistic face: lighting with a bright spot over a dim gradient, binary visibility (a
// disk of occluder), a Phong-like lobe for the BRDF.
struct Scene {
  std::vector<double> l, v, rho;
};
Scene RealFaces(uint64_t res) {
  Scene s;
  s.l.resize(res * res);
  s.v.resize(res * res);
  s.rho.resize(res * res);
  for (uint64_t y = 0; y < res; ++y) {
    for (uint64_t x = 0; x < res; ++x) {
      const double u = (x + 0.5) / res, w = (y + 0.5) / res;
      const double d2 = (u - 0.7) * (u - 0.7) + (w - 0.3) * (w - 0.3);
      s.l[y * res + x] = 0.2 + 0.3 * w + 50.0 * std::exp(-d2 / 0.002);
      s.v[y * res + x] = (u - 0.4) * (u - 0.4) + (w - 0.5) * (w - 0.5) < 0.06 ? 0.0 : 1.0;
      const double e2 = (u - 0.6) * (u - 0.6) + (w - 0.4) * (w - 0.4);
      s.rho[y * res + x] = 0.1 + 4.0 * std::pow(std::max(0.0, 1.0 - 4 * e2), 16.0);
    }
  }
  return s;
}

TEST(HaarTriple, LinearAlgorithmEqualsThePixelIntegral) {
  std::mt19937_64 rng(7);
  for (uint64_t res : {1u, 2u, 8u, 32u, 128u}) {
    for (int real = 0; real < 2; ++real) {
      Scene s =
          real ? RealFaces(res) : Scene{Random(res * res, rng), Random(res * res, rng, 0, 1), Random(res * res, rng)};
      const double pixel = PixelTripleProduct(s.l, s.v, s.rho);
      double magnitude = 0;  // Σ|L V ρ| / N: the scale of the rounding
      for (uint64_t p = 0; p < s.l.size(); ++p) magnitude += std::fabs(s.l[p] * s.v[p] * s.rho[p]);
      magnitude /= static_cast<double>(s.l.size());
      const double linear =
          LinearTripleProduct(HaarFace::Forward(s.l, res), HaarFace::Forward(s.v, res), HaarFace::Forward(s.rho, res));
      EXPECT_NEAR(linear, pixel, 1e-12 * std::max(magnitude, 1e-300)) << "R " << res << (real ? " real" : " random");
    }
  }
}

TEST(HaarTriple, SublinearConvergesToTheLinearResult) {
  const uint64_t res = 64, n = res * res;
  const Scene s = RealFaces(res);
  const HaarFace l = HaarFace::Forward(s.l, res), v = HaarFace::Forward(s.v, res), rho = HaarFace::Forward(s.rho, res);
  const double exact = LinearTripleProduct(l, v, rho);
  // Every term: the linear result.
  std::vector<uint32_t> all(n);
  for (uint32_t k = 0; k < n; ++k) all[k] = k;
  EXPECT_NEAR(SublinearTripleProduct(l, v, rho, all, all), exact, 1e-12 * std::fabs(exact));
  // Terms 1, 4, 16, ... of L and ρ. The error is not monotone term by term on this scene
  // (measured: 64 terms 2.5e-4, 256 terms 2.8e-3); what holds: it falls by orders of
  // magnitude from 1 to 1024 terms, is below 1% from N/64 terms on, and ends at zero.
  std::vector<double> err;
  for (uint64_t terms = 1; terms <= n; terms *= 4) {
    err.push_back(
        std::fabs(SublinearTripleProduct(l, v, rho, LargestTerms(l, terms), LargestTerms(rho, terms)) - exact) /
        std::fabs(exact));
    std::printf("sublinear, %5llu terms of %llu: relative error %.3e\n", static_cast<unsigned long long>(terms),
                static_cast<unsigned long long>(n), err.back());
  }
  ASSERT_EQ(err.size(), 7u);         // 1, 4, ..., 4096 terms
  EXPECT_GT(err[0], 0.1);            // one term: the scaling products only
  EXPECT_LT(err[3], 1e-2);           // 64 terms (N/64)
  EXPECT_LT(err[4], 1e-2);           // 256
  EXPECT_LT(err[5], 1e-4 * err[0]);  // 1024
  EXPECT_LT(err[6], 1e-12);          // every term: exact
}

// The parent sum of a square by walking its ancestors equals the dynamic programme's; at the
// pixel level it is the pixel's value (Inverse).
TEST(HaarTriple, ParentSumAtMatchesParentSumsAndPixels) {
  std::mt19937_64 rng(11);
  for (uint64_t res : {1, 2, 8, 32}) {
    const int levels = std::countr_zero(res);
    const HaarFace f = HaarFace::Forward(Random(res * res, rng), res);
    std::vector<double> dp;
    ParentSums(f.c.data(), levels, &dp);
    for (int l = 0; l < levels; ++l) {
      for (uint64_t j = 0; j < (uint64_t{1} << l); ++j) {
        for (uint64_t i = 0; i < (uint64_t{1} << l); ++i) {
          EXPECT_NEAR(ParentSumAt(f.c.data(), l, i, j), dp[SquareIndex(l, i, j)], 1e-12)
              << "R " << res << " square " << l << "," << i << "," << j;
        }
      }
    }
    const std::vector<double> px = f.Inverse();
    for (uint64_t y = 0; y < res; ++y)
      for (uint64_t x = 0; x < res; ++x) EXPECT_NEAR(ParentSumAt(f.c.data(), levels, x, y), px[y * res + x], 1e-12);
  }
}

// Cube rows Haar-transformed in place face by face: each face as HaarFace::Forward.
TEST(HaarTriple, HaarRowsInPlaceTransformsEachFace) {
  std::mt19937_64 rng(12);
  const uint64_t res = 8, face = res * res, cols = 6 * face;
  const std::vector<double> values = Random(2 * cols, rng);
  std::vector<float> rows(values.begin(), values.end());
  HaarRowsInPlace(rows.data(), 2, res);
  for (uint64_t r = 0; r < 2; ++r) {
    for (uint64_t f = 0; f < 6; ++f) {
      std::vector<double> px(face);
      for (uint64_t k = 0; k < face; ++k) px[k] = static_cast<float>(values[r * cols + f * face + k]);
      const HaarFace h = HaarFace::Forward(px, res);
      for (uint64_t k = 0; k < face; ++k) EXPECT_EQ(rows[r * cols + f * face + k], static_cast<float>(h.c[k]));
    }
  }
}

}  // namespace
}  // namespace ltb::triple
