// Area-correct resampling of an environment map (stages/relight/envmap.h) to ltbake's
// cubemap (docs/CUBEMAP.md), rotated about +Z, for relighting (docs/ENVMAPS.md).
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "format/progress.h"
#include "format/status.h"

namespace ltb::stages {

struct EnvMap;  // stages/relight/envmap.h

// Area-correct resampling of an environment map to a cubemap with R×R faces: 6R² texels ×
// 3 floats (texel-major, out[(f·R² + t·R + s)·3 + c]) of radiance, each texel the average of
// the working grid over the texel's solid angle; Σ texel·Ω_texel equals SourcePower exactly
// (one global factor).
//
// Create reduces the source, area-correctly, to a working lat-long grid (working_width()
// columns × working_rows() rows, every row held as exact prefix sums) and cuts every texel
// edge (a great-circle arc) into pieces, one or more per working row it crosses. Resample(α)
// integrates the working grid rotated by α about +Z over each texel by Green's theorem:
// ∫∫_texel L dω = ∮ S dz (S a row's prefix function, z = cos θ) along the texel's edges, each
// piece exact up to a cubic Hermite fit of the edge's shape (docs/ENVMAPS.md: within 1e-5 of a
// working pixel per column the piece crosses). Any α, no granularity; a rotation by
// k·2π/working_width() is exactly a shift of the working grid by k columns. Cost per frame:
// O(pieces + the columns they cross) ≈ 150·R² at R = 32, independent of the source size.
class CubemapResampler {
 public:
  // Largest cubemap the resampler builds (its tables grow as R²: 381 MB peak for a 1024 × 512
  // map at 512).
  static constexpr uint64_t kMaxCubeRes = 512;

  // cube_res: 1..512. `progress` is polled for cancellation (a Cancelled status).
  static Result<CubemapResampler> Create(const EnvMap& env, uint64_t cube_res, const Progress& progress = {});

  // rotation: radians about +Z (counter-clockwise seen from above): what the source shows
  // in direction d appears in direction Rz(rotation)·d. `out` holds 6R²·3 floats.
  // Thread-safe (const; scratch is per thread).
  void Resample(double rotation, float* out) const;
  // Σ radiance × solid angle of the source (a piecewise-constant function on the sphere).
  double SourcePower(int channel) const { return power_[channel]; }

  uint64_t cube_res() const { return r_; }
  uint64_t working_width() const { return ww_; }
  uint64_t working_rows() const { return hw_; }
  // Pieces of texel edges (one or more per edge and working row it crosses).
  uint64_t pieces() const { return pieces_.size(); }
  // Texels no piece bounds (none in practice); they take the working grid's value at their centre.
  uint64_t empty_texels() const { return empty_.size(); }
  // The exact solid angle of texel column f·R² + t·R + s.
  double TexelSolidAngle(uint64_t texel) const { return omega_[texel]; }

 private:
  // Create's steps (resampler.cpp): the working grid and its prefix sums (free functions
  // there), then BuildPieces, then Normalise.
  static Result<CubemapResampler> CreateUnchecked(const EnvMap& env, uint64_t cube_res, const Progress& progress);
  // The texel edges cut into pieces per working row, and the seam terms; dsum[texel] gathers
  // each texel's solid angle as the pieces see it.
  Status BuildPieces(const std::string& path, const Progress& progress, std::vector<double>* dsum);
  // texel_scale_ from dsum, and the texels no piece bounds (empty_).
  void Normalise(const std::vector<double>& dsum);

  // A piece of a texel edge inside one working row, traversed towards increasing column c
  // (a piece along a meridian: towards increasing z). With S the row's prefix function, the
  // rotation shift s, and K(t) = ∫_0^t (z(c + w) − z(c + τ)) dτ along the edge,
  //   V = ∫ S dz = dz·S(c + s) + Σ_columns L·ΔK      (× 2π/ww, folded into dz and K)
  // is added to the texel above it (left of a meridian piece) and subtracted from the one
  // below (Green's theorem). K is the cubic with K(0) = 0, K'(0) = dz, K'(w) = 0, K(w) = kw.
  struct Piece {
    double c = 0;   // working column where it starts, in [kSeamColumn, kSeamColumn + ww) (resampler.cpp)
    double dz = 0;  // (z at its end − z at its start) · 2π/ww
    float w = 0;    // width in working columns (0 along a meridian)
    float kw = 0;   // K(w)
    uint32_t up = 0, down = 0;
  };
  // A texel holding the seam meridian (c = kSeamColumn) over part of a row: it spans the row's whole
  // circle there, + (row total) · weight.
  struct SeamTerm {
    uint32_t row = 0, texel = 0;
    double weight = 0;  // Δz · 2π/ww
  };
  struct EmptyTexel {
    uint64_t texel = 0;
    uint32_t row = 0;
    double column = 0;  // working column of the texel centre (unrotated)
  };

  uint64_t r_ = 0, ww_ = 0, hw_ = 0;
  // hw × (ww + 1) × 3 (+1 pad): Σ of the row's values before column i. Immutable, shared by copies.
  std::shared_ptr<const double[]> prefix_;
  std::vector<Piece> pieces_;        // by working row, then column
  std::vector<uint64_t> row_first_;  // hw + 1: row J's pieces are [row_first_[J], row_first_[J + 1])
  std::vector<SeamTerm> seam_;
  std::vector<double> texel_scale_;  // 1 / the texel's solid angle as the pieces see it (1 for empty texels)
  std::vector<double> omega_;        // exact texel solid angles
  std::vector<EmptyTexel> empty_;
  double power_[3] = {0, 0, 0};
};

}  // namespace ltb::stages
