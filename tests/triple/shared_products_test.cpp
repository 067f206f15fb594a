// The shared evaluation of triple products (stages/triple/shared_products.h) against the
// pixel-basis integral written out here: B = Σ_parts w Σ_faces Σ_p L_p V_p ρ̃_p / R², with V
// and ρ̃ decoded from the very float coefficients the method reads (HaarFace::Inverse, tested
// against the basis' definition in haar_triple_test). Also its face transforms against
// HaarFace's, the BRDF-term prefix, independence of the thread count, and a foreign field.
#include "stages/triple/shared_products.h"

#include <gtest/gtest.h>

#include <bit>
#include <cmath>
#include <random>
#include <vector>

#include "stages/wavelet/haar_face.h"

namespace ltb::triple {
namespace {

using wavelet::HaarFace;

TEST(SharedProducts, FaceTransformsEqualHaarFaceLaneByLane) {
  std::mt19937_64 rng(7);
  std::uniform_real_distribution<double> u(-3, 5);
  for (uint64_t res : {1, 2, 4, 8, 32}) {
    const uint64_t face = res * res;
    const int levels = std::countr_zero(res);
    std::vector<double> lanes(face * kLanes), coef(face * kLanes);
    std::vector<std::vector<double>> px(kLanes, std::vector<double>(face));
    for (uint64_t p = 0; p < face; ++p)
      for (int k = 0; k < kLanes; ++k) lanes[p * kLanes + k] = px[k][p] = u(rng);
    std::vector<float> lanes_f(lanes.begin(), lanes.end()), coef_f(face * kLanes), back_f(face), c_f(face);
    ForwardHaarLanes(lanes.data(), levels, coef.data());
    ForwardHaarLanes(lanes_f.data(), levels, coef_f.data());
    for (int k = 0; k < kLanes; ++k) {
      const HaarFace h = HaarFace::Forward(px[k], res);
      for (uint64_t c = 0; c < face; ++c) {
        ASSERT_NEAR(coef[c * kLanes + k], h.c[c], 1e-13) << res << " " << c;
        // float: the input rounded, then a rounding a pass, on values of at most 5 (|x| ≤ 5).
        ASSERT_NEAR(coef_f[c * kLanes + k], h.c[c], 1e-6 * (1 + levels) * 5) << res << " " << c;
        c_f[c] = static_cast<float>(h.c[c]);
      }
      InverseHaarFace(c_f.data(), levels, back_f.data());
      for (uint64_t p = 0; p < face; ++p) ASSERT_NEAR(back_f[p], px[k][p], 1e-6 * (1 + levels) * 5);
      std::vector<double> back(face);
      InverseHaarFace(h.c.data(), levels, back.data());
      const std::vector<double> want = h.Inverse();
      for (uint64_t p = 0; p < face; ++p) {
        ASSERT_NEAR(back[p], want[p], 1e-12);
        ASSERT_NEAR(back[p], px[k][p], 1e-12);
      }
    }
  }
}

// A small scene of random functions on a cube of R = 8: visibility rows (fractions, zero on
// some faces), one field whose rows are non-zero on two faces each, coefficients ordered as
// MaterialField keeps them (scaling coefficients first, then by decreasing magnitude).
struct SharedScene {
  static constexpr uint64_t kRes = 8, kFace = kRes * kRes, kCols = 6 * kFace;
  SparseRows vis;
  std::vector<MaterialField> fields{1};
  std::vector<double> light_px[3];  // 6R² per channel
  std::vector<float> light_lanes;
  int light_exponent = 0;

