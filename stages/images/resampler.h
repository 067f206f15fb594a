// Area-correct resampling of an environment map (stages/images/envmap.h) to ltbake's
// cubemap (docs/CUBEMAP.md), rotated about +Z, for relighting (docs/ENVMAPS.md).
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "format/progress.h"
#include "format/status.h"

namespace ltb::stages {

struct EnvMap;  // stages/images/envmap.h

// Area-correct resampling of an environment map to a cubemap with R×R faces: 6R² texels ×
// 3 floats (texel-major, out[(f·R² + t·R + s)·3 + c]) of radiance, each texel the average of
// the working grid over the texel's solid angle; Σ texel·Ω_texel equals SourcePower exactly
// (one global factor).
//
// Create reduces the source, area-correctly, to a working lat-long grid (working_width()
// columns × working_rows() rows of radiance), cuts every texel edge (a great-circle arc) into
// pieces, one or more per working row it crosses, and gathers each texel's part of each row (a
// *band*): the columns it covers and the pieces that bound it above and below. Resample(α)
// integrates the working grid rotated by α about +Z over each band: with z = cos θ, dω = dz·dφ,
// so a band's integral is Σ_columns L·(the band's area in the column), and that area is the
// column's width × the row's height less the parts above the band's top pieces and below its
// bottom pieces, each exact up to a cubic Hermite fit of the piece's shape (docs/ENVMAPS.md:
// within 1e-5 of a working pixel per column the piece crosses). Every term is a radiance times
// a non-negative area, so a non-negative map gives non-negative texels by construction, and a
// texel's value depends on the columns it covers only (no prefix sums: a bright pixel elsewhere
// in the row cannot cancel into it). Any α, no granularity; a rotation by k·2π/working_width()
// is exactly a shift of the working grid by k columns. Cost per frame: O(the columns the bands
// cover + the columns the pieces cross) ≈ 1.2 × the working grid's pixels + 80·R².
class CubemapResampler {
 public:
  // Largest cubemap the resampler builds (its tables grow as R²).
  static constexpr uint64_t kMaxCubeRes = 512;

  // cube_res: 1..512. `progress` is polled for cancellation (a Cancelled status).
  static Result<CubemapResampler> Create(const EnvMap& env, uint64_t cube_res, const Progress& progress = {});

  // rotation: radians about +Z (counter-clockwise seen from above): what the source shows
  // in direction d appears in direction Rz(rotation)·d. `out` holds 6R²·3 floats, each finite,
  // non-negative and at most the working grid's largest value of its channel (a texel is an
  // average of it: a map near float32's largest value stays finite). A non-finite rotation
  // is taken as 0. Thread-safe (const; scratch is per thread). On `jobs` threads (each its own
  // texels, every texel's bands in the same order): the same bits for any jobs.
  void Resample(double rotation, float* out, int jobs = 1) const;
  // Σ radiance × solid angle of the source (a piecewise-constant function on the sphere).
  double SourcePower(int channel) const { return power_[channel]; }

  uint64_t cube_res() const { return r_; }
  uint64_t working_width() const { return ww_; }
  uint64_t working_rows() const { return hw_; }
  // Pieces of texel edges (one or more per edge and working row it crosses).
  uint64_t pieces() const { return pieces_; }
  // Bands: a texel's part of one working row.
  uint64_t bands() const { return bands_.size(); }
  // Texels no piece bounds (none in practice); they take the working grid's value at their centre.
  uint64_t empty_texels() const { return empty_.size(); }
  // The exact solid angle of texel column f·R² + t·R + s.
  double TexelSolidAngle(uint64_t texel) const { return omega_[texel]; }
  // max over texels of |(the texel's solid angle as its bands see it) / (the exact one) − 1|:
  // how well the bands tile the sphere (the geometry alone; docs/ENVMAPS.md).
  double SolidAngleError() const { return solid_angle_error_; }

