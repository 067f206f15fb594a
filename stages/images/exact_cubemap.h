// Exact texel averages of a cross, six-face or angular environment map at one rotation
// (docs/ENVMAPS.md "Exact texel averages"): each source pixel's solid angle is split among the
// cubemap texels it overlaps by clipping it against them. CubemapResampler goes through a
// working lat-long grid, exact for a lat-long source and fast at any rotation, but only
// within ~2% a texel for other layouts (a bright pixel is blurred by a working pixel across
// a texel edge); this is for what is resampled once: `convert env`, a single relit frame.
#pragma once

#include <cstdint>
#include <vector>

#include "format/progress.h"
#include "format/status.h"

namespace ltb::stages {

struct EnvMap;  // stages/images/envmap.h

// 6R² × 3 floats (texel-major, as CubemapResampler::Resample): texel t is
//   Σ_pixels L_p · Ω(p ∩ t) / Σ_pixels Ω(p ∩ t),
// with Ω(p ∩ t) the solid angle of the part of pixel p inside texel t, scaled by one global
// factor per channel so that Σ texel · Ω_texel equals the source's power, and clamped to the
// source's largest value (finite, non-negative for a non-negative map). What the source shows
// in direction d appears in direction Rz(rotation)·d.
//
// Cube faces (crosses, six faces): a pixel is bounded by great-circle arcs, as a texel is,
// so each part is an exact spherical polygon (its area from the triangle formula of
// Van Oosterom & Strackee): exact up to rounding at any rotation. Angular maps: pixel edges
// are straight in the map, not on the sphere; a pixel inside one texel goes whole, with its
// solid angle by Gauss–Legendre quadrature of π·sin(πr)/r; a pixel across a texel edge is
// split into m × m parts (1 ≤ m ≤ 16, of side ≤ √(1.4e-4·T) for the smallest texel side T),
// each taken as the spherical quadrilateral of its corners: their sides bow from great
// circles, an error falling as the square of the part's side, under 3e-4 a texel (measured
// in docs/ENVMAPS.md). Pixels across the disk's rim (the direction behind the probe) go by
// sub-sample centres.
//
// Layout kLatLong is refused (CubemapResampler is exact for it). Cost: O(source pixels) plus
// a clip for each pixel across a texel edge; a 2048² probe at R = 32 takes about a second.
Result<std::vector<float>> ExactCubemap(const EnvMap& env, uint64_t cube_res, double rotation,
                                        const Progress& progress = {});

}  // namespace ltb::stages
