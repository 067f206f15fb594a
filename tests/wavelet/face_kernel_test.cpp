// The row-transform face kernel (stages/wavelet/face_kernel.h) against the generic
// wavelet::Forward2D, per face, for every orthonormal filter and R = 1 .. 128, on random and
// special data: bit-identical to Forward2D<float> (its documented contract), within a
// tolerance derived from the arithmetic of Forward2D<double>, and perfectly reconstructed
// by Inverse2D. Then the row-block entry points of the stage: out of place = in place =
// per-face Forward2D, zero rows counted and written as zeros, and a row's result
// independent of the block it is in.
#include "stages/wavelet/face_kernel.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <random>
#include <string>
#include <vector>

#include "stages/row_transform/row_transform.h"
#include "stages/wavelet/wavelet.h"

namespace ltb::wavelet {
namespace {

const Filter kOrtho[] = {Filter::kHaar, Filter::kDb2, Filter::kDb3, Filter::kDb4};
const size_t kSides[] = {1, 2, 4, 8, 16, 32, 64, 128};

struct Case {
  std::string name;
  std::vector<float> face;
};

std::vector<Case> Cases(size_t r, uint32_t seed) {
  const size_t n = r * r;
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(-1, 1);
  std::vector<Case> out;
  auto add = [&](std::string name, auto gen) {
    Case c{std::move(name), std::vector<float>(n)};
    for (size_t i = 0; i < n; ++i) c.face[i] = gen(i);
    out.push_back(std::move(c));
  };
  add("random", [&](size_t) { return u(rng); });
  add("positive", [&](size_t) { return u(rng) * 0.5f + 0.5f; });  // like transport values
  add("zeros", [](size_t) { return 0.0f; });
  add("negative_zeros", [](size_t) { return -0.0f; });
  for (size_t at : {size_t(0), n / 2 + r / 3, n - 1}) {
    add("spike@" + std::to_string(at), [at](size_t i) { return i == at ? 1.0f : 0.0f; });
  }
  add("pm1e30", [&](size_t) { return u(rng) < 0 ? -1e30f : 1e30f; });
  add("wide_range", [&](size_t) { return u(rng) * std::ldexp(1.0f, static_cast<int>(rng() % 80) - 40); });
  add("subnormal", [&](size_t) { return u(rng) * std::numeric_limits<float>::denorm_min() * 1000.0f; });
  add("constant", [](size_t) { return 0.75f; });
  return out;
}

double MaxAbs(const std::vector<float>& v) {
  double m = 0;
  for (float x : v) m = std::max(m, std::fabs(double(x)));
  return m;
}

// Bound on |float result - exact result| for a full-depth transform of side r with F taps:
// every level is two passes of F-term sums, each term and partial sum rounded once (at most
// 2F roundings of eps/2 relative to the running magnitude, which is at most ‖lo‖₁ ×
// the pass's input magnitude), plus the error carried from the previous passes, amplified by
// ‖lo‖₁ per pass. Subnormal results round absolutely (2^-150 per operation).
double Tolerance(Filter f, size_t r, double max_abs) {
  auto taps = OrthoLowPass(f);
  double l1 = 0;
  for (double t : taps) l1 += std::fabs(t);
  const double eps = std::numeric_limits<float>::epsilon();
  const int passes = 2 * MaxDepth(r, r);
  double err = 0, mag = max_abs;
  for (int p = 0; p < passes; ++p) {
    mag *= l1;
    err = err * l1 + 2.0 * taps.size() * (eps / 2) * mag;
  }
  const double absolute = 4.0 * taps.size() * passes * std::ldexp(1.0, -149) * std::pow(l1, passes);
  return err + absolute;
}

TEST(FaceKernel, AppliesToOrthonormalPowerOfTwoSidesOnly) {
  for (Filter f : kOrtho) {
    for (size_t r : kSides) EXPECT_TRUE(HasFaceKernel(f, r)) << FilterName(f) << " " << r;
    EXPECT_FALSE(HasFaceKernel(f, 0));
    EXPECT_FALSE(HasFaceKernel(f, 12));
    EXPECT_FALSE(HasFaceKernel(f, 2 * kMaxFaceRes));
  }
  EXPECT_FALSE(HasFaceKernel(Filter::kLeGall53, 32));
  EXPECT_FALSE(HasFaceKernel(Filter::kCdf97, 32));
}

TEST(FaceKernel, MatchesForward2DPerFace) {
  for (Filter f : kOrtho) {
    for (size_t r : kSides) {
      const int depth = MaxDepth(r, r);
      std::vector<float> scratch(FaceScratchSize(r) + ScratchSize(r, r, 1));
      for (const Case& c : Cases(r, 11 + r)) {
        SCOPED_TRACE(std::string(FilterName(f)) + " R=" + std::to_string(r) + " " + c.name);
        // The generic path in float (the contract: bit-identical) and in double (the accuracy).
        std::vector<float> want = c.face;
        Forward2D(f, want.data(), r, r, 1, depth, scratch.data());
        std::vector<double> exact(c.face.begin(), c.face.end()), dscratch(r * r);
        Forward2D(f, exact.data(), r, r, 1, depth, dscratch.data());

        // Out of place, over garbage, to 32-, 16- and 4-byte aligned destination faces.
        std::vector<float> buffer(r * r + 16, 12345.0f);
        float* aligned = buffer.data() + (8 - (reinterpret_cast<uintptr_t>(buffer.data()) / 4) % 8) % 8;
        ForwardFace(f, r, c.face.data(), aligned, scratch.data());
        std::vector<float> got(aligned, aligned + r * r);
        for (size_t offset : {4, 1}) {
          ForwardFace(f, r, c.face.data(), aligned + offset, scratch.data());
          EXPECT_EQ(0, std::memcmp(aligned + offset, got.data(), r * r * sizeof(float))) << "offset " << offset;
        }
        std::vector<float> in_place = c.face;
        ForwardFace(f, r, in_place.data(), in_place.data(), scratch.data());

        EXPECT_EQ(0, std::memcmp(got.data(), want.data(), r * r * sizeof(float))) << "not bit-identical to Forward2D";
        EXPECT_EQ(0, std::memcmp(in_place.data(), got.data(), r * r * sizeof(float))) << "in place differs";
        const double tol = Tolerance(f, r, MaxAbs(c.face));
        double worst = 0;
        size_t worst_at = 0;
        for (size_t i = 0; i < r * r; ++i) {
          const double e = std::fabs(double(got[i]) - exact[i]);
          if (!(e <= worst)) worst = e, worst_at = i;
        }
        EXPECT_LE(worst, tol) << "at " << worst_at << ": " << got[worst_at] << " vs " << exact[worst_at];

        // Perfect reconstruction (orthonormal: the inverse is the transpose).
        std::vector<float> back = got;
        Inverse2D(f, back.data(), r, r, 1, depth, scratch.data());
        double rec = 0;
        for (size_t i = 0; i < r * r; ++i) rec = std::max(rec, std::fabs(double(back[i]) - double(c.face[i])));
        EXPECT_LE(rec, 2 * tol + 2 * Tolerance(f, r, MaxAbs(got))) << "reconstruction";
      }
    }
  }
}

}  // namespace
}  // namespace ltb::wavelet

