// Cubemap conventions: exact solid angles sum to 4π, directions round-trip through
// texels, the face table matches docs/CUBEMAP.md, and the angular radius bounds the texel.
#include "stages/common/cubemap.h"

#include <gtest/gtest.h>

#include <cmath>
#include <glm/geometric.hpp>
#include <random>

namespace ltb::cubemap {
namespace {

TEST(Cubemap, SolidAnglesSumToFourPi) {
  for (uint32_t r : {1u, 2u, 8u, 32u, 128u}) {
    double sum = 0;
    for (uint64_t c = 0; c < 6ull * r * r; ++c) sum += TexelSolidAngle(ColumnToTexel(c, r), r);
    EXPECT_NEAR(sum, 4 * M_PI, 1e-6) << "R=" << r;
  }
}

TEST(Cubemap, SolidAngleMatchesNumericalIntegration) {
  // dω = du dv / (1 + u² + v²)^(3/2) over a face region, midpoint rule on a fine grid.
  double u0 = -0.3, v0 = 0.1, u1 = 0.5, v1 = 0.9, sum = 0;
  int n = 2000;
  for (int i = 0; i < n; ++i)
    for (int j = 0; j < n; ++j) {
      double u = u0 + (i + 0.5) * (u1 - u0) / n, v = v0 + (j + 0.5) * (v1 - v0) / n;
      sum += std::pow(1 + u * u + v * v, -1.5);
    }
  sum *= (u1 - u0) * (v1 - v0) / (double(n) * n);
  EXPECT_NEAR(SolidAngle(u0, v0, u1, v1), sum, 1e-7);
}

TEST(Cubemap, EveryTexelRoundTrips) {
  for (uint32_t r : {1u, 4u, 32u}) {
    for (uint64_t c = 0; c < 6ull * r * r; ++c) {
      Texel x = ColumnToTexel(c, r);
      EXPECT_EQ(Column(x, r), c);
      glm::dvec3 d = TexelCenter(x, r);
      Texel y = DirectionToTexel(d, r);
      ASSERT_EQ(Column(y, r), c) << "R=" << r << " face " << x.face << " s " << x.s << " t " << x.t;
      EXPECT_NEAR(glm::length(d), 1.0, 1e-12);
    }
  }
}

TEST(Cubemap, RandomDirectionsRoundTripThroughFaceCoordinates) {
  std::mt19937 rng(4);
  std::normal_distribution<double> g;
  for (int i = 0; i < 100000; ++i) {
    glm::dvec3 d{g(rng), g(rng), g(rng)};
    int face;
    double u, v;
    DirectionToFace(d, &face, &u, &v);
    ASSERT_LE(std::fabs(u), 1.0);
    ASSERT_LE(std::fabs(v), 1.0);
    glm::dvec3 back = glm::normalize(FaceDirection(face, u, v));
    ASSERT_NEAR(glm::dot(back, glm::normalize(d)), 1.0, 1e-12);
  }
}

TEST(Cubemap, FaceAxesAsDocumented) {
  // Centre of each face points along its axis, in the order +X, -X, +Y, -Y, +Z, -Z.
  const glm::dvec3 axes[6] = {{1, 0, 0}, {-1, 0, 0}, {0, 1, 0}, {0, -1, 0}, {0, 0, 1}, {0, 0, -1}};
  for (int f = 0; f < 6; ++f) EXPECT_NEAR(glm::dot(glm::normalize(FaceDirection(f, 0, 0)), axes[f]), 1.0, 1e-15);
  // +Z face: s grows with +x, t grows with -y (t is the row, top to bottom).
  EXPECT_GT(FaceDirection(4, 0.5, 0).x, 0);
  EXPECT_LT(FaceDirection(4, 0, 0.5).y, 0);
}

TEST(Cubemap, AngularRadiusBoundsTheTexel) {
  std::mt19937 rng(9);
  std::uniform_real_distribution<double> u01(0, 1);
  uint32_t r = 4;
  for (uint64_t c = 0; c < 6ull * r * r; ++c) {
    Texel x = ColumnToTexel(c, r);
    double rho = TexelAngularRadius(x, r);
    glm::dvec3 centre = TexelCenter(x, r);
    for (int k = 0; k < 200; ++k) {
      double u = 2.0 * (x.s + u01(rng)) / r - 1.0, v = 2.0 * (x.t + u01(rng)) / r - 1.0;
      double ang = std::acos(std::min(1.0, glm::dot(centre, glm::normalize(FaceDirection(x.face, u, v)))));
      ASSERT_LE(ang, rho + 1e-12);
    }
  }
}

}  // namespace
}  // namespace ltb::cubemap
