// The material field of the triple product (stages/triple/material.h) against closed forms:
// a convex vertex (V = 1) under a constant environment reflects exactly its albedo (Lambert:
// ∫ max(0, n·ω)/π dω = 1) or ks (normalised Phong lobe: ∫ max(0, r·ω)^s dω = 2π/(s + 1)); the
// cube's Haar triple product against the direct texel sum Σ L V ρ Δω.
#include "stages/triple/material.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <numbers>
#include <random>
#include <vector>

#include "format/io/container_reader.h"
#include "stages/common/cubemap.h"

namespace ltb::triple {
namespace {

double ConstantMapResponse(const Brdf& brdf, const glm::dvec3& dir, uint64_t res) {
  std::vector<double> ones(6 * res * res, 1.0);
  const CubeFaces one = CubeFunctionFaces(ones.data(), res);
  return CubeTripleProduct(one, one, MaterialFaces(brdf, dir, res));
}

TEST(TripleMaterial, ParsesBrdfs) {
  auto l = ParseBrdf("lambert");
  ASSERT_TRUE(l.ok());
  EXPECT_EQ(l->kind, Brdf::Kind::kLambert);
  EXPECT_EQ(l->albedo, 1.0);
  auto p = ParseBrdf("phong:64:0.5");
  ASSERT_TRUE(p.ok());
  EXPECT_EQ(p->kind, Brdf::Kind::kPhong);
  EXPECT_EQ(p->exponent, 64.0);
  EXPECT_EQ(p->albedo, 0.5);
  auto ct = ParseBrdf("cook-torrance:0.3,0.04:0.7");
  ASSERT_TRUE(ct.ok()) << ct.status().ToString();
  EXPECT_EQ(ct->kind, Brdf::Kind::kCookTorrance);
  EXPECT_EQ(ct->roughness, 0.3);
  EXPECT_EQ(ct->f0, 0.04);
  EXPECT_EQ(ct->albedo, 0.7);
  EXPECT_TRUE(ct->TwoDirections());
  EXPECT_EQ(BrdfSpec(*ct), "cook-torrance:0.3,0.04");
  auto w = ParseBrdf("ward:0.2,0.2");
  ASSERT_TRUE(w.ok());
  EXPECT_EQ(w->kind, Brdf::Kind::kWard);
  EXPECT_TRUE(w->SameLobe(*ParseBrdf("ward:0.2:0.5")));
  EXPECT_FALSE(w->SameLobe(*ParseBrdf("ward:0.3")));
  EXPECT_EQ(ParseBrdf("blinn:40")->kind, Brdf::Kind::kBlinn);
  for (const char* bad : {"phong", "phong:x", "phong:-1", "ward:1,2", "lambert:1:2", "", "phong:1e999", "ward:0",
                          "cook-torrance:0.3", "cook-torrance:0.3,2", "blinn", "oren-nayar:1"}) {
    EXPECT_FALSE(ParseBrdf(bad).ok()) << bad;
  }
  EXPECT_NE(ParseBrdf("ward:0.1,0.3").status().message().find("anisotropic"), std::string::npos);
}

// The two-direction BRDFs are reciprocal: with ρ̃ = f(ω, ω_o)·(n·ω) and ω_o recovered from
// the reflection vector, f(ω, ω_o) = f(ω_o, ω) for every pair above the horizon.
TEST(TripleMaterial, GlossyLobesAreReciprocal) {
  std::mt19937_64 rng(7);
  std::normal_distribution<double> g;
  auto unit = [&] { return glm::normalize(glm::dvec3(g(rng), g(rng), g(rng))); };
  auto reflect = [](const glm::dvec3& n, const glm::dvec3& d) { return 2 * glm::dot(n, d) * n - d; };
  for (const char* spec : {"blinn:30", "ward:0.25", "cook-torrance:0.3,0.1"}) {
    const Brdf b = *ParseBrdf(spec);
    int tested = 0;
    while (tested < 200) {
      const glm::dvec3 n = unit(), wi = unit(), wo = unit();
      if (glm::dot(n, wi) < 0.05 || glm::dot(n, wo) < 0.05) continue;
      const double f_io = BrdfValue(b, n, reflect(n, wo), wi) / glm::dot(n, wi);
      const double f_oi = BrdfValue(b, n, reflect(n, wi), wo) / glm::dot(n, wo);
      EXPECT_NEAR(f_io, f_oi, 1e-9 * std::max(1.0, f_io)) << spec;
      EXPECT_GE(f_io, 0.0) << spec;
      ++tested;
    }
    // Below the horizon, in either direction, nothing.
    const glm::dvec3 n(0, 0, 1);
    EXPECT_EQ(BrdfValue(b, n, reflect(n, glm::normalize(glm::dvec3(1, 0, 1))), glm::normalize(glm::dvec3(0, 1, -1))),
              0.0);
    EXPECT_EQ(BrdfValue(b, n, glm::normalize(glm::dvec3(1, 0, -1)), glm::normalize(glm::dvec3(0, 1, 1))), 0.0);
  }
}

// The texel-centre (midpoint) rule with exact solid angles is second order where the
// integrand is smooth within every texel, as it is for an axis-aligned normal or reflection
// vector (the horizon runs along texel edges): the error falls at least 3× per doubling of R
// (4× asymptotically) and is below 1e-3 at R = 64.
TEST(TripleMaterial, ConvexVertexUnderAConstantMapReflectsItsAlbedo) {
  const glm::dvec3 up(0, 0, 1);
  for (const Brdf& brdf : {Brdf{Brdf::Kind::kLambert, 0, 0.7}, Brdf{Brdf::Kind::kPhong, 16, 0.4}}) {
    double previous = INFINITY;
    for (uint64_t res : {8u, 16u, 32u, 64u}) {
      const double e = std::fabs(ConstantMapResponse(brdf, up, res) - brdf.albedo) / brdf.albedo;
      std::printf("%s, R %3llu: relative error %.3e\n", brdf.kind == Brdf::Kind::kLambert ? "lambert" : "phong:16",
                  static_cast<unsigned long long>(res), e);
      EXPECT_LT(e, previous / 3) << "R " << res;
      previous = e;
    }
    EXPECT_LT(previous, 1e-3);
  }
  // An oblique normal: the horizon cuts texels (first order there), still close at R = 64.
  const glm::dvec3 n = glm::normalize(glm::dvec3(1, 2, 3));
  const double e = std::fabs(ConstantMapResponse(Brdf{Brdf::Kind::kLambert, 0, 1}, n, 64) - 1.0);
  std::printf("lambert, oblique normal, R 64: relative error %.3e\n", e);
  EXPECT_LT(e, 5e-3);
}

// The cube's Haar triple product equals the direct sum over texels of L·V·ρ̃·Δω (ρ̃ from its
// formula, Δω the exact texel solid angle), for random lighting and a half-space visibility.
TEST(TripleMaterial, CubeTripleProductEqualsTheTexelSum) {
  const uint64_t res = 16;
  const uint32_t r = static_cast<uint32_t>(res);
  std::mt19937_64 rng(5);
  std::uniform_real_distribution<double> d(0.0, 3.0);
  std::vector<double> light(6 * res * res), vis(6 * res * res);
  const glm::dvec3 a = glm::normalize(glm::dvec3(-1, 0.5, 0.2)), rdir = glm::normalize(glm::dvec3(0.3, -0.4, 1));
  const Brdf phong{Brdf::Kind::kPhong, 8, 0.9};
  double direct = 0;
  for (uint64_t col = 0; col < light.size(); ++col) {
    const cubemap::Texel x = cubemap::ColumnToTexel(col, r);
    const glm::dvec3 w = cubemap::TexelCenter(x, r);
    light[col] = d(rng);
    vis[col] = glm::dot(w, a) > 0 ? 1.0 : 0.0;
    const double c = std::max(0.0, glm::dot(w, rdir));
    const double rho = c > 0 ? 0.9 * 9 / (2 * std::numbers::pi) * std::pow(c, 8.0) : 0.0;
    direct += light[col] * vis[col] * rho * cubemap::TexelSolidAngle(x, r);
  }
  const double haar = CubeTripleProduct(CubeFunctionFaces(light.data(), res), CubeFunctionFaces(vis.data(), res),
                                        MaterialFaces(phong, rdir, res));
  EXPECT_NEAR(haar, direct, 1e-12 * direct);
}

// The material field file: one row per sampled direction (texel centres of the samples
// cube), holding that direction's Haar coefficients with exactly the smallest ones zeroed
// (the kept ones at least `energy` of Σc², dropping the smallest kept one would fall below),
// stored sparse; a rerun with the same parameters finds it complete.
TEST(TripleMaterial, MaterialFieldFileHoldsTheApproximatedRows) {
  MaterialOptions o;
  o.output = ::testing::TempDir() + "/ltb_material_test.ltm";
  std::remove(o.output.c_str());
  o.brdf = Brdf{Brdf::Kind::kPhong, 32, 1};
  o.cube_res = 16;
  o.samples_res = 2;
  o.energy = 0.99;
  auto r = RunMaterial(o, Progress{});
  ASSERT_TRUE(r.ok()) << r.status().ToString();
  EXPECT_EQ(r->rows, 24u);
  EXPECT_EQ(r->cols, 6u * 16 * 16);
  EXPECT_GE(r->worst_energy_kept, 0.99);
  auto reader = io::ContainerReader::Open(o.output);
  ASSERT_TRUE(reader.ok()) << reader.status().ToString();
  ASSERT_TRUE(reader->complete());
  EXPECT_EQ(reader->metadata().json["basis"]["cols"]["basis"], "haar-squares");
  uint64_t nonzero = 0;
  for (uint64_t k = 0; k < reader->metadata().matrix().ChunkCount(); ++k) {
    auto chunk = reader->ReadChunk(0, k);
    ASSERT_TRUE(chunk.ok()) << chunk.status().ToString();
    EXPECT_NE(chunk->encoding(), format::Encoding::kRaw) << "chunk " << k << " is not stored sparse";
    const auto values = chunk->as<float>();
    for (uint64_t rr = 0; rr < chunk->extent().rows; ++rr) {
      const uint64_t row = chunk->extent().row0 + rr;
      const glm::dvec3 dir = cubemap::TexelCenter(cubemap::ColumnToTexel(row, 2), 2);
      const CubeFaces faces = MaterialFaces(o.brdf, dir, 16);
      double total = 0, kept = 0, smallest_kept = INFINITY, largest_dropped = 0;
      for (int f = 0; f < 6; ++f) {
        for (uint64_t i = 0; i < 256; ++i) {
          const double c = faces[f].c[i];
          const float stored = values[rr * r->cols + f * 256 + i];
          total += c * c;
          if (stored != 0) {
            EXPECT_EQ(stored, static_cast<float>(c)) << "row " << row << " face " << f << " coefficient " << i;
            kept += c * c;
            smallest_kept = std::min(smallest_kept, c * c);
            ++nonzero;
          } else {
            largest_dropped = std::max(largest_dropped, c * c);
          }
        }
      }
      EXPECT_GE(kept, 0.99 * total) << "row " << row;
      EXPECT_LT(kept - smallest_kept, 0.99 * total) << "row " << row << ": more kept than needed";
      EXPECT_LE(largest_dropped, smallest_kept) << "row " << row << ": a larger coefficient was dropped";
    }
  }
  EXPECT_EQ(nonzero, r->terms_kept);
  EXPECT_LT(nonzero, r->rows * r->cols / 4) << "phong:32 at 99% energy should keep a small fraction";
  auto again = RunMaterial(o, Progress{});
  ASSERT_TRUE(again.ok());
  EXPECT_EQ(again->chunks_written, 0u);
  std::remove(o.output.c_str());
}

}  // namespace
}  // namespace ltb::triple
