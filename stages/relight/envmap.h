// Environment maps (docs/ENVMAPS.md): loading .exr (OpenEXR, any compression incl. DWAB;
// RGB, RGBA, luminance Y or luminance-chroma) and Radiance .hdr (RGBE, run-length or flat)
// as lat-long maps, horizontal or vertical crosses, or six face files; and area-correct
// resampling to ltbake's cubemap (docs/CUBEMAP.md), rotated about +Z, for relighting.
#pragma once

#include <cstdint>
#include <glm/vec3.hpp>
#include <memory>
#include <new>
#include <string>
#include <utility>
#include <vector>

#include "format/progress.h"
#include "format/status.h"

namespace ltb::stages {

// An allocator whose value-initialisation leaves floats uninitialised: the readers size a
// pixel buffer once, after every check of the file, and its pages are committed only as
// pixels are decoded into them (a file that fails half way has cost what it decoded).
template <typename T>
struct DefaultInitAllocator : std::allocator<T> {
  template <typename U>
  struct rebind {
    using other = DefaultInitAllocator<U>;
  };
  DefaultInitAllocator() = default;
  template <typename U>
  DefaultInitAllocator(const DefaultInitAllocator<U>&) noexcept {}  // NOLINT(implicit)
  template <typename U>
  void construct(U* p) noexcept {
    ::new (static_cast<void*>(p)) U;
  }
  template <typename U, typename... Args>
  void construct(U* p, Args&&... args) {
    ::new (static_cast<void*>(p)) U(std::forward<Args>(args)...);
  }
};
using PixelBuffer = std::vector<float, DefaultInitAllocator<float>>;

enum class EnvLayout { kAuto, kLatLong, kHCross, kVCross, kFaces, kAngular };

// "auto", "latlong", "hcross", "vcross", "faces", "angular" (the --env-layout spellings).
const char* EnvLayoutName(EnvLayout layout);
Result<EnvLayout> ParseEnvLayout(const std::string& name);

struct EnvLoadOptions {
  EnvLayout layout = EnvLayout::kAuto;
  // Fix values that are not radiance instead of refusing the map: NaN and negatives
  // become 0, +Inf the largest finite float. Each fixed value is counted in EnvMap::clamped.
  bool clamp = false;
  // Memory the loader may use for pixels and file bytes (`--mem-limit`); 0: no limit but
  // the fixed cap of 2^28 pixels. Checked against the sizes a file declares before
  // anything of that size is allocated.
  uint64_t max_bytes = 0;
  // Cancellation (SIGINT/SIGTERM), checked between strips of rows: a Cancelled status.
  Progress progress;
};

struct EnvMap {
  EnvLayout layout = EnvLayout::kLatLong;  // resolved (never kAuto)
  // Source pixels. kFaces: F × 6F, the six F×F faces stacked top to bottom in ltbake face
  // order (+X, −X, +Y, −Y, +Z, −Z), each in the face's (s right, t down) orientation.
  uint64_t width = 0, height = 0;
  PixelBuffer rgb;       // width·height·3, row-major, row 0 = top
  uint64_t clamped = 0;  // values fixed by EnvLoadOptions::clamp (negative, NaN, Inf)
  std::string path;
};

// Loads an environment map. `path` names one .exr or .hdr file (the format is recognised by
// its magic bytes), or six face files through a "{face}" placeholder, replaced by px nx py
// ny pz nz. kAuto picks the layout from the size: width = 2·height lat-long, 4:3
// horizontal cross, 3:4 vertical cross (and "{face}" six faces). Errors name the file and,
// for values that are not radiance, the pixel (x, y), channel and value.
// Hostile files: sizes are checked with overflow-safe arithmetic against the cap, the
// file's length and options.max_bytes before allocating; only regular files are opened
// (a FIFO, device or directory is refused without blocking); no exception escapes.
Result<EnvMap> LoadEnvMap(const std::string& path, const EnvLoadOptions& options);

// The lat-long convention (Blender/Cycles equirectangular): column fraction u ∈ [0, 1),
// row fraction v ∈ [0, 1] from the top: φ = π − 2πu (= atan2(y, x)), θ = πv (= acos z),
// direction (sin θ cos φ, sin θ sin φ, cos θ); z is up, the image centre looks along +X.
glm::dvec3 LatLongDirection(double u, double v);
// Inverse of LatLongDirection for any non-zero d: u ∈ [0, 1), v ∈ [0, 1].
void DirectionToLatLong(const glm::dvec3& d, double* u, double* v);

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
  static Result<CubemapResampler> CreateUnchecked(const EnvMap& env, uint64_t cube_res, const Progress& progress);

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

// `ltbake convert ENV OUT.npy --cube-res R`: loads ENV (.exr/.hdr, or six faces with {face})
// and writes its R-cubemap (rotation 0) as a 6R² × 3 float32 .npy, written beside OUT and
// renamed into place. R must be a power of two up to 512 (as for a matrix's cube columns).
// `clamped` (optional) receives EnvMap::clamped.
Status ConvertEnvToNpy(const std::string& in, const std::string& out, uint64_t cube_res, const EnvLoadOptions& options,
                       uint64_t* clamped = nullptr);
// True for paths ConvertEnvToNpy reads: .exr, .hdr, .pic, .rgbe (any case) or "{face}".
bool IsEnvMapPath(const std::string& path);

}  // namespace ltb::stages
