// The lighting of a relight: an environment map resampled to the bake's cubemap (and
// rotatable about +Z per frame), or a ready 6R² × 3 cubemap .npy (fixed). Shared by
// `relight` (run_relight.cpp) and the triple-product renderer (stages/triple/render.h).
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "format/status.h"
#include "stages/relight/envmap.h"

namespace ltb::stages {

class Environment {
 public:
  static Result<Environment> Open(const std::string& path, uint64_t cube_res, const EnvLoadOptions& o);
  // 6R² × 3 radiance for a rotation about +Z in radians (a .npy cubemap cannot rotate).
  void Cubemap(double rotation, std::vector<float>* out) const;
  bool rotates() const { return resampler_ != nullptr; }
  uint64_t clamped() const { return clamped_; }

 private:
  uint64_t cube_res_ = 0;
  std::vector<float> fixed_;
  std::unique_ptr<CubemapResampler> resampler_;
  uint64_t clamped_ = 0;
};

}  // namespace ltb::stages
