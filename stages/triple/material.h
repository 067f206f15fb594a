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

#include "format/progress.h"
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

// ρ̃ for `dir` (the normal or the reflection vector, unit) at the incident direction w (unit).
double BrdfValue(const Brdf& brdf, const glm::dvec3& dir, const glm::dvec3& w);

// ρ̃ for `dir` (the normal for Lambert, the reflection vector for Phong; unit length) on
// faces of R × R texels (R a power of two), solid-angle weighted as above, Haar-transformed.
CubeFaces MaterialFaces(const Brdf& brdf, const glm::dvec3& dir, uint64_t res);

// A function on the cube's texels (6R² values, ltbake's column order) Haar-transformed per
// face: lighting (radiance) or visibility.
CubeFaces CubeFunctionFaces(const double* values, uint64_t res);

// B = Σ over the six faces of LinearTripleProduct(L, V, ρ̃).
double CubeTripleProduct(const CubeFaces& l, const CubeFaces& v, const CubeFaces& rho);

}  // namespace ltb::triple

namespace ltb::triple {

// `ltbake material --brdf B -o mat.ltm --cube-res R` (docs/TRIPLE.md "The material field"):
// ρ̃ tabulated for every sampled direction — the texel centres of a cube of faces S × S: the
// normals n for Lambert, the reflection vectors ω_r for Phong — one row each, its 6R²
// columns the Haar coefficients of the six faces (face f's at f·R² + the HaarFace layout),
// non-linearly approximated: the largest coefficients holding `energy` of the row's Σc²
// are kept, the rest are zero. Rows layout, sparse(+zstd) chunks; resumable like a stage.
struct MaterialOptions {
  std::string output;
  Brdf brdf;
  uint64_t cube_res = 32;    // R, the lighting's cubemap
  uint64_t samples_res = 0;  // S; 0: 16 for Lambert, 32 for Phong
  double energy = 0.999;     // kept fraction of each row's energy (0, 1]
  int jobs = 2;
  bool overwrite = false;
};

struct MaterialResult {
  uint64_t rows = 0, cols = 0, samples_res = 0;
  uint64_t terms_kept = 0;       // nonzero coefficients stored
  double worst_energy_kept = 1;  // the smallest kept fraction over rows (≥ energy)
  uint64_t chunks_written = 0, chunks_already_committed = 0;
  uint64_t file_bytes = 0;
};

Result<MaterialResult> RunMaterial(const MaterialOptions& options, const Progress& progress);

}  // namespace ltb::triple
