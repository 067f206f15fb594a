// The material side of the triple product (Ng et al. 2004, §7.1.2; docs/TRIPLE.md): the
// BRDF times the incident cosine, in global coordinates, tabulated over ltbake's cubemap of
// incident directions (docs/CUBEMAP.md) and reparameterised so that it depends on one
// direction only: the normal n for Lambert (ρ̃ = albedo/π · max(0, n·ω)), the reflection
// vector ω_r for Phong (ρ̃ = ks·(s + 1)/(2π) · max(0, ω_r·ω)^s, the Phong shading lobe,
// normalised so that it integrates to ks over the sphere, as the paper uses it).
//
// Each texel's value carries the texel's exact solid angle times R² (the face's area in
// unit-square measure), so that the unit-square triple product of a face
// (LinearTripleProduct) is ∫ L V ρ̃ dω over that face's directions, and the sum over the
// six faces is the rendering integral B = ∫_S² L V ρ̃ dω.
#pragma once

#include <array>
#include <cstdint>
#include <glm/geometric.hpp>
#include <glm/vec3.hpp>
#include <string>

#include "format/status.h"
#include "stages/triple/haar_triple.h"

namespace ltb::triple {

struct Brdf {
  enum class Kind { kLambert, kPhong } kind = Kind::kLambert;
  double exponent = 0;  // Phong s
  double albedo = 1;    // Lambert albedo, Phong ks
};
// "lambert", "lambert:ALBEDO", "phong:S", "phong:S:KS".
Result<Brdf> ParseBrdf(const std::string& text);

using CubeFaces = std::array<HaarFace, 6>;

// ρ̃ for `dir` (the normal for Lambert, the reflection vector for Phong; unit length) on
// faces of R × R texels (R a power of two), solid-angle weighted as above, Haar-transformed.
CubeFaces MaterialFaces(const Brdf& brdf, const glm::dvec3& dir, uint64_t res);

// A function on the cube's texels (6R² values, ltbake's column order) Haar-transformed per
// face: lighting (radiance) or visibility.
CubeFaces CubeFunctionFaces(const double* values, uint64_t res);

// B = Σ over the six faces of LinearTripleProduct(L, V, ρ̃).
double CubeTripleProduct(const CubeFaces& l, const CubeFaces& v, const CubeFaces& rho);

}  // namespace ltb::triple
