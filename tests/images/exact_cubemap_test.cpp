// Exact texel averages of cube-face and angular maps (stages/images/exact_cubemap.h) against
// oracles of the test's own: closed-form rectangle overlaps for a cross at rotation 0, and a
// quadtree over each bright pixel with a rigorous bound of what it cannot place at any rotation.
#include "stages/images/exact_cubemap.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <functional>
#include <glm/geometric.hpp>
#include <numbers>
#include <random>
#include <vector>

#include "stages/common/cubemap.h"
#include "stages/images/envmap.h"
#include "stages/images/resampler.h"

namespace exact_cubemap_test {
namespace {

using ltb::stages::CubemapResampler;
using ltb::stages::EnvLayout;
using ltb::stages::EnvMap;
using ltb::stages::ExactCubemap;
namespace cubemap = ltb::cubemap;
constexpr double kPi = std::numbers::pi;

// A horizontal cross (4F × 3F: +Y / −X +Z +X −Z / −Y, docs/ENVMAPS.md) from per-face pixels.
EnvMap Cross(uint64_t F, const std::function<float(int f, uint64_t s, uint64_t t, int c)>& value) {
  static const int kCol[6] = {2, 0, 1, 1, 1, 3}, kRow[6] = {1, 1, 0, 2, 1, 1};
  EnvMap env;
  env.layout = EnvLayout::kHCross;
  env.width = 4 * F;
  env.height = 3 * F;
  env.path = "cross";
  env.rgb.assign(env.width * env.height * 3, 0.0f);
  for (int f = 0; f < 6; ++f)
    for (uint64_t t = 0; t < F; ++t)
      for (uint64_t s = 0; s < F; ++s)
        for (int c = 0; c < 3; ++c) {
          env.rgb[((kRow[f] * F + t) * env.width + kCol[f] * F + s) * 3 + c] = value(f, s, t, c);
        }
  return env;
}

// The documented angular projection (docs/ENVMAPS.md): (u, v) at angle π·r from the centre
// direction +X, towards u·right + v·up with right = −Y, up = +Z; density π·sin(πr)/r.
glm::dvec3 Angular(double u, double v) {
  const double r = std::sqrt(u * u + v * v);
  glm::dvec3 d(std::cos(kPi * r), 0, 0);
  if (r > 0) d += std::sin(kPi * r) / r * glm::dvec3(0, -u, v);
  return d;
}
double AngularArea(double u0, double u1, double v0, double v1) {  // 4 × 4 Gauss–Legendre
  static const double x[4] = {-0.8611363115940526, -0.3399810435848563, 0.3399810435848563, 0.8611363115940526};
  static const double w[4] = {0.3478548451374538, 0.6521451548625461, 0.6521451548625461, 0.3478548451374538};
  double s = 0;
  for (int i = 0; i < 4; ++i)
    for (int j = 0; j < 4; ++j) {
      const double u = 0.5 * (u0 + u1) + 0.5 * (u1 - u0) * x[i], v = 0.5 * (v0 + v1) + 0.5 * (v1 - v0) * x[j];
      const double r = std::sqrt(u * u + v * v);
      s += w[i] * w[j] * (r > 0 ? kPi * std::sin(kPi * r) / r : kPi * kPi);
    }
  return s * 0.25 * (u1 - u0) * (v1 - v0);
}

glm::dvec3 Rz(double a, const glm::dvec3& d) {
  return {std::cos(a) * d.x - std::sin(a) * d.y, std::sin(a) * d.x + std::cos(a) * d.y, d.z};
}

// A bright pixel as a parameter square [0, 1]²: its direction at (a, b) (rotated) and the
// solid angle of a sub-rectangle.
struct Pixel {
  std::function<glm::dvec3(double a, double b)> dir;
  std::function<double(double a0, double a1, double b0, double b1)> area;
};

// Quadtree over a pixel: a cell whose corners and centre lie in one texel goes to it whole;
// others split, to 1/2^depth of the pixel's side; what is left goes to the centre's texel,
// and its area to `slack` of every texel its corners touch (what the oracle cannot place).
void Place(const Pixel& p, uint32_t R, double a0, double a1, double b0, double b1, int depth,
           std::vector<double>* placed, std::vector<double>* slack) {
  const glm::dvec3 pts[5] = {p.dir(a0, b0), p.dir(a1, b0), p.dir(a0, b1), p.dir(a1, b1),
                             p.dir(0.5 * (a0 + a1), 0.5 * (b0 + b1))};
  uint64_t col[5];
  for (int i = 0; i < 5; ++i) col[i] = cubemap::Column(cubemap::DirectionToTexel(pts[i], R), R);
  const bool one = std::all_of(col, col + 5, [&](uint64_t c) { return c == col[0]; });
  if (one || depth == 0) {
    const double w = p.area(a0, a1, b0, b1);
    (*placed)[col[4]] += w;
    if (!one) {
      for (int i = 0; i < 5; ++i) {
        if (std::find(col, col + i, col[i]) == col + i) (*slack)[col[i]] += w;
      }
    }
    return;
  }
  const double am = 0.5 * (a0 + a1), bm = 0.5 * (b0 + b1);
  Place(p, R, a0, am, b0, bm, depth - 1, placed, slack);
  Place(p, R, am, a1, b0, bm, depth - 1, placed, slack);
  Place(p, R, a0, am, bm, b1, depth - 1, placed, slack);
  Place(p, R, am, a1, bm, b1, depth - 1, placed, slack);
}

// Texel averages of a map of constant radiance 1 with bright pixels of radiance B:
// 1 + (B − 1)·Ω(bright ∩ texel)/Ω_texel, and the bound of that value's error.
struct Oracle {
  std::vector<double> value, bound;
};
Oracle BrightOracle(const std::vector<Pixel>& bright, double B, uint32_t R) {
  const uint64_t texels = uint64_t(6) * R * R;
  std::vector<double> placed(texels, 0.0), slack(texels, 0.0);
  for (const Pixel& p : bright) {
    constexpr int kStart = 16;  // cells small enough that a curved edge's bulge is negligible
    for (int j = 0; j < kStart; ++j)
      for (int i = 0; i < kStart; ++i) {
        Place(p, R, double(i) / kStart, double(i + 1) / kStart, double(j) / kStart, double(j + 1) / kStart, 8, &placed,
              &slack);
      }
  }
  Oracle o{std::vector<double>(texels), std::vector<double>(texels)};
  for (uint64_t t = 0; t < texels; ++t) {
    const double omega = cubemap::TexelSolidAngle(cubemap::ColumnToTexel(t, R), R);
    o.value[t] = 1.0 + (B - 1.0) * placed[t] / omega;
    o.bound[t] = (B - 1.0) * slack[t] / omega;
  }
  return o;
}

// Pixels whose corners fall in different texels (at `rotation`), `count` of them at random.
template <typename CornerDir>
std::vector<std::pair<uint64_t, uint64_t>> Straddling(uint64_t nx, uint64_t ny, uint32_t R, CornerDir corner,
                                                      size_t count, uint32_t seed) {
  std::vector<std::pair<uint64_t, uint64_t>> all;
  for (uint64_t y = 0; y < ny; ++y)
    for (uint64_t x = 0; x < nx; ++x) {
      glm::dvec3 d[4];
      bool ok = true;
      for (int k = 0; k < 4 && ok; ++k) ok = corner(x, y, k % 2, k / 2, &d[k]);
      if (!ok) continue;
      const uint64_t c0 = cubemap::Column(cubemap::DirectionToTexel(d[0], R), R);
      for (int k = 1; k < 4; ++k) {
        if (cubemap::Column(cubemap::DirectionToTexel(d[k], R), R) != c0) {
          all.emplace_back(x, y);
          break;
        }
      }
    }
  std::mt19937 rng(seed);
  std::shuffle(all.begin(), all.end(), rng);
  all.resize(std::min(all.size(), count));
  return all;
}

struct Worst {
  double excess = 0;  // largest |got − oracle| − bound, relative to the oracle
  double rel = 0;     // largest |got − oracle| / oracle
  double bound = 0;   // largest bound / oracle
};
Worst Compare(const std::vector<float>& got, const Oracle& o) {
  Worst w{-1e300, 0};
  for (size_t t = 0; t < o.value.size(); ++t)
    for (int c = 0; c < 3; ++c) {
      const double err = std::fabs(double(got[t * 3 + c]) - o.value[t]);
      w.excess = std::max(w.excess, (err - o.bound[t]) / o.value[t]);
      w.rel = std::max(w.rel, err / o.value[t]);
      w.bound = std::max(w.bound, o.bound[t] / o.value[t]);
    }
  return w;
}

std::vector<float> Exact(const EnvMap& env, uint32_t R, double rotation) {
  auto cube = ExactCubemap(env, R, rotation);
  EXPECT_TRUE(cube.ok()) << cube.status().ToString();
  return cube.ok() ? *cube : std::vector<float>(size_t(6) * R * R * 3, 0.0f);
}
std::vector<float> ThroughTheWorkingGrid(const EnvMap& env, uint32_t R, double rotation) {
  auto rs = CubemapResampler::Create(env, R);
  EXPECT_TRUE(rs.ok()) << rs.status().ToString();
  std::vector<float> out(size_t(6) * R * R * 3);
  rs->Resample(rotation, out.data());
  return out;
}

TEST(ExactCubemap, CrossAtRotationZeroIsTheRectangleOverlaps) {
  // At rotation 0 a source pixel and a texel of the same face overlap in a rectangle of face
  // coordinates, of closed-form solid angle (cubemap::SolidAngle): every texel against that.
  // F = 60 is no multiple of R = 8: pixels straddle texel edges. A random background and
  // six pixels 10^3 brighter.
  const uint64_t F = 60;
  const uint32_t R = 8;
  std::mt19937 rng(41);
  std::uniform_real_distribution<float> dist(0.5f, 1.5f);
  std::vector<float> px(6 * F * F * 3);
  for (float& v : px) v = dist(rng);
  for (int i = 0; i < 6; ++i) {
    const uint64_t s = 7 + 15 * (i % 4), t = 7 + 22 * (i % 3);  // s, t ≡ 7 (mod 7.5): on an edge
    for (int c = 0; c < 3; ++c) px[((i * F + t) * F + s) * 3 + c] = 1000.0f;
  }
  const EnvMap env = Cross(F, [&](int f, uint64_t s, uint64_t t, int c) { return px[((f * F + t) * F + s) * 3 + c]; });
  const std::vector<float> got = Exact(env, R, 0.0), grid = ThroughTheWorkingGrid(env, R, 0.0);
  double worst = 0, worst_grid = 0;
  for (int f = 0; f < 6; ++f)
    for (uint32_t t = 0; t < R; ++t)
      for (uint32_t s = 0; s < R; ++s) {
        const double x0 = 2.0 * s / R - 1, x1 = 2.0 * (s + 1) / R - 1, y0 = 2.0 * t / R - 1, y1 = 2.0 * (t + 1) / R - 1;
        double sum[3] = {0, 0, 0}, omega = 0;
        for (uint64_t q = 0; q < F; ++q)
          for (uint64_t p = 0; p < F; ++p) {
            const double a0 = std::max(x0, 2.0 * p / F - 1), a1 = std::min(x1, 2.0 * (p + 1) / F - 1);
            const double b0 = std::max(y0, 2.0 * q / F - 1), b1 = std::min(y1, 2.0 * (q + 1) / F - 1);
            if (a1 <= a0 || b1 <= b0) continue;
            const double w = cubemap::SolidAngle(a0, b0, a1, b1);
            for (int c = 0; c < 3; ++c) sum[c] += px[((f * F + q) * F + p) * 3 + c] * w;
            omega += w;
          }
        const size_t texel = cubemap::Column({f, s, t}, R);
        for (int c = 0; c < 3; ++c) {
          const double want = sum[c] / omega;
          worst = std::max(worst, std::fabs(got[texel * 3 + c] - want) / want);
          worst_grid = std::max(worst_grid, std::fabs(grid[texel * 3 + c] - want) / want);
        }
      }
  std::printf("[ exact ] cross F=60, R=8, rotation 0: worst texel %.2g exact, %.2g through the working grid\n", worst,
              worst_grid);
  EXPECT_LT(worst, 2e-6);  // float32 output and the power factor's rounding

  // A cross whose faces have R × R texels is itself (the working grid blurred it by 9.8% rms).
  const EnvMap same = Cross(R, [&](int f, uint64_t s, uint64_t t, int c) { return px[((f * F + t) * F + s) * 3 + c]; });
  const std::vector<float> back = Exact(same, R, 0.0);
  for (int f = 0; f < 6; ++f)
    for (uint32_t t = 0; t < R; ++t)
      for (uint32_t s = 0; s < R; ++s)
        for (int c = 0; c < 3; ++c) {
          const float want = px[((f * F + t) * F + s) * 3 + c];
          EXPECT_NEAR(back[cubemap::Column({f, s, t}, R) * 3 + c], want, 2e-6 * want) << f << " " << s << " " << t;
        }
}

TEST(ExactCubemap, PeakyCrossAndAngularMapsAtAnyRotationMatchAQuadtreeOracle) {
  // Radiance 1 everywhere but six pixels at 10^3 that straddle texel edges at that rotation:
  // each texel against BrightOracle, within the oracle's own bound plus float rounding.
  const uint32_t R = 8;
  const double B = 1000;
  const uint64_t F = 60, W = 200;
  for (double rotation : {0.0, 0.37}) {
    {                                                                             // the cross
      auto corner = [&](uint64_t x, uint64_t y, int dx, int dy, glm::dvec3* d) {  // x: the six faces side by side
        const int f = int(x / F);
        const double s = double(x % F + dx), t = double(y + dy);
        *d = Rz(rotation, glm::normalize(cubemap::FaceDirection(f, 2.0 * s / F - 1, 2.0 * t / F - 1)));
        return true;
      };
      const auto picked = Straddling(6 * F, F, R, corner, 6, 5);
      ASSERT_EQ(picked.size(), 6u);
      std::vector<Pixel> bright;
      std::vector<bool> hot(6 * F * F, false);
      for (auto [x, y] : picked) {
        const int f = int(x / F);
        const uint64_t s = x % F, t = y;
        hot[(f * F + t) * F + s] = true;
        auto u = [=](double a) { return 2.0 * (double(s) + a) / F - 1; };
        auto v = [=](double b) { return 2.0 * (double(t) + b) / F - 1; };
        bright.push_back({[=](double a, double b) { return Rz(rotation, cubemap::FaceDirection(f, u(a), v(b))); },
                          [=](double a0, double a1, double b0, double b1) {
                            return cubemap::SolidAngle(u(a0), v(b0), u(a1), v(b1));
                          }});
      }
      const EnvMap env =
          Cross(F, [&](int f, uint64_t s, uint64_t t, int) { return hot[(f * F + t) * F + s] ? float(B) : 1.0f; });
      const Oracle o = BrightOracle(bright, B, R);
      const Worst exact = Compare(Exact(env, R, rotation), o),
                  grid = Compare(ThroughTheWorkingGrid(env, R, rotation), o);
      std::printf(
          "[ exact ] peaky cross F=60, R=8, rotation %.2f: worst texel %.2g exact, %.2g through the working grid\n",
          rotation, exact.rel, grid.rel);
      EXPECT_LT(exact.excess, 1e-6) << "cross, rotation " << rotation;
      EXPECT_LT(exact.rel, 2e-6) << "cross, rotation " << rotation;  // exact geometry: float rounding
    }
    {  // the angular map
      const double h = 2.0 / W;
      auto corner = [&](uint64_t x, uint64_t y, int dx, int dy, glm::dvec3* d) {
        const double u = -1 + h * double(x + dx), v = 1 - h * double(y + dy);
        *d = Rz(rotation, Angular(u, v));
        return u * u + v * v < 0.8;  // away from the rim
      };
      const auto picked = Straddling(W, W, R, corner, 6, 9);
      ASSERT_EQ(picked.size(), 6u);
      std::vector<Pixel> bright;
      EnvMap env;
      env.layout = EnvLayout::kAngular;
      env.width = env.height = W;
      env.path = "angular";
      env.rgb.assign(W * W * 3, 1.0f);
      for (const auto& xy : picked) {
        const uint64_t x = xy.first, y = xy.second;  // (a lambda cannot capture a structured binding in clang 14)
        for (int c = 0; c < 3; ++c) env.rgb[(y * W + x) * 3 + c] = float(B);
        auto u = [=](double a) { return -1 + h * (double(x) + a); };
        auto v = [=](double b) { return 1 - h * (double(y) + b); };
        bright.push_back(
            {[=](double a, double b) { return Rz(rotation, Angular(u(a), v(b))); },
             [=](double a0, double a1, double b0, double b1) { return AngularArea(u(a0), u(a1), v(b1), v(b0)); }});
      }
      const Oracle o = BrightOracle(bright, B, R);
      const Worst exact = Compare(Exact(env, R, rotation), o),
                  grid = Compare(ThroughTheWorkingGrid(env, R, rotation), o);
      std::printf(
          "[ exact ] peaky angular 200², R=8, rotation %.2f: worst texel %.2g exact, %.2g through the working "
          "grid (oracle bound %.2g)\n",
          rotation, exact.rel, grid.rel, exact.bound);
      EXPECT_LT(exact.excess, 1e-6) << "angular, rotation " << rotation;
      // The oracle places far better than its bound (4e-7 on the cross, same quadtree): what
      // is left here is the parts' bowed sides, 7e-4 with 4 × 4 parts, 1.4e-4 with the 9 × 9
      // the rule picks for R = 8, W = 200 (docs/ENVMAPS.md).
      EXPECT_LT(exact.rel, 3e-4) << "angular, rotation " << rotation;
    }
  }
}

}  // namespace
}  // namespace exact_cubemap_test
