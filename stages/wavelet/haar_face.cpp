#include "stages/wavelet/haar_face.h"

#include <algorithm>
#include <bit>
#include <cmath>

namespace ltb::wavelet {
namespace {

int Log2(uint64_t r) { return std::countr_zero(r); }  // R is a power of two

}  // namespace

HaarFace HaarFace::Forward(std::span<const double> pixels, uint64_t res) {
  HaarFace f;
  f.res = res;
  f.c.assign(res * res, 0.0);
  const int n = Log2(res);
  // Means of the squares of level l + 1, coarsened one level per pass.
  std::vector<double> mean(pixels.begin(), pixels.end()), coarse;
  for (int l = n - 1; l >= 0; --l) {
    const uint64_t side = uint64_t{1} << l, fine = side * 2;
    coarse.assign(side * side, 0.0);
    const double scale = std::ldexp(1.0, -l - 2);
    for (uint64_t j = 0; j < side; ++j) {
      for (uint64_t i = 0; i < side; ++i) {
        double q[2][2];  // [qy][qx]
        for (int qy = 0; qy < 2; ++qy)
          for (int qx = 0; qx < 2; ++qx) q[qy][qx] = mean[(2 * j + qy) * fine + 2 * i + qx];
        double* w = &f.c[1 + 3 * SquareIndex(l, i, j)];
        for (int t = 0; t < 3; ++t) {
          double s = 0;
          for (int qy = 0; qy < 2; ++qy)
            for (int qx = 0; qx < 2; ++qx) s += SignOfQuadrant(t, qx, qy) * q[qy][qx];
          w[t] = scale * s;
        }
        coarse[j * side + i] = 0.25 * (q[0][0] + q[0][1] + q[1][0] + q[1][1]);
      }
    }
    mean.swap(coarse);
  }
  f.c[0] = mean[0];
  return f;
}

std::vector<double> HaarFace::Inverse() const {
  const int n = Log2(res);
  std::vector<double> mean = {c[0]}, fine;
  for (int l = 0; l < n; ++l) {
    const uint64_t side = uint64_t{1} << l, fs = side * 2;
    fine.assign(fs * fs, 0.0);
    const double scale = std::ldexp(1.0, l);
    for (uint64_t j = 0; j < side; ++j) {
      for (uint64_t i = 0; i < side; ++i) {
        const double* w = &c[1 + 3 * SquareIndex(l, i, j)];
        for (int qy = 0; qy < 2; ++qy)
          for (int qx = 0; qx < 2; ++qx)
            fine[(2 * j + qy) * fs + 2 * i + qx] = mean[j * side + i] + scale * SignedSum(w, qx, qy);
      }
    }
    mean.swap(fine);
  }
  return mean;
}

void HaarRowsInPlace(float* rows, uint64_t count, uint64_t res) {
  const uint64_t face = res * res;
  std::vector<double> pixels(face);
  for (uint64_t r = 0; r < count; ++r) {
    for (uint64_t f = 0; f < 6; ++f) {
      float* x = rows + (r * 6 + f) * face;
      std::copy(x, x + face, pixels.begin());
      const HaarFace h = HaarFace::Forward(pixels, res);
      for (uint64_t k = 0; k < face; ++k) x[k] = static_cast<float>(h.c[k]);
    }
  }
}

}  // namespace ltb::wavelet
