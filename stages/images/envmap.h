// Environment maps (docs/ENVMAPS.md): loading .exr (OpenEXR, any compression incl. DWAB;
// RGB, RGBA, luminance Y or luminance-chroma) and Radiance .hdr (RGBE, run-length or flat)
// as lat-long maps, horizontal or vertical crosses, or six face files; and area-correct
// resampling to ltbake's cubemap (docs/CUBEMAP.md), rotated about +Z, for relighting.
// The resampler (CubemapResampler) is declared in resampler.h, included here.
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
#include "stages/images/resampler.h"

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
  // Threads a rotated lat-long map is resampled on, frame after frame (Environment::Cubemap);
  // the cubemap does not depend on it.
  int jobs = 1;
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

// What LoadEnvMap would make of `path`'s shape, without decoding a pixel (for checks before
// a bake runs: `ltbake run` reads every map of a recipe so): the files' sizes checked as
// LoadEnvMap checks them, and the layout (options.layout, or the one auto-detection picks),
// with LoadEnvMap's message when the shape fits no layout. Pixel values are not checked.
Result<EnvLayout> CheckEnvMapShape(const std::string& path, const EnvLoadOptions& options);

// The lat-long convention (Blender/Cycles equirectangular): column fraction u ∈ [0, 1),
// row fraction v ∈ [0, 1] from the top: φ = π − 2πu (= atan2(y, x)), θ = πv (= acos z),
// direction (sin θ cos φ, sin θ sin φ, cos θ); z is up, the image centre looks along +X.
glm::dvec3 LatLongDirection(double u, double v);
// Inverse of LatLongDirection for any non-zero d: u ∈ [0, 1), v ∈ [0, 1].
void DirectionToLatLong(const glm::dvec3& d, double* u, double* v);

// `ltbake convert ENV OUT.npy --cube-res R`: loads ENV (.exr/.hdr, or six faces with {face})
// and writes its R-cubemap (rotation 0) as a 6R² × 3 float32 .npy, written beside OUT and
// renamed into place. R must be a power of two up to 512 (as for a matrix's cube columns).
// `clamped` (optional) receives EnvMap::clamped.
// The R-cubemap of ENV (rotation 0) in memory, 6R² × 3 floats: what ConvertEnvToNpy writes.
Result<std::vector<float>> EnvToCubemap(const std::string& in, uint64_t cube_res, const EnvLoadOptions& options,
                                        uint64_t* clamped = nullptr);
Status ConvertEnvToNpy(const std::string& in, const std::string& out, uint64_t cube_res, const EnvLoadOptions& options,
                       uint64_t* clamped = nullptr);
// True for paths ConvertEnvToNpy reads: .exr, .hdr, .pic, .rgbe (any case) or "{face}".
bool IsEnvMapPath(const std::string& path);

}  // namespace ltb::stages