  static void Append(const std::vector<double>& px, bool by_magnitude, SparseRows* rows, uint32_t* scaling) {
    std::vector<std::pair<uint32_t, float>> e;
    for (uint64_t f = 0; f < 6; ++f) {
      const HaarFace h =
          HaarFace::Forward(std::vector<double>(px.begin() + f * kFace, px.begin() + (f + 1) * kFace), kRes);
      for (uint64_t c = 0; c < kFace; ++c)
        if (h.c[c] != 0) e.emplace_back(static_cast<uint32_t>(f * kFace + c), static_cast<float>(h.c[c]));
    }
    if (by_magnitude) {
      std::stable_sort(e.begin(), e.end(), [](const auto& a, const auto& b) {
        const bool sa = a.first % kFace == 0, sb = b.first % kFace == 0;
        return sa != sb ? sa : std::fabs(a.second) > std::fabs(b.second);
      });
      *scaling =
          static_cast<uint32_t>(std::count_if(e.begin(), e.end(), [](const auto& x) { return x.first % kFace == 0; }));
    }
    for (const auto& [c, v] : e) {
      rows->col.push_back(c);
      rows->val.push_back(v);
    }
    rows->offset.push_back(rows->col.size());
    ++rows->rows;
  }

  SharedScene() {
    std::mt19937_64 rng(11);
    std::uniform_real_distribution<double> u(0, 1);
    vis.cols = kCols;
    for (int r = 0; r < 5; ++r) {
      std::vector<double> v(kCols, 0.0);
      for (uint64_t p = 0; p < kCols; ++p) {
        if (p / kFace == static_cast<uint64_t>(r % 6)) continue;  // a face unseen
        const double x = u(rng);
        v[p] = x < 0.4 ? 1.0 : x < 0.7 ? 0.0 : x;
      }
      Append(v, false, &vis, nullptr);
    }
    MaterialField& mf = fields[0];
    mf.rows.cols = kCols;
    for (int r = 0; r < 7; ++r) {
      std::vector<double> rho(kCols, 0.0);
      for (uint64_t p = 0; p < kCols; ++p) {
        const uint64_t f = p / kFace;
        if (f == static_cast<uint64_t>(r % 6) || f == static_cast<uint64_t>((r + 2) % 6)) rho[p] = std::pow(u(rng), 4);
      }
      mf.scaling.push_back(0);
      Append(rho, true, &mf.rows, &mf.scaling.back());
    }
    std::vector<double> coef[3];
    for (int ch = 0; ch < 3; ++ch) {
      light_px[ch].resize(kCols);
      for (double& x : light_px[ch]) x = 10 * std::pow(u(rng), 3);
      coef[ch].resize(kCols);
      for (uint64_t f = 0; f < 6; ++f) {
        const HaarFace h = HaarFace::Forward(
            std::vector<double>(light_px[ch].begin() + f * kFace, light_px[ch].begin() + (f + 1) * kFace), kRes);
        std::copy(h.c.begin(), h.c.end(), coef[ch].begin() + f * kFace);
      }
    }
    light_lanes = LightingLanes(coef, kRes, &light_exponent);
  }

  // The pixel values of sparse row `r` (its first `keep` entries).
  static std::vector<double> Pixels(const SparseRows& rows, uint64_t r, uint64_t keep) {
    std::vector<double> c(kCols, 0.0), px;
    const uint64_t end = rows.offset[r] + std::min(keep, rows.offset[r + 1] - rows.offset[r]);
    for (uint64_t e = rows.offset[r]; e < end; ++e) c[rows.col[e]] = rows.val[e];
    for (uint64_t f = 0; f < 6; ++f) {
      HaarFace h;
      h.res = kRes;
      h.c.assign(c.begin() + f * kFace, c.begin() + (f + 1) * kFace);
      const std::vector<double> p = h.Inverse();
      px.insert(px.end(), p.begin(), p.end());
    }
    return px;
  }

