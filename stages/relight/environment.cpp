#include "stages/relight/environment.h"

#include <algorithm>
#include <utility>

#include "stages/relight/relight.h"

namespace ltb::stages {

Result<Environment> Environment::Open(const std::string& path, uint64_t cube_res, const EnvLoadOptions& o) {
  Environment e;
  e.cube_res_ = cube_res;
  if (path.ends_with(".npy")) {
    LTB_ASSIGN_OR_RETURN(std::vector<float> m, ReadCubemapNpy(path, cube_res, o.clamp, &e.clamped_));
    e.fixed_ = std::move(m);
    return e;
  }
  LTB_ASSIGN_OR_RETURN(EnvMap map, LoadEnvMap(path, o));
  e.clamped_ = map.clamped;
  LTB_ASSIGN_OR_RETURN(CubemapResampler r, CubemapResampler::Create(map, cube_res, o.progress));
  e.resampler_ = std::make_unique<CubemapResampler>(std::move(r));
  return e;
}

void Environment::Cubemap(double rotation, std::vector<float>* out) const {
  out->resize(6 * cube_res_ * cube_res_ * 3);
  if (resampler_) {
    resampler_->Resample(rotation, out->data());
  } else {
    std::copy(fixed_.begin(), fixed_.end(), out->begin());
  }
}

}  // namespace ltb::stages
