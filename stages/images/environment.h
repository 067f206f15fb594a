// The lighting of a relight: an environment map resampled to the bake's cubemap (and
// rotatable about +Z per frame), or a ready 6R² × 3 cubemap .npy (fixed). Shared by
// `relight` (run_relight.cpp), the glossy and triple-product views, sequences and `view`.
#pragma once

#include <cstdint>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include "format/status.h"
#include "stages/images/envmap.h"

namespace ltb::stages {

// A 6R² × 3 cubemap of radiance from .npy (float32 or float64, C order), checked finite,
// non-negative and (float64) within float32's range; the first value that is not is named
// with its texel, channel and value (%.9g), with how many there are. With `clamp`
// (--clamp, as for maps: EnvLoadOptions::clamp) they are fixed instead and counted in
// `clamped`: NaN and negatives (−Inf included) become 0, +Inf and float64 values above
// float32's largest become the largest finite float. Only a regular file is opened; the
// declared shape must be (6R², 3) and its size (checked arithmetic) must fit the file
// before anything is allocated.
Result<std::vector<float>> ReadCubemapNpy(const std::string& path, uint64_t cube_res, bool clamp = false,
                                          uint64_t* clamped = nullptr);
// The R of a cubemap .npy from its header alone (for checks before a bake runs): an error
// unless it holds a C-order float (6R², 3) array with R a power of two.
Result<uint64_t> CubemapNpyResolution(const std::string& path);

// How a map that is not lat-long becomes a cubemap (a lat-long map is exact either way).
enum class EnvResampling {
  // Exact texel averages at every call (stages/images/exact_cubemap.h): for a frame
  // resampled once (about a second for a 2048² probe at R = 32).
  kExact,
  // The working-grid resampler (resampler.h): milliseconds a frame at any rotation, for
  // sequences and the viewer; within ~2% a texel of the exact averages on a peaky map.
  kPerFrame,
};

class Environment {
 public:
  static Result<Environment> Open(const std::string& path, uint64_t cube_res, const EnvLoadOptions& o,
                                  EnvResampling resampling = EnvResampling::kExact);
  // A cubemap already in memory (the Python module's relight from a NumPy array): 6R² × 3
  // values, checked as ReadCubemapNpy checks a file's (`what` names it in messages).
  static Result<Environment> FromCubemap(std::vector<float> values, uint64_t cube_res, bool clamp,
                                         const std::string& what);
  // 6R² × 3 radiance for a rotation about +Z in radians (a .npy cubemap cannot rotate).
  // Fails only when the exact path is cancelled (EnvLoadOptions::progress).
  Status Cubemap(double rotation, std::vector<float>* out) const;
  bool rotates() const { return resampler_ != nullptr || exact_ != nullptr; }
  uint64_t clamped() const { return clamped_; }
  // The largest value of the source (of the .npy): no texel of any rotation is larger.
  float peak() const { return peak_; }

 private:
  uint64_t cube_res_ = 0;
  std::vector<float> fixed_;
  std::unique_ptr<CubemapResampler> resampler_;
  std::shared_ptr<const EnvMap> exact_;  // the source, for EnvResampling::kExact of a non-lat-long map
  Progress progress_;
  int jobs_ = 1;  // the resampler's threads
  uint64_t clamped_ = 0;
  float peak_ = 0;
  // The last exact cubemap (a glossy set asks for the same one per member); behind a pointer
  // so that the environment moves as a value.
  struct LastExact {
    std::mutex mutex;
    double rotation = 0;
    std::vector<float> cube;
  };
  std::unique_ptr<LastExact> last_ = std::make_unique<LastExact>();
};

}  // namespace ltb::stages
