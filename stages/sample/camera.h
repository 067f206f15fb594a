// The camera every renderer shoots: the view check (what Embree can trace), the pinhole
// camera of image mode and of the view renderers (relight --eye: the glossy and the
// triple-product views), their primary-ray tracer and orbits.
#pragma once

#include <cstdint>
#include <glm/vec3.hpp>
#include <vector>

#include "format/status.h"

namespace ltb::sample {

struct Geometry;

struct Camera {
  glm::dvec3 eye{0, -3, 1.5}, target{0, 0, 0}, up{0, 0, 1};
  double fov_degrees = 40.0;  // vertical
  uint32_t width = 64, height = 64;
};

// How far from the origin anything traced may be. Embree asserts (and aborts the process)
// on a ray whose origin has a coordinate beyond its FLT_LARGE, 1.844e18; shadow and bounce
// rays start on the geometry and primary rays at the eye, so the eye, the target and every
// object's bounds must stay within this, with a margin for the offsets rays start at.
inline constexpr double kMaxTraceCoordinate = 1e17;

// A view every renderer can trace (the sampler's image-mode camera, the glossy and the
// triple-product views): eye and target within ±kMaxTraceCoordinate and apart, a non-zero up
// not parallel to the view direction, 0 < fov < 180 degrees. kInvalidArgument naming the
// value and what to change otherwise ("eye [1, 2, 3] equals target [1, 2, 3]: ...").
Status ValidateView(const glm::dvec3& eye, const glm::dvec3& target, const glm::dvec3& up, double fov_degrees);

// The pinhole camera of image mode (docs/SCENE.md), also what the view renderers shoot
// (relight --eye): the ray direction through the centre of pixel (x, y), row 0 at the top.
class PinholeCamera {
 public:
  // The only way to make one from loose values: checked by ValidateView (and a size of at
  // least 1x1), so every ray it gives is one Embree accepts.
  static Result<PinholeCamera> Create(const glm::dvec3& eye, const glm::dvec3& target, const glm::dvec3& up,
                                      double fov_degrees, uint64_t width, uint64_t height);
  // A scene's camera, which ParseScene has checked with ValidateView.
  explicit PinholeCamera(const Camera& c) : PinholeCamera(c.eye, c.target, c.up, c.fov_degrees, c.width, c.height) {}
  glm::dvec3 Direction(uint64_t x, uint64_t y) const;
  const glm::dvec3& eye() const { return eye_; }
  uint64_t width() const { return width_; }
  uint64_t height() const { return height_; }

 private:
  PinholeCamera(const glm::dvec3& eye, const glm::dvec3& target, const glm::dvec3& up, double fov_degrees,
                uint64_t width, uint64_t height);

  glm::dvec3 eye_, f_, right_, up_;
  double th_, aspect_;
  uint64_t width_, height_;
};

// What a pixel's primary ray hit: the Embree geometry (−1: nothing), the triangle and the
// barycentrics.
struct PixelHit {
  int64_t geom = -1;
  uint32_t prim = 0;
  float u = 0, v = 0;
};
// The memory a view of width x height pixels takes in the renderers (the hit of each pixel,
// its RGB value and the writer's buffers), measured: 48 bytes a pixel (a 16384² glossy view
// took 12.0 GiB, an 8192² triple one 3.0 GiB). kInvalidArgument when that is over mem_limit
// (0: no limit), naming the size, the bytes it needs and the largest square view that fits.
inline constexpr uint64_t kViewBytesPerPixel = 48;
Status CheckViewMemory(uint64_t width, uint64_t height, uint64_t mem_limit);

// One primary ray per pixel through the camera, lines in parallel (the triple-product and
// the factored-bake views).
Status TracePixels(const Geometry& geo, const PinholeCamera& camera, int jobs, std::vector<PixelHit>* hits);
// Frame k of an orbit: the eye turned by k·deg_per_frame degrees about the +Z axis through
// the target.
glm::dvec3 OrbitEye(const glm::dvec3& eye, const glm::dvec3& target, double deg_per_frame, uint32_t k);

}  // namespace ltb::sample
