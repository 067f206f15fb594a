// The 2D Haar transform of a cube face in the layout the triple products index (Ng,
// Ramamoorthi, Hanrahan 2004; docs/TRIPLE.md): the visibility field of `sample --visibility`
// is stored in it, the triple products read it (stages/triple/haar_triple.h).
//
// The basis, on the unit square [0,1]² (the paper's Eq. 17–18): the scaling function Φ = 1,
// and at level l = 0 .. log2(R) − 1, square (i, j) (x offset i, y offset j, 0 ≤ i, j < 2^l),
// three wavelets Ψ_M^{lij}(x, y) = 2^l Ψ_M(2^l x − i, 2^l y − j), orthonormal, with the mother
// wavelets (qx, qy = the half of the unit square in x and y, 0 or 1):
//   Ψ_01 = +1 in the upper half (qy = 1), −1 in the lower (vertical differencing);
//   Ψ_10 = +1 in the right half (qx = 1), −1 in the left (horizontal differencing);
//   Ψ_11 = Ψ_01 · Ψ_10 (diagonal).
// A face of R × R pixels (R a power of two, pixel (x, y) at x + y·R, y growing with the
// coordinate y) is the piecewise-constant function with those values.
//
// Coefficient layout (HaarFace::c, R² values): c[0] the scaling coefficient; the wavelets of
// square (l, i, j) at 1 + 3·s + k, s = SquareIndex(l, i, j) = (4^l − 1)/3 + j·2^l + i, and
// k = 0, 1, 2 for the types 01, 10, 11.
#pragma once

#include <cstdint>
#include <span>
#include <vector>

namespace ltb::wavelet {

// Mother wavelet types, in coefficient order.
enum class HaarType : uint8_t { k01 = 0, k10 = 1, k11 = 2 };

// +1 or −1: the sign of the mother wavelet of `type` in quadrant (qx, qy).
inline int SignOfQuadrant(int type, int qx, int qy) {
  const int sy = qy != 0 ? 1 : -1, sx = qx != 0 ? 1 : -1;
  return type == 0 ? sy : type == 1 ? sx : sx * sy;
}

// Σ_M w[M]·sign(M, q) over the three wavelets of a square, for child quadrant q.
inline double SignedSum(const double* w, int qx, int qy) {
  return w[0] * SignOfQuadrant(0, qx, qy) + w[1] * SignOfQuadrant(1, qx, qy) + w[2] * SignOfQuadrant(2, qx, qy);
}

inline uint64_t SquareIndex(int level, uint64_t i, uint64_t j) {
  return ((uint64_t{1} << (2 * level)) - 1) / 3 + (j << level) + i;
}

// The Haar coefficients of a face (R × R values, R a power of two ≤ 2^15).
struct HaarFace {
  uint64_t res = 0;       // R
  std::vector<double> c;  // R² coefficients (layout above)
  static HaarFace Forward(std::span<const double> pixels, uint64_t res);
  // The pixel values back (for tests and previews).
  std::vector<double> Inverse() const;
};

// Rows of 6R² values (a cube's six R × R faces, ltbake's column order, docs/CUBEMAP.md)
// replaced by their per-face Haar coefficients, each face in HaarFace's layout.
void HaarRowsInPlace(float* rows, uint64_t count, uint64_t res);

}  // namespace ltb::wavelet
