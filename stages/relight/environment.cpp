#include "stages/relight/environment.h"

#include <algorithm>
#include <cmath>
#include <utility>

#include "stages/relight/exact_cubemap.h"
#include "stages/relight/relight.h"

namespace ltb::stages {

Result<Environment> Environment::Open(const std::string& path, uint64_t cube_res, const EnvLoadOptions& o,
                                      EnvResampling resampling) {
  Environment e;
  e.cube_res_ = cube_res;
  e.progress_ = o.progress;
  if (path.ends_with(".npy")) {
    LTB_ASSIGN_OR_RETURN(std::vector<float> m, ReadCubemapNpy(path, cube_res, o.clamp, &e.clamped_));
    e.fixed_ = std::move(m);
    for (float v : e.fixed_) e.peak_ = std::max(e.peak_, std::fabs(v));
    return e;
  }
  LTB_ASSIGN_OR_RETURN(EnvMap map, LoadEnvMap(path, o));
  e.clamped_ = map.clamped;
  for (float v : map.rgb) e.peak_ = std::max(e.peak_, std::fabs(v));  // NaN (outside an angular disk) is skipped
  if (resampling == EnvResampling::kExact && map.layout != EnvLayout::kLatLong) {
    e.exact_ = std::make_shared<const EnvMap>(std::move(map));
    return e;
  }
  LTB_ASSIGN_OR_RETURN(CubemapResampler r, CubemapResampler::Create(map, cube_res, o.progress));
  e.resampler_ = std::make_unique<CubemapResampler>(std::move(r));
  return e;
}

Environment::Environment(Environment&& o) noexcept { *this = std::move(o); }

Environment& Environment::operator=(Environment&& o) noexcept {
  cube_res_ = o.cube_res_;
  fixed_ = std::move(o.fixed_);
  resampler_ = std::move(o.resampler_);
  exact_ = std::move(o.exact_);
  progress_ = o.progress_;
  clamped_ = o.clamped_;
  peak_ = o.peak_;
  last_rotation_ = o.last_rotation_;
  last_ = std::move(o.last_);
  return *this;
}

Status Environment::Cubemap(double rotation, std::vector<float>* out) const {
  if (exact_) {
    std::lock_guard<std::mutex> lock(last_mutex_);
    if (last_.empty() || last_rotation_ != rotation) {
      LTB_ASSIGN_OR_RETURN(last_, ExactCubemap(*exact_, cube_res_, rotation, progress_));
      last_rotation_ = rotation;
    }
    *out = last_;
    return Status::Ok();
  }
  out->resize(6 * cube_res_ * cube_res_ * 3);
  if (resampler_) {
    resampler_->Resample(rotation, out->data());
  } else {
    std::copy(fixed_.begin(), fixed_.end(), out->begin());
  }
  return Status::Ok();
}

}  // namespace ltb::stages
