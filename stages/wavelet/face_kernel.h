// The row-transform kernel: the full-depth 2D transform of one R×R cube face (one matrix
// row's face, row-major and contiguous), from a source to a destination face, with an
// orthonormal filter on a power-of-two R.
//
// It computes exactly what Forward2D(f, face, R, R, /*lanes=*/1, MaxDepth(R, R), ...)
// computes — the same products and sums in the same order (a row step then a column step
// per level, each output 0 + Σ_j tap_j · x_j in ascending j, no FMA contraction) — so its
// result is bit-identical to the generic path, lane by lane. What differs is the data
// movement: a level reads its input band once into an L1 scratch of row-step results
// (horizontal AVX2: even/odd deinterleave, periodic shifts by lane permutes), then the
// column step runs on whole band rows and writes the three detail quadrants straight to
// their Mallat positions in the destination; only the low band goes to a small scratch
// for the next level. Without AVX2 the same loops run in portable scalar code.
#pragma once

#include <cstddef>

#include "stages/wavelet/wavelet.h"

namespace ltb::wavelet {

// Largest face side the kernel takes (its per-row register arrays are sized for it).
inline constexpr size_t kMaxFaceRes = 1024;

// Whether ForwardFace handles (f, r): an orthonormal filter and a power of two
// 1 <= r <= kMaxFaceRes. Depends on nothing else, so callers can choose a path per call.
bool HasFaceKernel(Filter f, size_t r);

// Scratch floats ForwardFace needs for side r.
inline size_t FaceScratchSize(size_t r) { return r * r + 2 * (r / 2) * (r / 2); }

// dst = the Mallat-layout 2D transform of src to full depth (log2 r steps); both r × r,
// row-major. src == dst is allowed (in place); any other overlap is not.
// Precondition: HasFaceKernel(f, r).
void ForwardFace(Filter f, size_t r, const float* src, float* dst, float* scratch);
// The same on `count` consecutive faces (src + i·r², dst + i·r²), requesting the next
// faces' cache lines ahead: what the row-transform stage runs on a run of matrix rows.
void ForwardFaces(Filter f, size_t r, size_t count, const float* src, float* dst, float* scratch);

}  // namespace ltb::wavelet
