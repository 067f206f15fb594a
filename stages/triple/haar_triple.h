// Triple product integrals in the 2D Haar basis (Ng, Ramamoorthi, Hanrahan 2004, §4.5 and
// §5; docs/TRIPLE.md): ∫ L·V·ρ over a square domain from the Haar coefficients of the three
// functions, exactly in time linear in the number of coefficients (parent sums by dynamic
// programming, §5.2), or estimated from non-linear approximations of L and ρ in time
// proportional to the terms kept (lazy parent sums, §5.3). The relighting path of issue 22
// evaluates it per vertex and cube face; this is the math, with no files.
//
// The basis and the coefficient layout of a face: stages/wavelet/haar_face.h.
#pragma once

#include <cstdint>
#include <span>
#include <vector>

#include "stages/wavelet/haar_face.h"

namespace ltb::triple {

// The face transform (stages/wavelet/haar_face.h), which the tripling coefficients index.
using wavelet::HaarFace;
using wavelet::HaarRowsInPlace;
using wavelet::HaarType;
using wavelet::SignedSum;
using wavelet::SignOfQuadrant;
using wavelet::SquareIndex;

// One basis function: the scaling function (level = −1), or wavelet `type` of square
// (level, i, j).
struct HaarBasis {
  int level = -1;
  uint64_t i = 0, j = 0;
  int type = 0;
};
// The basis function of coefficient index `index` (< R²) of a face of side R.
HaarBasis BasisOf(uint64_t index);
// Its coefficient index.
uint64_t IndexOf(const HaarBasis& b);

// The tripling coefficient C_uvw = ∫ Ψ_u Ψ_v Ψ_w over the unit square, from the Haar
// tripling coefficient theorem (§4.5.2): 1 for three scaling functions; 2^l for three
// different types in one square of level l; ±2^l for two identical wavelets and a third
// function — the scaling function (l = 0, +1) or a wavelet of a strictly coarser square
// containing theirs (its level l, the sign of its type in the quadrant holding them); else 0.
double TriplingCoefficient(const HaarBasis& u, const HaarBasis& v, const HaarBasis& w);

// ∫ L·V·ρ over the unit square in the pixel basis: Σ_p L_p V_p ρ_p / R² (the reference).
double PixelTripleProduct(std::span<const double> l, std::span<const double> v, std::span<const double> rho);

// Parent sums of every square of a face (R = 2^levels), by dynamic programming: P[root] =
// the scaling coefficient, a square's = its parent's + 2^(parent level) × the parent's
// wavelets signed for its quadrant. (4^levels − 1)/3 values, SquareIndex order.
void ParentSums(const double* coef, int levels, std::vector<double>* out);

// The parent sum of square (level, i, j) from the coefficients alone, walking its ancestors
// (O(level)); at level = log2 R it is the value of pixel (i, j). `coef` is any indexable
// (double or float array).
template <typename T>
double ParentSumAt(const T* coef, int level, uint64_t i, uint64_t j) {
  double p = coef[0];
  for (int a = 0; a < level; ++a) {
    const int shift = level - a;
    const T* w = coef + 1 + 3 * SquareIndex(a, i >> shift, j >> shift);
    const int qx = static_cast<int>((i >> (shift - 1)) & 1), qy = static_cast<int>((j >> (shift - 1)) & 1);
    const double sy = qy ? 1.0 : -1.0, sx = qx ? 1.0 : -1.0;
    p += static_cast<double>(uint64_t{1} << a) * (sy * w[0] + sx * w[1] + sx * sy * w[2]);
  }
  return p;
}

// LinearTripleProduct's sum from dense coefficient arrays (R² each, HaarFace layout) and
// their parent sums (ParentSums), for callers that reuse parent sums across products.
double LinearTripleProductDense(const double* l, const double* pl, const double* v, const double* pv, const double* rho,
                                const double* pr, int levels);

// The exact integral from the three faces' coefficients, O(R²): case 1, case 2 per square
// and case 3 per wavelet with parent sums filled by dynamic programming (§5.2).
double LinearTripleProduct(const HaarFace& l, const HaarFace& v, const HaarFace& rho);

// The indices of the `n` largest coefficients by magnitude (the scaling coefficient always
// among them when n ≥ 1), ascending: a non-linear approximation.
std::vector<uint32_t> LargestTerms(const HaarFace& f, uint64_t n);

// The estimate of §5.3 from the non-linear approximations `l_terms` of L and `rho_terms`
// of ρ (coefficient indices, any order; ρ's scaling coefficient is always used; V, and L
// inside the case-2 terms and the parent sums, exact):
// case 1, case 2 over the squares of ρ's terms, case 3 over ρ's wavelets (with V's and L's
// parent sums) and over L's wavelets (with ρ's parent sum). Parent sums are computed lazily,
// only for the squares asked for. With every index in both lists it equals
// LinearTripleProduct up to rounding. This version allocates O(R²) scratch per call (the
// arithmetic is proportional to the terms); a per-vertex renderer keeps it between calls.
double SublinearTripleProduct(const HaarFace& l, const HaarFace& v, const HaarFace& rho,
                              std::span<const uint32_t> l_terms, std::span<const uint32_t> rho_terms);

}  // namespace ltb::triple
