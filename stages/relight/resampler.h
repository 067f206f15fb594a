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
// the source over the texel's solid angle (boundaries resolved per latitude band, about a
// fifth of the smallest texel high); Σ texel·Ω_texel equals SourcePower exactly (one global
// factor).
//
// Create reduces the source, area-correctly, to a working lat-long grid (working_width()
// columns × working_rows() rows, every row held as exact prefix sums) and precomputes, per
// latitude band, the column intervals where the band crosses each texel. Resample(α) then
// integrates the working grid rotated by α about +Z over those intervals: any α, no
// granularity; a rotation by k·2π/working_width() is exactly a shift of the working grid by
// k columns. Cost per frame: O(number of intervals) ≈ 50·R², independent of the source size.
class CubemapResampler {
 public:
  // Largest cubemap the resampler builds (its tables grow as R²: ~50 M intervals at 512).
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
  uint64_t bands() const { return bands_.size(); }
  uint64_t intervals() const { return run_start_.size(); }
  // Texels no band crossed (0 in practice); they take the working grid's value at their centre.
  uint64_t empty_texels() const { return empty_.size(); }
  // The exact solid angle of texel column f·R² + t·R + s.
  double TexelSolidAngle(uint64_t texel) const { return omega_[texel]; }

 private:
  // Create's steps (resampler.cpp): the working grid and its prefix sums (free functions
  // there), then BuildBands, then Normalise.
  static Result<CubemapResampler> CreateUnchecked(const EnvMap& env, uint64_t cube_res, const Progress& progress);
  // The latitude bands, `sub` per working row, with their column intervals; dsum[texel]
  // gathers the band solid angle over each texel.
  Status BuildBands(uint64_t sub, const std::string& path, const Progress& progress, std::vector<double>* dsum);
  // texel_scale_ from dsum, and the texels no band crossed (empty_).
  void Normalise(const std::vector<double>& dsum);

  struct Band {
    uint32_t row = 0;   // working row
    double weight = 0;  // solid angle per working column in this band
    uint64_t first_run = 0, run_count = 0;
  };
  struct EmptyTexel {
    uint64_t texel = 0;
    uint32_t row = 0;
    double column = 0;  // working column of the texel centre (unrotated)
  };

  uint64_t r_ = 0, ww_ = 0, hw_ = 0;
  // hw × (ww + 1) × 3 (+1 pad): Σ of the row's values before column i. Immutable, shared by copies.
  std::shared_ptr<const double[]> prefix_;
  std::vector<Band> bands_;
  std::vector<double> run_start_;    // working column where each interval starts, ascending per band
  std::vector<uint32_t> run_texel_;  // texel of each interval (until the next start; the last wraps)
  std::vector<double> texel_scale_;  // 1 / Σ band solid angle over the texel (1 for empty texels)
  std::vector<double> omega_;        // exact texel solid angles
  std::vector<EmptyTexel> empty_;
  double power_[3] = {0, 0, 0};
};

}  // namespace ltb::stages