  // The oracle: Σ_parts w Σ_p L_p V_p ρ_p / R² of each listed vertex.
  std::vector<double> Expected(const std::vector<uint64_t>& verts, const VertexRho& rho, uint64_t brdf_terms) const {
    std::vector<double> out;
    for (uint64_t i = 0; i < verts.size(); ++i) {
      const std::vector<double> v = Pixels(vis, verts[i], UINT64_MAX);
      double b[3] = {0, 0, 0};
      for (uint64_t s = rho.offset[i]; s < rho.offset[i + 1]; ++s) {
        const RhoPart& p = rho.parts[s];
        const uint64_t keep = brdf_terms == UINT64_MAX ? UINT64_MAX : p.field->scaling[p.row] + brdf_terms;
        const std::vector<double> r = Pixels(p.field->rows, p.row, keep);
        for (int ch = 0; ch < 3; ++ch)
          for (uint64_t q = 0; q < kCols; ++q) b[ch] += p.weight * light_px[ch][q] * v[q] * r[q] / kFace;
      }
      out.insert(out.end(), b, b + 3);
    }
    return out;
  }
};

VertexRho Parts(const SharedScene& sc, const std::vector<uint64_t>& verts) {
  VertexRho rho;
  for (uint64_t i = 0; i < verts.size(); ++i) {
    for (uint64_t k = 0; k < 4; ++k)  // rows shared between vertices, one used twice by a vertex
      rho.parts.push_back({&sc.fields[0], (i + k * k) % 7, 0.1 + 0.2 * static_cast<double>(k)});
    rho.offset.push_back(rho.parts.size());
  }
  return rho;
}

TEST(SharedProducts, EqualsThePixelBasisIntegral) {
  const SharedScene sc;
  const std::vector<uint64_t> verts = {0, 3, 1, 4, 2, 0};
  const VertexRho rho = Parts(sc, verts);
  for (uint64_t terms : {UINT64_MAX, uint64_t{0}, uint64_t{3}}) {
    std::vector<double> got;
    SharedStats stats;
    ASSERT_TRUE(SharedTripleProducts(sc.vis, SharedScene::kRes, sc.light_lanes, verts, rho, sc.fields, terms, 2, {},
                                     &got, &stats)
                    .ok());
    const std::vector<double> want = sc.Expected(verts, rho, terms);
    ASSERT_EQ(got.size(), want.size());
    double scale = 0;
    for (double w : want) scale = std::max(scale, std::fabs(w));
    ASSERT_GT(scale, 0.1);
    // The rows are lit in float (24-bit significands): the lighting rounded once, each lit
    // texel and each of the 2·log2 R transform passes adds a rounding of the values' size, so
    // ‖ΔG‖ ≲ 10 · 2^-24 · ‖Lρ‖ and |ΔB| ≲ ‖V‖ ‖ΔG‖; 1e-6 of the largest B holds that with room.
    for (uint64_t k = 0; k < want.size(); ++k)
      EXPECT_NEAR(std::ldexp(got[k], sc.light_exponent), want[k], 1e-6 * scale) << terms << " " << k;
    EXPECT_EQ(stats.rows_lit, 7u);
    EXPECT_EQ(stats.faces_lit, 14u);  // two faces a row
  }
}

TEST(SharedProducts, TheThreadCountDoesNotChangeABit) {
  const SharedScene sc;
  const std::vector<uint64_t> verts = {4, 2, 2, 0, 1, 3};
  const VertexRho rho = Parts(sc, verts);
  std::vector<double> one, two;
  ASSERT_TRUE(SharedTripleProducts(sc.vis, SharedScene::kRes, sc.light_lanes, verts, rho, sc.fields, UINT64_MAX, 1, {},
                                   &one, nullptr)
                  .ok());
  ASSERT_TRUE(SharedTripleProducts(sc.vis, SharedScene::kRes, sc.light_lanes, verts, rho, sc.fields, UINT64_MAX, 2, {},
                                   &two, nullptr)
                  .ok());
  ASSERT_EQ(one.size(), two.size());
  for (uint64_t k = 0; k < one.size(); ++k) EXPECT_EQ(std::bit_cast<uint64_t>(one[k]), std::bit_cast<uint64_t>(two[k]));
}

TEST(SharedProducts, RefusesAPartOfAnotherField) {
  const SharedScene sc;
  MaterialField other = sc.fields[0];
  VertexRho rho;
  rho.parts.push_back({&other, 0, 1.0});
  rho.offset.push_back(1);
  std::vector<double> out;
  const Status s = SharedTripleProducts(sc.vis, SharedScene::kRes, sc.light_lanes, std::vector<uint64_t>{0}, rho,
                                        sc.fields, UINT64_MAX, 1, {}, &out, nullptr);
  EXPECT_FALSE(s.ok());
  EXPECT_NE(s.message().find("outside the material fields"), std::string::npos) << s.message();
}

}  // namespace
}  // namespace ltb::triple
