// ColumnCompressor and quantization: depth choice on known images, the bounds the method
// promises, exact round trips, numerical stress, and the quantizer's error bounds.
// Reconstructions here are computed independently in double (wavelet::Inverse2D<double>)
// from the kept coefficients; errors are compared with what the compressor reports.
#include "stages/column_transform/column_compressor.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <limits>
#include <random>

#include "stages/column_transform/column_codec.h"
#include "stages/quantize/quantize.h"

namespace ltb::stages {
namespace {

using wavelet::Filter;

constexpr Filter kAll[] = {Filter::kHaar, Filter::kDb2, Filter::kDb3, Filter::kDb4, Filter::kLeGall53, Filter::kCdf97};

ColumnChoice ChooseOne(Filter f, uint64_t w, uint64_t h, int dmin, int dmax, const std::vector<float>& img,
                       uint64_t terms) {
  auto c = ColumnCompressor::Create(f, w, h, dmin, dmax);
  EXPECT_TRUE(c.ok()) << c.status().message();
  const float* cols[1] = {img.data()};
  Selection sel;
  sel.terms = terms;
  ColumnChoice out[1];
  Status s = c->Choose(cols, 1, &sel, nullptr, out);
  EXPECT_TRUE(s.ok()) << s.message();
  return out[0];
}

// ‖x − S(kept)‖² in double, independently of the compressor.
double ReconstructionError(Filter f, uint64_t w, uint64_t h, const std::vector<float>& img, const ColumnChoice& c,
                           std::vector<double>* rec_out = nullptr) {
  std::vector<double> rec(w * h, 0.0), scratch(wavelet::ScratchSize(w, h, 1));
  for (size_t i = 0; i < c.index.size(); ++i) rec[c.index[i]] = c.value[i];
  wavelet::Inverse2D<double>(f, rec.data(), w, h, 1, c.depth, scratch.data());
  double e = 0;
  for (size_t p = 0; p < img.size(); ++p) e += (img[p] - rec[p]) * (img[p] - rec[p]);
  if (rec_out) *rec_out = rec;
  return e;
}

int Deepest(uint64_t w, uint64_t h) { return wavelet::MaxDepth(w, h); }

TEST(ColumnCompressor, ConstantImageChoosesFullDepth) {
  for (Filter f : kAll) {
    std::vector<float> img(32 * 32, 0.75f);
    ColumnChoice c = ChooseOne(f, 32, 32, 0, Deepest(32, 32), img, 4);
    EXPECT_EQ(c.depth, Deepest(32, 32)) << wavelet::FilterName(f);
    EXPECT_LE(c.index.size(), 1u) << wavelet::FilterName(f);
    EXPECT_LE(c.error, kExactRelativeEnergy * c.energy) << wavelet::FilterName(f);
  }
}

TEST(ColumnCompressor, SmoothImageChoosesFullDepth) {
  // A wide, low bump: smooth at every scale of a 64×64 image.
  std::vector<float> img(64 * 64);
  for (int y = 0; y < 64; ++y)
    for (int x = 0; x < 64; ++x)
      img[y * 64 + x] = static_cast<float>(1.0 + 0.25 * std::cos(2 * M_PI * x / 64.0) * std::cos(2 * M_PI * y / 64.0));
  for (Filter f : {Filter::kHaar, Filter::kDb2, Filter::kLeGall53, Filter::kCdf97}) {
    ColumnChoice c = ChooseOne(f, 64, 64, 0, Deepest(64, 64), img, 16);
    EXPECT_GE(c.depth, Deepest(64, 64) - 1) << wavelet::FilterName(f);
  }
}

TEST(ColumnCompressor, SinglePixelChoosesDepthZero) {
  for (Filter f : kAll) {
    std::vector<float> img(16 * 16, 0.0f);
    img[5 * 16 + 9] = 3.0f;
    ColumnChoice c = ChooseOne(f, 16, 16, 0, Deepest(16, 16), img, 1);
    EXPECT_EQ(c.depth, 0) << wavelet::FilterName(f);
    EXPECT_EQ(c.error, 0.0) << wavelet::FilterName(f);
    ASSERT_EQ(c.index.size(), 1u);
    EXPECT_EQ(c.index[0], 5u * 16 + 9);
  }
}

std::vector<float> TestImage(uint64_t w, uint64_t h, uint32_t seed) {
  // A smooth part, a hard shadow edge and noise: neither depth 0 nor the full depth is
  // trivially best.
  std::mt19937 rng(seed);
  std::normal_distribution<float> noise(0.0f, 0.02f);
  std::vector<float> img(w * h);
  for (uint64_t y = 0; y < h; ++y)
    for (uint64_t x = 0; x < w; ++x) {
      float v = 0.5f + 0.3f * std::sin(0.2f * x + 0.1f * y) + (x * 3 > y * 2 + w ? 0.4f : 0.0f);
      img[y * w + x] = v + noise(rng);
    }
  return img;
}

TEST(ColumnCompressor, ChosenDepthIsNoWorseThanDepthZeroOrFullAndReportsTheTrueError) {
  for (Filter f : kAll) {
    for (uint64_t terms : {4u, 32u, 200u}) {
      const uint64_t w = 32, h = 16;
      auto img = TestImage(w, h, 7);
      int dmax = Deepest(w, h);
      ColumnChoice a = ChooseOne(f, w, h, 0, dmax, img, terms);
      ColumnChoice z = ChooseOne(f, w, h, 0, 0, img, terms);
      ColumnChoice full = ChooseOne(f, w, h, dmax, dmax, img, terms);
      EXPECT_LE(a.error, z.error) << wavelet::FilterName(f) << " N=" << terms;
      EXPECT_LE(a.error, full.error) << wavelet::FilterName(f) << " N=" << terms;
      EXPECT_LE(a.index.size(), terms);
      for (const ColumnChoice* c : {&a, &z, &full}) {
        double truth = ReconstructionError(f, w, h, img, *c);
        // The reported error comes from f32 coefficients: it is within f32 rounding of the
        // dropped energy itself, plus the rounding of the kept terms (≤ (64 ε)² of the energy).
        EXPECT_NEAR(c->error, truth, 1e-5 * truth + 4 * kExactRelativeEnergy * c->energy)
            << wavelet::FilterName(f) << " N=" << terms << " depth " << c->depth;
      }
    }
  }
}

TEST(ColumnCompressor, ErrorIsNonIncreasingInTerms) {
  for (Filter f : kAll) {
    auto img = TestImage(16, 16, 3);
    double prev = std::numeric_limits<double>::infinity();
    for (uint64_t n = 1; n <= 256; n += 5) {
      ColumnChoice c = ChooseOne(f, 16, 16, 0, Deepest(16, 16), img, n);
      EXPECT_LE(c.error, prev * (1 + 1e-12)) << wavelet::FilterName(f) << " N=" << n;
      prev = c.error;
    }
  }
}

TEST(ColumnCompressor, KeepingEveryTermIsExactToFloatPrecision) {
  for (Filter f : kAll) {
    for (int d = 0; d <= Deepest(32, 32); ++d) {
      auto img = TestImage(32, 32, 11);
      ColumnChoice c = ChooseOne(f, 32, 32, d, d, img, 32 * 32);
      std::vector<double> rec;
      ReconstructionError(f, 32, 32, img, c, &rec);
      double maxabs = 0;
      for (float v : img) maxabs = std::max<double>(maxabs, std::fabs(v));
      // Each f32 analysis step rounds every value once (relative ε per step, amplified by
      // at most the filter's gain, < 4 for these filters); synthesis runs in double.
      double bound = 4.0 * (d + 1) * std::numeric_limits<float>::epsilon() * maxabs * 4;
      for (size_t p = 0; p < img.size(); ++p)
        ASSERT_NEAR(rec[p], img[p], bound) << wavelet::FilterName(f) << " d=" << d;
    }
  }
}

TEST(ColumnCompressor, NumericalStress) {
  struct Case {
    const char* name;
    uint64_t w, h;
    std::function<float(uint64_t, uint64_t)> v;
  };
  const float sub = std::numeric_limits<float>::denorm_min() * 1000;
  std::vector<Case> cases = {
      {"tiny 1e-30", 16, 16, [](uint64_t x, uint64_t y) { return 1e-30f * (1 + (x * 7 + y * 3) % 5); }},
      {"huge 1e+30", 16, 16, [](uint64_t x, uint64_t y) { return 1e30f * (1 + (x * 7 + y * 3) % 5); }},
      {"subnormal", 16, 16, [sub](uint64_t x, uint64_t y) { return sub * ((x + y) % 3); }},
      {"one huge among tiny", 16, 16, [](uint64_t x, uint64_t y) { return x == 3 && y == 4 ? 1e30f : 1e-30f; }},
      {"constant", 16, 16, [](uint64_t, uint64_t) { return 2.5f; }},
      {"1xN", 1, 64, [](uint64_t, uint64_t y) { return 0.1f * y; }},
      {"Nx1", 64, 1, [](uint64_t x, uint64_t) { return 0.1f * (x % 7); }},
      {"odd 13x7", 13, 7, [](uint64_t x, uint64_t y) { return std::sin(0.3f * x) + 0.1f * y; }},
      {"1x1", 1, 1, [](uint64_t, uint64_t) { return 4.0f; }},
  };
  for (const Case& k : cases) {
    std::vector<float> img(k.w * k.h);
    for (uint64_t y = 0; y < k.h; ++y)
      for (uint64_t x = 0; x < k.w; ++x) img[y * k.w + x] = k.v(x, y);
    for (Filter f : kAll) {
      if (!wavelet::CheckSize(f, k.w, k.h).ok()) continue;
      for (uint64_t terms : {1u, 5u, 1000u}) {
        ColumnChoice c = ChooseOne(f, k.w, k.h, 0, Deepest(k.w, k.h), img, terms);
        std::string where = std::string(k.name) + " " + wavelet::FilterName(f) + " N=" + std::to_string(terms);
        ASSERT_TRUE(std::isfinite(c.energy) && std::isfinite(c.error)) << where;
        EXPECT_GE(c.error, 0.0) << where;
        // Depth 0 is always examined and drops pixels: the error never exceeds the energy.
        EXPECT_LE(c.error, c.energy * (1 + 1e-12)) << where;
        for (float v : c.value) ASSERT_TRUE(std::isfinite(v)) << where;
        if (terms >= k.w * k.h) {
          double truth = ReconstructionError(f, k.w, k.h, img, c);
          EXPECT_LE(truth, 1e-10 * c.energy + 0.0) << where;
        }
      }
    }
  }
}

TEST(ColumnCompressor, AllZeroColumnKeepsNothing) {
  std::vector<float> img(8 * 8, 0.0f);
  ColumnChoice c = ChooseOne(Filter::kLeGall53, 8, 8, 0, 3, img, 10);
  EXPECT_EQ(c.energy, 0.0);
  EXPECT_EQ(c.error, 0.0);
  EXPECT_TRUE(c.index.empty());
}

TEST(ColumnCompressor, NonFiniteInputIsRefusedNamingThePixel) {
  std::vector<float> img(8 * 8, 1.0f);
  img[8 * 2 + 5] = std::numeric_limits<float>::quiet_NaN();
  auto c = ColumnCompressor::Create(Filter::kHaar, 8, 8, 0, 3);
  ASSERT_TRUE(c.ok());
  const float* cols[1] = {img.data()};
  Selection sel;
  sel.terms = 3;
  ColumnChoice out[1];
  Status s = c->Choose(cols, 1, &sel, nullptr, out);
  EXPECT_EQ(s.code(), StatusCode::kInvalidArgument);
  EXPECT_NE(s.message().find("x 5, y 2"), std::string::npos) << s.message();
}

TEST(ColumnCompressor, LanesAreIndependent) {
  // The same column gives the same choice alone and among seven others.
  const uint64_t w = 16, h = 16;
  std::vector<std::vector<float>> imgs;
  for (uint32_t i = 0; i < 8; ++i) imgs.push_back(TestImage(w, h, 100 + i));
  for (Filter f : {Filter::kDb2, Filter::kCdf97}) {
    auto c = ColumnCompressor::Create(f, w, h, 0, Deepest(w, h));
    ASSERT_TRUE(c.ok());
    const float* cols[8];
    Selection sel[8];
    for (int i = 0; i < 8; ++i) {
      cols[i] = imgs[i].data();
      sel[i].terms = 20;
    }
    ColumnChoice together[8];
    ASSERT_TRUE(c->Choose(cols, 8, sel, nullptr, together).ok());
    for (int i = 0; i < 8; ++i) {
      ColumnChoice alone = ChooseOne(f, w, h, 0, Deepest(w, h), imgs[i], 20);
      EXPECT_EQ(alone.depth, together[i].depth);
      EXPECT_EQ(alone.index, together[i].index);
      EXPECT_EQ(alone.value, together[i].value);
      EXPECT_EQ(alone.error, together[i].error);
    }
  }
}

// Columns of several kinds for the path comparison below: the test image, sparse
// columns (fewer nonzeros than terms at some depths), values on a coarse grid (many equal
// keys: ties at the threshold), a constant (exact at full depth: the rounding-residue
// trim), a smooth ramp plus a blob (coarse bands kept whole at deep depths), a pixel on
// fine checkerboards (exact zeros in the coarse bands), zeros.
std::vector<float> PathTestColumn(uint64_t w, uint64_t h, uint32_t kind, uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(-1.0f, 1.0f);
  std::vector<float> img(w * h, 0.0f);
  switch (kind % 7) {
    case 0:
      return TestImage(w, h, seed);
    case 1:
      for (int i = 0; i < 6; ++i) img[rng() % img.size()] = u(rng);
      return img;
    case 2:
      for (float& v : img) v = std::round(u(rng) * 3.0f) * 0.25f;
      return img;
    case 3:
      std::fill(img.begin(), img.end(), 0.375f);
      return img;
    case 4:
      for (uint64_t y = 0; y < h; ++y)
        for (uint64_t x = 0; x < w; ++x) {
          float dx = float(x) - 0.3f * float(w), dy = float(y) - 0.6f * float(h);
          img[y * w + x] = 0.01f * float(x + 2 * y) + 2.0f * std::exp(-(dx * dx + dy * dy) / 9.0f);
        }
      return img;
    case 5:
      // A bright 4×4 block and, in the right half, 2×2 checkerboards: for Haar these are
      // pure finest-level HH, so the coarse low bands hold exact zeros, and depth 2 packs
      // the block's four depth-1 coefficients into one.
      for (uint64_t y = 0; y < 4; ++y)
        for (uint64_t x = 0; x < 4; ++x) img[y * w + x] = 10.0f;
      for (uint64_t y = 0; y + 1 < h; y += 2)
        for (uint64_t x = w / 2; x + 1 < w; x += 2) {
          float s = 0.001f * (1.0f + u(rng));
          img[y * w + x] = img[(y + 1) * w + x + 1] = s;
          img[y * w + x + 1] = img[(y + 1) * w + x] = -s;
        }
      return img;
    default:
      return img;  // all zero
  }
}

TEST(ColumnCompressor, CutPathEqualsTheExplicitPathBitForBit) {
  // The depth search builds kept sets as cuts and measures errors in one pass over the
  // lanes; SetReferencePath(true) selects and reconstructs every column and depth
  // explicitly. Both must give the same depth, kept terms, values and error (bit for
  // bit), for every filter, depth range and term count, columns eight to a call.
  struct Size {
    uint64_t w, h;
  };
  for (Filter f : kAll) {
    const bool ortho = wavelet::IsOrthonormal(f);
    for (Size sz : {Size{16, 16}, Size{32, 8}, Size{24, 20}}) {
      if (ortho && sz.w == 24) continue;
      const int deepest = Deepest(sz.w, sz.h);
      for (auto [dmin, dmax] : {std::pair{0, deepest}, std::pair{2, deepest - 1}, std::pair{deepest, deepest}}) {
        auto fast = ColumnCompressor::Create(f, sz.w, sz.h, dmin, dmax);
        auto ref = ColumnCompressor::Create(f, sz.w, sz.h, dmin, dmax);
        ASSERT_TRUE(fast.ok() && ref.ok());
        ref->SetReferencePath(true);
        for (uint64_t terms : {1u, 7u, 40u, 300u}) {
          std::vector<std::vector<float>> imgs;
          const float* cols[8];
          Selection sel[8];
          for (uint32_t k = 0; k < 8; ++k) {
            imgs.push_back(PathTestColumn(sz.w, sz.h, k + static_cast<uint32_t>(terms), 31 * k + 5));
            sel[k].terms = terms;
          }
          for (uint32_t k = 0; k < 8; ++k) cols[k] = imgs[k].data();
          ColumnChoice a[8], b[8];
          ASSERT_TRUE(fast->Choose(cols, 8, sel, nullptr, a).ok());
          ASSERT_TRUE(ref->Choose(cols, 8, sel, nullptr, b).ok());
          for (int k = 0; k < 8; ++k) {
            SCOPED_TRACE(std::string(wavelet::FilterName(f)) + " " + std::to_string(sz.w) + "x" + std::to_string(sz.h) +
                         " depths " + std::to_string(dmin) + ".." + std::to_string(dmax) + " terms " +
                         std::to_string(terms) + " column " + std::to_string(k));
            EXPECT_EQ(a[k].depth, b[k].depth);
            EXPECT_EQ(a[k].index, b[k].index);
            EXPECT_EQ(a[k].value, b[k].value);
            EXPECT_EQ(std::memcmp(&a[k].error, &b[k].error, sizeof(double)), 0) << a[k].error << " " << b[k].error;
            EXPECT_EQ(a[k].energy, b[k].energy);
          }
        }
      }
    }
  }
}

TEST(EnergyBins, EdgesAgreeWithBins) {
  std::mt19937_64 rng(5);
  std::uniform_real_distribution<double> u(-300, 300);
  for (int i = 0; i < 20000; ++i) {
    double e = std::exp2(u(rng));
    int b = EnergyBin(e);
    EXPECT_GE(e, BinLowerEdge(b));
    EXPECT_LT(e, BinLowerEdge(b + 1));
  }
  EXPECT_EQ(EnergyBin(1.0), 0);
  EXPECT_EQ(EnergyBin(2.0), kBinsPerOctave);
  EXPECT_EQ(EnergyBin(0.5), -kBinsPerOctave);
  EXPECT_EQ(EnergyBin(std::numeric_limits<double>::denorm_min()), kBinsPerOctave * -1074);
}

TEST(Levels, MatchTheBandStructure) {
  // 8×8 at depth 3: low band (1×1) and step-3 details are level 0, step 2 level 1, step 1 level 2.
  auto lv = ColumnCodec::ComputeLevels(8, 8, 3);
  EXPECT_EQ(lv[0], 0);
  EXPECT_EQ(lv[1], 0);          // step-3 detail (x = 1)
  EXPECT_EQ(lv[2 * 8 + 3], 1);  // step-2 band (x, y in 2..3)
  EXPECT_EQ(lv[7 * 8 + 7], 2);  // finest
  EXPECT_EQ(lv[0 * 8 + 4], 2);
  auto flat = ColumnCodec::ComputeLevels(8, 8, 0);
  for (uint8_t l : flat) EXPECT_EQ(l, 0);
}

TEST(Quantize, RoundingIsWithinHalfAStepAndDitherWithinOne) {
  std::mt19937_64 rng(9);
  std::uniform_real_distribution<double> u(-1, 1);
  for (int bits : {2, 5, 9, 16}) {
    const double q = std::ldexp(1.0, bits - 1) - 1;
    double mean_err = 0;
    const int n = 20000;
    for (int i = 0; i < n; ++i) {
      double m = std::ldexp(1.0, static_cast<int>(u(rng) * 100));
      double v = u(rng) * m;
      int32_t r = QuantizeValue(v, m, q, false, 1, 3, i);
      int32_t d = QuantizeValue(v, m, q, true, 1, 3, i);
      double step = m / q;
      EXPECT_LE(std::fabs(r * step - v), 0.5 * step * (1 + 1e-12)) << bits;
      EXPECT_LT(std::fabs(d * step - v), step * (1 + 1e-12)) << bits;
      EXPECT_LE(std::abs(r), q);
      EXPECT_LE(std::abs(d), q);
      mean_err += d * step - v;
      // Deterministic: the same element gives the same value.
      EXPECT_EQ(d, QuantizeValue(v, m, q, true, 1, 3, i));
    }
    (void)mean_err;
  }
  // The extremes map to ±Q exactly.
  EXPECT_EQ(QuantizeValue(1e-40, 1e-40, 255, true, 1, 0, 0), 255);
  EXPECT_EQ(QuantizeValue(-1e30, 1e30, 255, false, 1, 0, 0), -255);
}

TEST(Quantize, DitherIsUnbiased) {
  // Non-subtractive uniform dither: the mean of q·step over many elements of one value is
  // the value itself (to ~1/sqrt(n) of a step).
  const double q = 255, m = 1.0, v = 0.123456;
  double sum = 0;
  const int n = 100000;
  for (int i = 0; i < n; ++i) sum += QuantizeValue(v, m, q, true, 7, 1, i) * (m / q);
  EXPECT_NEAR(sum / n, v, 5.0 / q / std::sqrt(n));
}

TEST(Quantize, StepDecisionEqualsTheOrderedScalarSum) {
  // The step search decides from a vectorised sum except near the bound; its answer must be
  // the plain loop's (std::round, added in order) for every bound, also one equal to that
  // loop's own result and its neighbouring doubles, with exact halves, negatives and ties.
  std::mt19937_64 rng(11);
  std::normal_distribution<double> normal;
  for (const size_t n : {size_t{1}, size_t{7}, size_t{8}, size_t{9}, size_t{1000}, size_t{100003}}) {
    std::vector<double> x(n);
    for (size_t i = 0; i < n; ++i) x[i] = normal(rng) * std::exp2(static_cast<int>(rng() % 20) - 10);
    for (size_t i = 0; i < n; i += 5) x[i] = (static_cast<double>(rng() % 40) - 20.0 + 0.5) * 0.25;  // halves of 0.25
    for (const double step : {0.25, 0.1, 1.0 / 3.0, 3.0}) {
      double ordered = 0;
      for (double v : x) {
        const double d = std::round(v / step) * step - v;
        ordered += d * d;
      }
      for (const double weight : {1.0, 2.5}) {
        const double e = ordered * weight;
        for (const double bound : {e, std::nextafter(e, 0.0), std::nextafter(e, INFINITY), e * (1 + 1e-12),
                                   e * (1 - 1e-12), e * 1.01, e * 0.99, 0.0}) {
          EXPECT_EQ(QuantizationErrorAtMost(x, step, weight, bound), e <= bound)
              << "n " << n << " step " << step << " weight " << weight << " bound " << bound << " sum " << e;
        }
      }
    }
  }
}

}  // namespace
}  // namespace ltb::stages