 private:
  // Create's steps (resampler.cpp): the working grid (free functions there), the pieces of
  // the texel edges (CutTexelEdges there), then BuildBands and Normalise.
  static Result<CubemapResampler> CreateUnchecked(const EnvMap& env, uint64_t cube_res, const Progress& progress);
  struct RawPiece;
  struct SeamCell;
  // The texel edges cut into pieces (each inside one row; resampler.cpp), and the seam's cells.
  static Status CutTexelEdges(uint64_t R, uint64_t ww, uint64_t hw, const std::string& path, const Progress& progress,
                              const std::vector<double>& zrow, std::vector<RawPiece>* pieces,
                              std::vector<SeamCell>* seam);
  // The bands from the pieces (and the cells of the seam meridian, for bands no piece bounds),
  // both sorted by row.
  Status BuildBands(const std::string& path, const Progress& progress, const std::vector<double>& zrow,
                    const std::vector<RawPiece>& pieces, const std::vector<SeamCell>& seam);
  // texel_scale_ from the bands' solid angles, and the texels no piece bounds (empty_).
  void Normalise();
  // acc[texel·4 + c] += Σ over the texel's bands of Σ_columns L·area, the working grid rotated
  // by `shift` columns; values == nullptr: a map of ones (every lane gets the area). `acc` is
  // 32-byte aligned (4 doubles a texel).
  // Only the bands of texels t with t % parts == part (a thread's share; 0 of 1: every band).
  void Integrate(double shift, const double* values, double* acc, uint32_t part = 0, uint32_t parts = 1) const;

  // A texel's part of one working row. Its columns are in a coordinate of its own, lifted so
  // that the band is contiguous: spans and edges lie in [spans.front().a, spans.back().b], within
  // one turn (ww columns) of each other.
  struct Band {
    uint32_t texel = 0, row = 0;
    uint32_t first_span = 0, spans = 0;
    uint32_t first_edge = 0, top_edges = 0, bottom_edges = 0;  // top edges first, then bottom ones
    double height = 0;                                         // the row's height in z
  };
  // The band covers columns [a, b] (some of the row's height in each).
  struct Span {
    double a = 0, b = 0;
  };
  // A piece of a texel edge that is not along a meridian, as the top of the band below it or
  // the bottom of the band above it, traversed towards increasing column c. With K(t) =
  // ∫_0^t (z(c + w) − z(c + τ)) dτ, fitted by the cubic K(t) = t·(dz + t·(a2 + t·a3)) with
  // K(0) = 0, K'(0) = dz, K'(w) = 0 and the exact K(w), the band's area in a column between
  // t = a and t = b along it is less by
  //   top:    (b − a)·h + K(b) − K(a)      (h = row top − z(c + w))
  //   bottom: (b − a)·h − (K(b) − K(a))    (h = z(c + w) − row bottom)
  struct Edge {
    double c = 0;  // working column where it starts, in the band's coordinate
    double h = 0;
    double dz = 0, a2 = 0, a3 = 0;  // dz: z at its end − z at its start
    double w = 0;                   // width in working columns
  };
  struct EmptyTexel {
    uint64_t texel = 0;
    uint32_t row = 0;
    double column = 0;  // working column of the texel centre (unrotated)
  };

  uint64_t r_ = 0, ww_ = 0, hw_ = 0, pieces_ = 0;
  // hw × ww × 3 (+1 pad): the working grid's radiance, row-major. Immutable, shared by copies.
  std::shared_ptr<const double[]> values_;
  std::vector<Band> bands_;
  std::vector<Span> spans_;
  std::vector<Edge> edges_;
  uint64_t widest_band_ = 0;         // columns of the widest band (Integrate's scratch)
  std::vector<double> texel_scale_;  // 1 / the texel's solid angle as its bands see it (1 for empty texels)
  std::vector<double> omega_;        // exact texel solid angles
  std::vector<EmptyTexel> empty_;
  double power_[3] = {0, 0, 0};
  double peak_[3] = {0, 0, 0};  // the working grid's largest value per channel
  double solid_angle_error_ = 0;
};

}  // namespace ltb::stages
