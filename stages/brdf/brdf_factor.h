// The BRDF in-out factorisation (Liu et al. 2004, Wang et al. 2004; the sparse-precomputation
// paper §3 Eq. 2–3, the PBI thesis ch. 7.2): ρ(ω, ω_o)·cos θ ≈ Σ_{k<K} f_k(ω)·g_k(ω_o) in
// the surface's local frame (z = the normal), so that a vertex bake of K view-independent
// matrices T_k(x, ω) = V(x, ω)·f_k(ω in x's frame) relights any view as
// B(x, ω_o) = Σ_k g_k(ω_o in x's frame)·(T_k L)(x) (docs/GLOSSY.md).
//
// Both directions are tabulated on parabolic maps of the upper hemisphere (Liu et al. use
// them too): (u, v) in the unit disk ↔ ω = (2u, 2v, 1 − u² − v²)/(1 + u² + v²), with
// dω = 4/(1 + u² + v²)² du dv; a lookup is one division and a bilinear interpolation.
// The factors are the truncated SVD of the solid-angle-weighted table (the L2-optimal rank-K
// approximation of ρ·cos over both hemispheres).
#pragma once

#include <cstdint>
#include <glm/vec3.hpp>
#include <vector>

#include "format/status.h"

namespace ltb::brdf {

// A unit normal's tangent frame (t, b, n), the same function at bake and at render: any
// frame does for an isotropic BRDF, as long as both use it (Duff et al. 2017, branchless).
void TangentFrame(const glm::dvec3& n, glm::dvec3* t, glm::dvec3* b);

// Where a local direction falls on a parabolic map of res × res cells: the four cells'
// offset and the bilinear weights (directions below the horizon read the horizon).
struct ParabolicCoords {
  uint32_t i0 = 0, i1 = 0, j0 = 0, j1 = 0;
  double a = 0, b = 0;
  ParabolicCoords(uint32_t res, const glm::dvec3& w);
};

// A table over a parabolic map of the upper hemisphere: res × res cells of [-1, 1]², values
// at the cell centres.
struct ParabolicTable {
  uint32_t res = 0;
  std::vector<float> value;  // res × res, row v, column u
  // Bilinear at the local direction w (z up; need not be unit).
  double Lookup(const glm::dvec3& w) const { return At(ParabolicCoords(res, w)); }
  double At(const ParabolicCoords& c) const;
  // The cell centre's direction and its solid angle (0 for a centre outside the disk).
  static glm::dvec3 Direction(uint32_t res, uint32_t i, uint32_t j, double* solid_angle);
};

// The factorisation of one material's ρ·cos with K terms: term 0 is the diffuse part,
// exact (f_0 = albedo/π·cos, g_0 = 1: a K = 1 bake is the plain diffuse vertex bake), terms
// 1..K−1 the truncated SVD of the glossy part ks·lobe·cos. f holds f_k / cos θ (the
// incident factor without the cosine the sampler's ray weights already carry). error[k−1]
// is the relative L2 error of the K = k approximation of the whole ρ·cos over both
// hemispheres (solid-angle weighted), for k = 1..max(K, 8).
struct BrdfFactors {
  uint32_t terms = 0;
  std::vector<ParabolicTable> f, g;
  std::vector<double> error;
  // cos θ·Σ_k f_k(w)·g_k(wo), both local (0 for w below the horizon), for tests.
  double Eval(const glm::dvec3& w, const glm::dvec3& wo) const;
};

// The sampler's BRDF (docs/SAMPLE.md): albedo/π + ks·(n+2)/(2π)·max(0, r·ω)ⁿ, r the mirror
// of ω_o about z, times cos θ (0 below the horizon), in the local frame.
double PhongCos(double albedo, double ks, double exponent, const glm::dvec3& w, const glm::dvec3& wo);

// Factors PhongCos with `terms` terms, tabulated with incident_res² and view_res² parabolic
// cells; errors for ranks 1..max(terms, 8). A Lambertian material (ks = 0) is exactly rank
// one: f_0 = albedo/π·cos, g_0 = 1, the other terms 0.
Result<BrdfFactors> FactorPhong(double albedo, double ks, double exponent, uint32_t terms, uint32_t incident_res = 96,
                                uint32_t view_res = 32);

}  // namespace ltb::brdf
