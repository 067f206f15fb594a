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
#include <vector>

#include "format/progress.h"
#include "format/status.h"
#include "stages/brdf/brdf.h"
#include "stages/triple/haar_triple.h"

namespace ltb::triple {

// The BRDF model (stages/brdf): one Brdf for the triple products, the material stage and
// the recipes.
using brdf::Brdf;
using brdf::BrdfKindName;
using brdf::BrdfSpec;
using brdf::BrdfValue;
using brdf::ParseBrdf;

using CubeFaces = std::array<HaarFace, 6>;

// The texel centres of a cube of faces R × R (ltbake's column order) and their solid angles × R².
struct TexelTable {
  explicit TexelTable(uint64_t res);
  uint64_t res;
  std::vector<glm::dvec3> centre;
  std::vector<double> weight;
};

// ρ̃ for (n, wr) on faces of R × R texels (R a power of two), solid-angle weighted as above,
// Haar-transformed.
CubeFaces MaterialFaces(const Brdf& brdf, const glm::dvec3& n, const glm::dvec3& wr, const TexelTable& texels);
CubeFaces MaterialFaces(const Brdf& brdf, const glm::dvec3& n, const glm::dvec3& wr, uint64_t res);
// The one-direction BRDFs: `dir` is the normal (Lambert) or the reflection vector (Phong).
inline CubeFaces MaterialFaces(const Brdf& brdf, const glm::dvec3& dir, uint64_t res) {
  return MaterialFaces(brdf, dir, dir, res);
}

// A function on the cube's texels (6R² values, ltbake's column order) Haar-transformed per
// face: lighting (radiance) or visibility.
CubeFaces CubeFunctionFaces(const double* values, uint64_t res);

// B = Σ over the six faces of LinearTripleProduct(L, V, ρ̃).
double CubeTripleProduct(const CubeFaces& l, const CubeFaces& v, const CubeFaces& rho);

}  // namespace ltb::triple

namespace ltb::triple {

// `ltbake material --brdf B -o mat.ltm --cube-res R` (docs/TRIPLE.md "The material field"):
// ρ̃ tabulated for every sampled direction — the texel centres of a cube of faces S × S: the
// normals n for Lambert, the reflection vectors ω_r for Phong; for the two-direction BRDFs
// every pair of a normal (a cube of faces N × N) and a reflection vector, row
// n_index·6S² + ω_r_index — one row each, its 6R²
// columns the Haar coefficients of the six faces (face f's at f·R² + the HaarFace layout),
// non-linearly approximated: the largest coefficients holding `energy` of the row's Σc²
// are kept, the rest are zero. Rows layout, sparse(+zstd) chunks; resumable like a stage.
struct MaterialOptions {
  std::string output;
  Brdf brdf;
  uint64_t cube_res = 32;    // R, the lighting's cubemap
  uint64_t samples_res = 0;  // S; 0: 16 for Lambert, 32 for Phong, 16 for the two-direction BRDFs
  uint64_t normals_res = 0;  // N, two-direction BRDFs only; 0: 4
  double energy = 0.9999;    // kept fraction of each row's energy (0, 1]
  int jobs = 2;
  bool overwrite = false;
};

struct MaterialResult {
  uint64_t rows = 0, cols = 0, samples_res = 0, normals_res = 0;
  uint64_t terms_kept = 0;       // nonzero coefficients stored
  double worst_energy_kept = 1;  // the smallest kept fraction over rows (≥ energy)
  uint64_t chunks_written = 0, chunks_already_committed = 0;
  uint64_t file_bytes = 0;
};

Result<MaterialResult> RunMaterial(const MaterialOptions& options, const Progress& progress);

}  // namespace ltb::triple
