// Wavelet library properties: perfect reconstruction for every filter, depth and size
// (odd, 1×N, N×1), energy preservation for the orthonormal filters, linearity, lane
// independence, and closed forms for the biorthogonal lifting (DC gain 1, Nyquist gain 2,
// vanishing moments). The PyWavelets oracle is tests/wavelet/pywt_oracle_test.py.
#include "stages/wavelet/wavelet.h"

#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <vector>

namespace ltb::wavelet {
namespace {

const Filter kAll[] = {Filter::kHaar, Filter::kDb2, Filter::kDb3, Filter::kDb4, Filter::kLeGall53, Filter::kCdf97};

template <typename T>
std::vector<T> Random(size_t n, uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-1, 1);
  std::vector<T> v(n);
  for (auto& x : v) x = static_cast<T>(u(rng));
  return v;
}

template <typename T>
double RelError(const std::vector<T>& a, const std::vector<T>& b) {
  double num = 0, den = 0;
  for (size_t i = 0; i < a.size(); ++i) {
    num += (double(a[i]) - double(b[i])) * (double(a[i]) - double(b[i]));
    den += double(b[i]) * double(b[i]);
  }
  return std::sqrt(num / std::max(den, 1e-300));
}

template <typename T>
double Energy(const std::vector<T>& a) {
  double e = 0;
  for (T x : a) e += double(x) * double(x);
  return e;
}

std::vector<std::pair<size_t, size_t>> Sizes(Filter f) {
  if (IsOrthonormal(f)) return {{1, 1}, {2, 2}, {1, 16}, {16, 1}, {8, 32}, {64, 64}, {2, 128}};
  return {{1, 1}, {1, 7}, {7, 1}, {5, 3}, {2, 9}, {13, 17}, {33, 32}, {64, 64}, {1, 100}};
}

template <typename T>
void CheckReconstruction(double tol) {
  for (Filter f : kAll) {
    for (auto [w, h] : Sizes(f)) {
      ASSERT_TRUE(CheckSize(f, w, h).ok());
      for (size_t lanes : {size_t(1), size_t(3)}) {
        for (int depth = 0; depth <= MaxDepth(w, h); ++depth) {
          auto x = Random<T>(w * h * lanes, 7 + depth);
          auto y = x;
          std::vector<T> scratch(ScratchSize(w, h, lanes));
          Forward2D(f, y.data(), w, h, lanes, depth, scratch.data());
          if (IsOrthonormal(f)) {
            EXPECT_NEAR(Energy(y) / Energy(x), 1.0, tol) << FilterName(f) << " " << w << "x" << h << " d" << depth;
          }
          Inverse2D(f, y.data(), w, h, lanes, depth, scratch.data());
          EXPECT_LE(RelError(y, x), tol) << FilterName(f) << " " << w << "x" << h << " lanes " << lanes << " depth "
                                         << depth;
        }
      }
    }
  }
}

TEST(Wavelet, PerfectReconstructionF64) { CheckReconstruction<double>(1e-6); }
TEST(Wavelet, PerfectReconstructionF32) { CheckReconstruction<float>(1e-5); }

TEST(Wavelet, Reconstruction1DAnyLength) {
  for (Filter f : kAll) {
    for (size_t n : {1, 2, 3, 4, 5, 8, 11, 16, 31, 64}) {
      if (CheckSize(f, n, 1).ok() == false) continue;
      auto x = Random<double>(n * 2, 3);
      auto y = x;
      std::vector<double> scratch(n * 2);
      int depth = MaxDepth(n, 1);
      Forward1D(f, y.data(), n, 2, 2, depth, scratch.data());
      Inverse1D(f, y.data(), n, 2, 2, depth, scratch.data());
      EXPECT_LE(RelError(y, x), 1e-12) << FilterName(f) << " n=" << n;
    }
  }
}

TEST(Wavelet, LinearityAndLaneIndependence) {
  for (Filter f : kAll) {
    size_t w = 16, h = 8, lanes = 4;
    auto a = Random<double>(w * h, 1), b = Random<double>(w * h, 2);
    // Lane 0: a, lane 1: b, lane 2: 2a - 3b, lane 3: zero.
    std::vector<double> packed(w * h * lanes, 0.0);
    for (size_t i = 0; i < w * h; ++i) {
      packed[i * lanes + 0] = a[i];
      packed[i * lanes + 1] = b[i];
      packed[i * lanes + 2] = 2 * a[i] - 3 * b[i];
    }
    std::vector<double> scratch(ScratchSize(w, h, lanes)), s1(ScratchSize(w, h, 1));
    Forward2D(f, packed.data(), w, h, lanes, MaxDepth(w, h), scratch.data());
    auto ta = a;
    Forward2D(f, ta.data(), w, h, 1, MaxDepth(w, h), s1.data());
    for (size_t i = 0; i < w * h; ++i) {
      EXPECT_EQ(packed[i * lanes + 0], ta[i]) << "lane 0 must equal the single-lane transform";
      EXPECT_NEAR(packed[i * lanes + 2], 2 * packed[i * lanes + 0] - 3 * packed[i * lanes + 1], 1e-12);
      EXPECT_EQ(packed[i * lanes + 3], 0.0);
    }
  }
}

TEST(Biorthogonal, DcGainOneNyquistGainTwo) {
  for (Filter f : {Filter::kLeGall53, Filter::kCdf97}) {
    for (size_t n : {2, 3, 8, 9, 16}) {
      std::vector<double> c(n, 3.0), alt(n), scratch(n);
      for (size_t i = 0; i < n; ++i) alt[i] = (i % 2 == 0) ? 1.0 : -1.0;
      AnalysisStep1D(f, c.data(), n, 1, 1, scratch.data());
      size_t low = LowCount(n);
      for (size_t i = 0; i < low; ++i) EXPECT_NEAR(c[i], 3.0, 1e-12) << FilterName(f) << " n=" << n;
      for (size_t i = low; i < n; ++i) EXPECT_NEAR(c[i], 0.0, 1e-12) << FilterName(f) << " n=" << n;
      AnalysisStep1D(f, alt.data(), n, 1, 1, scratch.data());
      // Interior high-pass samples of the alternating signal (+1 at even, -1 at odd): -2.
      if (n >= 8) {
        EXPECT_NEAR(alt[low + 1], -2.0, 1e-9) << FilterName(f);
        EXPECT_NEAR(alt[1], 0.0, 1e-9) << FilterName(f);
      }
    }
  }
}

TEST(Biorthogonal, VanishingMoments) {
  // 5/3 annihilates linear signals, 9/7 cubic ones, away from the boundaries.
  size_t n = 32;
  for (auto [f, degree] : {std::pair{Filter::kLeGall53, 1}, std::pair{Filter::kCdf97, 3}}) {
    std::vector<double> x(n), scratch(n);
    for (size_t i = 0; i < n; ++i) x[i] = std::pow(double(i) * 0.1 - 1.0, degree) + 0.5;
    AnalysisStep1D(f, x.data(), n, 1, 1, scratch.data());
    for (size_t k = 3; k < n / 2 - 3; ++k) EXPECT_NEAR(x[n / 2 + k], 0.0, 1e-9) << FilterName(f) << " k=" << k;
  }
}

TEST(Wavelet, SingleStepsComposeToFull) {
  for (Filter f : kAll) {
    size_t w = 32, h = 16;
    auto x = Random<double>(w * h, 5);
    auto full = x;
    std::vector<double> scratch(ScratchSize(w, h, 1));
    Forward2D(f, full.data(), w, h, 1, 3, scratch.data());
    auto steps = x;
    auto sizes = BandSizes(w, h, 3);
    for (int l = 0; l < 3; ++l) AnalysisStep2D(f, steps.data(), w, 1, sizes[l].width, sizes[l].height, scratch.data());
    EXPECT_EQ(steps, full);
    // One inverse step takes depth 3 to depth 2.
    auto two = x;
    Forward2D(f, two.data(), w, h, 1, 2, scratch.data());
    SynthesisStep2D(f, steps.data(), w, 1, sizes[2].width, sizes[2].height, scratch.data());
    EXPECT_LE(RelError(steps, two), 1e-12);
  }
}

// LeGall 5/3 as two plain lifting passes over the natural-order signal (T.800 Annex F's
// reversible structure without rounding; whole-sample symmetric extension), then the
// even/odd split. The library computes the same values in one pass; every value is the
// same float expression, so the two must agree bit for bit.
std::vector<float> LeGallByPasses(std::vector<float> x, size_t n, size_t lanes, bool inverse) {
  auto at = [&](long long i) {  // mirror: -1 -> 1, n -> n - 2
    if (i < 0) i = -i;
    if (i >= static_cast<long long>(n)) i = 2 * (static_cast<long long>(n) - 1) - i;
    return static_cast<size_t>(i);
  };
  const size_t low = (n + 1) / 2;
  std::vector<float> nat(n * lanes);
  if (inverse) {
    for (size_t p = 0; p < n; ++p)
      for (size_t l = 0; l < lanes; ++l) nat[p * lanes + l] = x[((p & 1) ? low + p / 2 : p / 2) * lanes + l];
  } else {
    nat = x;
  }
  auto lift = [&](size_t parity, float c) {
    for (size_t p = parity; p < n; p += 2)
      for (size_t l = 0; l < lanes; ++l)
        nat[p * lanes + l] += c * (nat[at(static_cast<long long>(p) - 1) * lanes + l] +
                                   nat[at(static_cast<long long>(p) + 1) * lanes + l]);
  };
  if (inverse) {
    lift(0, -0.25f);
    lift(1, 0.5f);
    return nat;
  }
  lift(1, -0.5f);
  lift(0, 0.25f);
  std::vector<float> out(n * lanes);
  for (size_t p = 0; p < n; ++p)
    for (size_t l = 0; l < lanes; ++l) out[((p & 1) ? low + p / 2 : p / 2) * lanes + l] = nat[p * lanes + l];
  return out;
}

TEST(Biorthogonal, LeGallOnePassEqualsTheLiftingPassesBitForBit) {
  for (size_t lanes : {size_t(1), size_t(3), size_t(8), size_t(16), size_t(24)}) {
    for (size_t n = 2; n <= 19; ++n) {
      for (size_t pad : {size_t(0), size_t(5)}) {  // stride == lanes, and a strided signal
        const size_t stride = lanes + pad;
        auto x = Random<float>(n * lanes, static_cast<uint32_t>(100 * n + lanes));
        for (bool inverse : {false, true}) {
          std::vector<float> data(n * stride, -7.0f), scratch(n * lanes);
          for (size_t p = 0; p < n; ++p)
            for (size_t l = 0; l < lanes; ++l) data[p * stride + l] = x[p * lanes + l];
          if (inverse)
            SynthesisStep1D(Filter::kLeGall53, data.data(), n, stride, lanes, scratch.data());
          else
            AnalysisStep1D(Filter::kLeGall53, data.data(), n, stride, lanes, scratch.data());
          auto want = LeGallByPasses(x, n, lanes, inverse);
          for (size_t p = 0; p < n; ++p) {
            for (size_t l = 0; l < lanes; ++l)
              ASSERT_EQ(data[p * stride + l], want[p * lanes + l])
                  << (inverse ? "synthesis" : "analysis") << " n " << n << " lanes " << lanes << " stride " << stride
                  << " sample " << p << " lane " << l;
            for (size_t l = lanes; l < stride; ++l) ASSERT_EQ(data[p * stride + l], -7.0f) << "padding written";
          }
        }
      }
    }
  }
}

TEST(Wavelet, ParseAndCheckSize) {
  EXPECT_EQ(*ParseFilter("db1"), Filter::kHaar);
  EXPECT_FALSE(ParseFilter("db5").ok());
  EXPECT_FALSE(CheckSize(Filter::kDb2, 12, 16).ok());
  EXPECT_TRUE(CheckSize(Filter::kCdf97, 12, 17).ok());
  EXPECT_EQ(MaxDepth(1, 1), 0);
  EXPECT_EQ(MaxDepth(256, 256), 8);
  EXPECT_EQ(MaxDepth(5, 3), 3);
}

}  // namespace
}  // namespace ltb::wavelet
