// The BRDF in-out factorisation's pieces (stages/brdf/brdf_factor.h) and the base64 of its
// view tables (stages/common/base64.h), against closed forms: RFC 4648's test vectors, an
// orthonormal frame, the hemisphere's solid angle 2π, a Lambertian BRDF's exact rank one,
// and the reported errors against the residual measured on the grid the SVD used.
#include "stages/brdf/brdf_factor.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <glm/geometric.hpp>
#include <random>

#include "stages/common/base64.h"

namespace ltb::brdf {
namespace {

TEST(Base64, Rfc4648Vectors) {
  const std::pair<const char*, const char*> cases[] = {{"", ""},
                                                       {"f", "Zg=="},
                                                       {"fo", "Zm8="},
                                                       {"foo", "Zm9v"},
                                                       {"foob", "Zm9vYg=="},
                                                       {"fooba", "Zm9vYmE="},
                                                       {"foobar", "Zm9vYmFy"}};
  for (const auto& [plain, coded] : cases) {
    EXPECT_EQ(stages::Base64Encode(plain, std::strlen(plain)), coded);
    auto back = stages::Base64Decode(coded);
    ASSERT_TRUE(back.ok()) << coded;
    EXPECT_EQ(std::string(back->begin(), back->end()), plain);
  }
  for (const char* bad : {"Zg=", "Z===", "Zm9v!A==", "Zg==Zg==", "=Zg="}) {
    EXPECT_FALSE(stages::Base64Decode(bad).ok()) << bad;
  }
  const std::vector<float> v = {0.0f, -1.5f, 3.25e-20f, 1e30f};
  auto w = stages::FloatsFromBase64(stages::FloatsToBase64(v));
  ASSERT_TRUE(w.ok());
  EXPECT_EQ(*w, v);
}

TEST(BrdfFactor, TangentFrameIsOrthonormalAndRightHanded) {
  std::mt19937_64 rng(7);
  std::normal_distribution<double> g;
  std::vector<glm::dvec3> normals = {{0, 0, 1}, {0, 0, -1}, {1, 0, 0}, {0, -1, 0}};
  for (int i = 0; i < 200; ++i) normals.push_back(glm::normalize(glm::dvec3(g(rng), g(rng), g(rng))));
  for (const glm::dvec3& n : normals) {
    glm::dvec3 t, b;
    TangentFrame(n, &t, &b);
    EXPECT_NEAR(glm::length(t), 1.0, 1e-12);
    EXPECT_NEAR(glm::length(b), 1.0, 1e-12);
    EXPECT_NEAR(glm::dot(t, b), 0.0, 1e-12);
    EXPECT_NEAR(glm::dot(t, n), 0.0, 1e-12);
    EXPECT_NEAR(glm::dot(glm::cross(t, b), n), 1.0, 1e-12);
  }
}

TEST(BrdfFactor, ParabolicCellsCoverTheHemisphere) {
  for (uint32_t res : {16u, 64u, 256u}) {
    double total = 0;
    for (uint32_t j = 0; j < res; ++j)
      for (uint32_t i = 0; i < res; ++i) {
        double a = 0;
        const glm::dvec3 d = ParabolicTable::Direction(res, i, j, &a);
        EXPECT_NEAR(glm::length(d), 1.0, 1e-12);
        EXPECT_GE(d.z, -1e-15);
        total += a;
      }
    // Midpoint rule on the disk's cells: the boundary cells cut off make it converge as 1/res.
    EXPECT_NEAR(total, 2 * M_PI, 2 * M_PI * 4.0 / res) << res;
  }
  // A table of z reads back z exactly at the cell centres and to within the bilinear error between.
  const uint32_t res = 32;
  ParabolicTable t{res, std::vector<float>(res * res)};
  for (uint32_t j = 0; j < res; ++j)
    for (uint32_t i = 0; i < res; ++i) {
      double a = 0;
      t.value[j * res + i] = static_cast<float>(ParabolicTable::Direction(res, i, j, &a).z);
    }
  double a = 0;
  const glm::dvec3 centre = ParabolicTable::Direction(res, 20, 13, &a);
  EXPECT_NEAR(t.Lookup(centre), centre.z, 1e-6);
  EXPECT_NEAR(t.Lookup({0.3, -0.2, 0.9}), glm::normalize(glm::dvec3(0.3, -0.2, 0.9)).z, 0.01);
}

TEST(BrdfFactor, LambertianIsExactlyRankOne) {
  auto f = FactorPhong(0.6, 0.0, 20.0, 4, 24, 12);
  ASSERT_TRUE(f.ok());
  for (double e : f->error) EXPECT_EQ(e, 0.0);
  EXPECT_EQ(f->f.size(), 4u);
  for (const glm::dvec3& w : {glm::dvec3(0.1, 0.2, 0.9), glm::dvec3(-0.7, 0.1, 0.2)}) {
    const glm::dvec3 u = glm::normalize(w);
    EXPECT_NEAR(f->Eval(u, {0, 0, 1}), 0.6 / M_PI * u.z, 1e-6);
  }
}

TEST(BrdfFactor, ReportedErrorIsTheGridResidual) {
  const uint32_t ri = 24, rv = 12, terms = 6;
  auto f = FactorPhong(0.3, 0.5, 8.0, terms, ri, rv);
  ASSERT_TRUE(f.ok());
  ASSERT_EQ(f->error.size(), 8u);
  for (size_t k = 1; k < f->error.size(); ++k) EXPECT_LE(f->error[k], f->error[k - 1] + 1e-12);
  // The residual of the K = terms approximation over the same cells and weights.
  double num = 0, den = 0;
  for (uint32_t j = 0; j < rv * rv; ++j) {
    double av = 0;
    const glm::dvec3 o = ParabolicTable::Direction(rv, j % rv, j / rv, &av);
    if (av == 0) continue;
    for (uint32_t i = 0; i < ri * ri; ++i) {
      double ai = 0;
      const glm::dvec3 w = ParabolicTable::Direction(ri, i % ri, i / ri, &ai);
      if (ai == 0) continue;
      const double exact = PhongCos(0.3, 0.5, 8.0, w, o);
      const double approx = f->Eval(w, o);
      num += ai * av * (exact - approx) * (exact - approx);
      den += ai * av * exact * exact;
    }
  }
  // At the cell centres the tables hold exact values (float-rounded): the residual is the SVD's.
  EXPECT_NEAR(std::sqrt(num / den), f->error[terms - 1], 2e-4);
}

}  // namespace
}  // namespace ltb::brdf
