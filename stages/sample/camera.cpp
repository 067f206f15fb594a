#include "stages/sample/camera.h"

#include <cmath>
#include <cstdio>
#include <glm/geometric.hpp>
#include <glm/trigonometric.hpp>
#include <numeric>
#include <string>

#include "stages/common/parallel_for.h"
#include "stages/mesh/triangle_mesh.h"
#include "stages/sample/scene_geometry.h"

namespace ltb::sample {

using mesh::FormatVec3;

Status ValidateView(const glm::dvec3& eye, const glm::dvec3& target, const glm::dvec3& up, double fov_degrees) {
  char lim[32];
  std::snprintf(lim, sizeof lim, "%g", kMaxTraceCoordinate);
  for (const auto& [key, v] : {std::pair{"eye", eye}, std::pair{"target", target}, std::pair{"up", up}}) {
    for (int i = 0; i < 3; ++i) {
      if (!std::isfinite(v[i]) || std::fabs(v[i]) > kMaxTraceCoordinate) {
        return InvalidArgument(std::string(key) + " " + FormatVec3(v) + " is outside what ray tracing holds (each " +
                               "coordinate finite and within ±" + lim + "); use smaller coordinates");
      }
    }
  }
  if (!(fov_degrees > 0 && fov_degrees < 180)) {
    char b[48];
    std::snprintf(b, sizeof b, "%g", fov_degrees);
    return InvalidArgument(std::string("fov ") + b + ": the vertical field of view must be in (0, 180) degrees");
  }
  const glm::dvec3 d = target - eye;
  const double len = glm::length(d);
  if (!(len > 0) || !std::isfinite(len)) {
    return InvalidArgument("eye " + FormatVec3(eye) + " equals target " + FormatVec3(target) +
                           ": the camera has no view direction; move the eye or the target");
  }
  const double up_len = glm::length(up);
  if (!(up_len > 0) || !std::isfinite(up_len)) {
    return InvalidArgument("up is " + FormatVec3(up) +
                           "; it must be a non-zero vector, not parallel to the view direction (e.g. [0, 0, 1])");
  }
  const glm::dvec3 f = d / len;
  const double sine = glm::length(glm::cross(f, up / up_len));  // of the angle between them
  if (!(sine > 1e-6)) {
    return InvalidArgument("up " + FormatVec3(up) + " is parallel to the view direction " + FormatVec3(f) +
                           " (from eye to target); choose an up that is not");
  }
  // The frame in single precision, as the rays get it: a tiny but nonzero view direction
  // (eye and target 1e-300 apart) must not become NaN there.
  const glm::vec3 ff = glm::vec3(f), uf = glm::vec3(up / up_len);
  if (!(glm::length(glm::cross(ff, uf)) > 0)) {
    return InvalidArgument("up " + FormatVec3(up) + " is too close to the view direction " + FormatVec3(f) +
                           "; choose an up that is not");
  }
  return Status::Ok();
}

Result<PinholeCamera> PinholeCamera::Create(const glm::dvec3& eye, const glm::dvec3& target, const glm::dvec3& up,
                                            double fov_degrees, uint64_t width, uint64_t height) {
  LTB_RETURN_IF_ERROR(ValidateView(eye, target, up, fov_degrees));
  if (width == 0 || height == 0) {
    return InvalidArgument("image size " + std::to_string(width) + "x" + std::to_string(height) +
                           ": both sides must be at least 1 pixel");
  }
  return PinholeCamera(eye, target, up, fov_degrees, width, height);
}

PinholeCamera::PinholeCamera(const glm::dvec3& eye, const glm::dvec3& target, const glm::dvec3& up, double fov_degrees,
                             uint64_t width, uint64_t height)
    : eye_(eye), width_(width), height_(height) {
  f_ = glm::normalize(target - eye);
  right_ = glm::normalize(glm::cross(f_, up));
  up_ = glm::cross(right_, f_);
  th_ = std::tan(glm::radians(fov_degrees) / 2);
  aspect_ = double(width) / height;
}

glm::dvec3 PinholeCamera::Direction(uint64_t x, uint64_t y) const {
  const double px = (2.0 * (x + 0.5) / width_ - 1.0) * th_ * aspect_, py = (1.0 - 2.0 * (y + 0.5) / height_) * th_;
  return glm::normalize(f_ + px * right_ + py * up_);
}

glm::dvec3 OrbitEye(const glm::dvec3& eye, const glm::dvec3& target, double deg_per_frame, uint32_t k) {
  const double angle = glm::radians(deg_per_frame * k);
  const glm::dvec3 rel = eye - target;
  return target + glm::dvec3(rel.x * std::cos(angle) - rel.y * std::sin(angle),
                             rel.x * std::sin(angle) + rel.y * std::cos(angle), rel.z);
}

Status CheckViewMemory(uint64_t width, uint64_t height, uint64_t mem_limit) {
  const uint64_t pixels = width * height;  // both at most 2^16 (the size parser's limit)
  if (mem_limit == 0 || pixels <= mem_limit / kViewBytesPerPixel) return Status::Ok();
  const uint64_t side = static_cast<uint64_t>(std::sqrt(static_cast<double>(mem_limit / kViewBytesPerPixel)));
  auto mib = [](uint64_t bytes) {
    char b[48];
    std::snprintf(b, sizeof b, "%.1f MiB", static_cast<double>(bytes) / (1 << 20));
    return std::string(b);
  };
  return InvalidArgument("--size " + std::to_string(width) + "x" + std::to_string(height) + " needs about " +
                         mib(pixels * kViewBytesPerPixel) + " of image buffers (" + std::to_string(kViewBytesPerPixel) +
                         " bytes a pixel), over --mem-limit " + mib(mem_limit) +
                         "; the largest square view that fits is " + std::to_string(side) + "x" + std::to_string(side) +
                         ": lower --size or raise --mem-limit");
}

Status TracePixels(const Geometry& geo, const PinholeCamera& camera, int jobs, std::vector<PixelHit>* hits) {
  hits->assign(camera.width() * camera.height(), PixelHit{});
  std::vector<uint64_t> lines(camera.height());
  std::iota(lines.begin(), lines.end(), 0);
  LTB_RETURN_IF_ERROR(stages::ParallelFor(lines, jobs, Progress{}, "lines", [&](uint64_t y) -> Status {
    for (uint64_t x = 0; x < camera.width(); ++x) {
      const Hit h = geo.rays->Intersect(camera.eye(), camera.Direction(x, y));
      if (!h.hit) continue;
      PixelHit& ph = (*hits)[y * camera.width() + x];
      ph.geom = h.geom_id;
      ph.prim = h.prim_id;
      ph.u = static_cast<float>(h.u);
      ph.v = static_cast<float>(h.v);
    }
    return Status::Ok();
  }));
  return geo.rays->error();
}

}  // namespace ltb::sample
