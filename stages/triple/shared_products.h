// The shared evaluation of the triple products (docs/TRIPLE.md "The shared method"): every
// vertex's ρ̃ is a weighted sum of a few *sampled* rows of the material fields (bilinear or
// quadrilinear between sampled directions), and rows are far fewer than vertices. So per
// frame each sampled row s that some vertex uses is lit once — G_s = Haar(L ⊙ ρ̃_s), the
// product formed texel by texel (exact: both are constant on texels) and transformed face by
// face, only on the faces where ρ̃_s is non-zero — and every vertex using it takes the double
// product ⟨V, G_s⟩ over its visibility's non-zeros:
//
//     B(x) = Σ_parts w ∫ L V ρ̃_s = Σ_parts w Σ_j V_j (G_s)_j.
//
// It equals the linear method (§5.2) with the same lighting and BRDF terms up to rounding, at
// a cost of (rows lit × their faces × R²) + Σ_vertices (parts × V's non-zeros) a frame,
// whatever the number of terms. The renderer is stages/triple/render.cpp.
#pragma once

#include <cstdint>
#include <span>
#include <vector>

#include "format/progress.h"
#include "format/status.h"
#include "stages/triple/material_field.h"

namespace ltb::triple {

// Values per texel or coefficient in the lit rows: R, G, B and an unused fourth lane (zero),
// so the loops over lanes are one 4-wide vector operation.
inline constexpr int kLanes = 4;

// The 2D Haar transform of one face (HaarFace's layout) of kLanes interleaved lanes:
// `pixels` (R² × kLanes, x + y·R; overwritten: the means are coarsened in place) into `coef`
// (R² × kLanes). Equals HaarFace::Forward lane by lane up to rounding (T's). The renderer
// lights rows in float (twice the lanes a vector instruction holds; its sums stay double).
template <typename T>
void ForwardHaarLanes(T* pixels, int levels, T* coef);

// The inverse of one face of one lane: coefficients (R², HaarFace's layout) into pixel values
// (R²). Equals HaarFace::Inverse up to rounding (T's).
template <typename T>
void InverseHaarFace(const T* coef, int levels, T* pixels);

// The pixel values (6R² × kLanes, fourth lane zero) of three channels of Haar coefficients
// (each 6R², face by face): the lighting the shared method multiplies the rows by, scaled by
// 2^-exponent so that its largest magnitude is in [1, 2) — float then neither overflows for
// the brightest maps float32 holds nor loses the faint ones; B scales back exactly by 2^exponent.
std::vector<float> LightingLanes(const std::vector<double> (&coef)[3], uint64_t res, int* exponent);

// The vertices' ρ̃: vertex i (of the list passed with it) is the weighted rows
// parts[offset[i] .. offset[i + 1]).
struct VertexRho {
  std::vector<uint64_t> offset{0};
  std::vector<RhoPart> parts;
};

struct SharedStats {
  uint64_t rows_lit = 0;   // sampled rows lit this frame
  uint64_t faces_lit = 0;  // their faces transformed
};

// B of each vertex of `vertex_rows` (rows of `vis`, the visibility field in HaarFace's layout
// per face) into out (vertex_rows.size() × 3): Σ over its parts of weight × ⟨V, Haar(L ⊙
// ρ̃_row)⟩, with `light` from LightingLanes and each row cut to its scaling coefficients plus
// `brdf_terms` wavelets (the prefix MaterialField keeps them in; UINT64_MAX: every one).
// Every part's field must be one of `fields`. Rows are lit on `jobs` threads; the result does
// not depend on how many.
Status SharedTripleProducts(const SparseRows& vis, uint64_t res, std::span<const float> light,
                            std::span<const uint64_t> vertex_rows, const VertexRho& rho,
                            std::span<const MaterialField> fields, uint64_t brdf_terms, int jobs,
                            const Progress& progress, std::vector<double>* out, SharedStats* stats);

}  // namespace ltb::triple