namespace ltb::stages {
namespace {

std::vector<float> RandomRows(size_t rows, size_t cols, uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(-1, 1);
  std::vector<float> v(rows * cols);
  for (auto& x : v) x = u(rng);
  return v;
}

TEST(TransformRows, OutOfPlaceEqualsInPlaceEqualsPerFaceForward2D) {
  for (auto f : {wavelet::Filter::kHaar, wavelet::Filter::kDb2, wavelet::Filter::kDb3, wavelet::Filter::kDb4}) {
    for (size_t r : {1, 2, 4, 8, 16, 32}) {
      SCOPED_TRACE(std::string(wavelet::FilterName(f)) + " R=" + std::to_string(r));
      const size_t cols = 6 * r * r, rows = 21;
      auto src = RandomRows(rows, cols, 5);
      for (size_t zero : {size_t(0), size_t(7), size_t(20)}) std::fill_n(src.begin() + zero * cols, cols, 0.0f);
      std::vector<float> scratch(RowBlockScratchSize(r));
      std::vector<float> dst(rows * cols, -7.0f);
      uint64_t zeros = 0;
      TransformRows(f, r, src.data(), dst.data(), rows, scratch.data(), &zeros);
      EXPECT_EQ(zeros, 3u);
      std::vector<float> in_place = src;
      uint64_t zeros2 = 0;
      TransformRowBlock(f, r, in_place.data(), rows, scratch.data(), &zeros2);
      EXPECT_EQ(zeros2, 3u);
      EXPECT_EQ(0, std::memcmp(dst.data(), in_place.data(), dst.size() * sizeof(float)));

      std::vector<float> want = src, ws(wavelet::ScratchSize(r, r, 1));
      for (size_t face = 0; face < 6 * rows; ++face) {
        wavelet::Forward2D(f, want.data() + face * r * r, r, r, 1, wavelet::MaxDepth(r, r), ws.data());
      }
      EXPECT_EQ(0, std::memcmp(dst.data(), want.data(), dst.size() * sizeof(float)));
      for (size_t zero : {size_t(0), size_t(7), size_t(20)}) {
        for (size_t c = 0; c < cols; ++c) ASSERT_EQ(dst[zero * cols + c], 0.0f) << "zero row " << zero;
      }
      // A row's result does not depend on the block it is in: one row at a time.
      std::vector<float> single(rows * cols);
      uint64_t zeros3 = 0;
      for (size_t i = 0; i < rows; ++i) {
        TransformRows(f, r, src.data() + i * cols, single.data() + i * cols, 1, scratch.data(), &zeros3);
      }
      EXPECT_EQ(zeros3, 3u);
      EXPECT_EQ(0, std::memcmp(dst.data(), single.data(), dst.size() * sizeof(float)));
    }
  }
}

TEST(TransformRows, GenericPathForOtherFiltersAndSides) {
  // legall53 on R = 3 has no face kernel: the lanes path, still out of place.
  const size_t r = 3, cols = 6 * r * r, rows = 17;
  auto src = RandomRows(rows, cols, 9);
  std::vector<float> scratch(RowBlockScratchSize(r)), dst(rows * cols);
  uint64_t zeros = 0;
  TransformRows(wavelet::Filter::kLeGall53, r, src.data(), dst.data(), rows, scratch.data(), &zeros);
  std::vector<float> want = src, ws(wavelet::ScratchSize(r, r, 1));
  for (size_t face = 0; face < 6 * rows; ++face) {
    wavelet::Forward2D(wavelet::Filter::kLeGall53, want.data() + face * r * r, r, r, 1, wavelet::MaxDepth(r, r),
                       ws.data());
  }
  EXPECT_EQ(0, std::memcmp(dst.data(), want.data(), dst.size() * sizeof(float)));
}

}  // namespace
}  // namespace ltb::stages
