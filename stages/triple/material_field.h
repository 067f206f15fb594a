// Reading a material field (`ltbake material`, docs/TRIPLE.md) for the triple-product
// renderer: its rows of sparse Haar coefficients, ordered so that a row's N-term
// approximation is a prefix of it, and ρ̃ interpolated between its sampled directions.
// The writer is stages/triple/material.cpp.
#pragma once

#include <cstdint>
#include <glm/vec3.hpp>
#include <string>
#include <vector>

#include "format/io/container_reader.h"
#include "format/status.h"
#include "stages/triple/material.h"

namespace ltb::triple {

// ∫|Ψ| of the basis function of coefficient `index` of a face: 1 for the scaling function,
// 2^-l for a wavelet of level l. Terms are ranked by |coefficient| × ∫|Ψ|, a bound on what
// dropping them costs: |∫ c Ψ g| ≤ |c| ∫|Ψ| max|g| for the rest of the integrand g (measured
// on the dragon benchmark: 30% less error than plain magnitude at 0.5% of the lighting terms).
double L1Norm(uint64_t index);

// Rows of sparse Haar coefficients in memory: row r's entries are [offset[r], offset[r+1]).
struct SparseRows {
  uint64_t rows = 0, cols = 0;
  std::vector<uint64_t> offset{0};
  std::vector<uint32_t> col;
  std::vector<float> val;
};

// Reads a rows-layout f32 matrix as sparse rows, chunk by chunk (ContainerReader::ReadSparse:
// sparse chunks are never densified).
Status ReadSparseRows(const io::ContainerReader& in, SparseRows* out);

// A material field (ltbake material): its BRDF, the sampled directions' cube S, and per row
// the face scaling coefficients first, then the wavelets by decreasing |c|·∫|Ψ| (L1Norm), so
// that the N-term approximation of a row is a prefix of it.
struct MaterialField {
  std::string path;
  Brdf brdf;
  uint32_t sres = 0;
  uint32_t nres = 0;  // the normals' cube, for the two-direction BRDFs
  SparseRows rows;
  std::vector<uint32_t> scaling;  // per row: how many of its leading entries are scaling coefficients
};

// The field at `path`, checked against the visibility field's cube resolution `res`.
Result<MaterialField> LoadMaterialField(const std::string& path, uint64_t res);

// One sampled row of a field with its interpolation weight × the material's scale.
struct RhoPart {
  const MaterialField* field;
  uint64_t row;
  double weight;
};

// The four texel centres of a cube of faces `res` × `res` nearest `dir` (bilinear on the
// face `dir` falls in, clamped at the face's edges): their indices and weights. False for a
// direction that is not one (zero or not finite: a vertex without faces, or seen from its
// own position), which then reflects nothing.
bool Bilinear(const glm::dvec3& dir, uint32_t res, uint64_t index[4], double weight[4]);

// ρ̃ of the field at (n, ω_r), scaled by `scale` (the material's albedo or ks over the
// field's): bilinear between the four nearest sampled directions for a one-direction BRDF,
// quadrilinear between the 16 nearest (normal, reflection vector) pairs for a two-direction
// one (§7.2). Appends the parts to `out`.
void Interpolate(const MaterialField& f, const glm::dvec3& n, const glm::dvec3& wr, double scale,
                 std::vector<RhoPart>* out);

}  // namespace ltb::triple
