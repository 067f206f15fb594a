#include "stages/common/cubemap.h"

#include <algorithm>
#include <cmath>
#include <glm/geometric.hpp>

namespace ltb::cubemap {

void DirectionToFace(const glm::dvec3& d, int* face, double* u, double* v) {
  double ax = std::fabs(d.x), ay = std::fabs(d.y), az = std::fabs(d.z);
  // Ties go to the earlier face in the order +X, -X, +Y, -Y, +Z, -Z.
  if (ax >= ay && ax >= az) {
    *face = d.x > 0 ? 0 : 1;
    *u = d.x > 0 ? -d.z / ax : d.z / ax;
    *v = -d.y / ax;
  } else if (ay >= az) {
    *face = d.y > 0 ? 2 : 3;
    *u = d.x / ay;
    *v = d.y > 0 ? d.z / ay : -d.z / ay;
  } else {
    *face = d.z > 0 ? 4 : 5;
    *u = d.z > 0 ? d.x / az : -d.x / az;
    *v = -d.y / az;
  }
}

Texel DirectionToTexel(const glm::dvec3& d, uint32_t r) {
  int face;
  double u, v;
  DirectionToFace(d, &face, &u, &v);
  auto index = [r](double c) {
    long long i = static_cast<long long>(std::floor((c + 1.0) * 0.5 * r));
    return static_cast<uint32_t>(std::clamp<long long>(i, 0, r - 1));
  };
  return {face, index(u), index(v)};
}

glm::dvec3 TexelCenter(const Texel& x, uint32_t r) {
  double u = 2.0 * (x.s + 0.5) / r - 1.0, v = 2.0 * (x.t + 0.5) / r - 1.0;
  return glm::normalize(FaceDirection(x.face, u, v));
}

double SolidAngle(double u0, double v0, double u1, double v1) {
  auto a = [](double x, double y) { return std::atan2(x * y, std::sqrt(x * x + y * y + 1.0)); };
  return a(u1, v1) - a(u0, v1) - a(u1, v0) + a(u0, v0);
}

double TexelSolidAngle(const Texel& x, uint32_t r) {
  double u0 = 2.0 * x.s / r - 1.0, v0 = 2.0 * x.t / r - 1.0;
  return SolidAngle(u0, v0, u0 + 2.0 / r, v0 + 2.0 / r);
}

double TexelAngularRadius(const Texel& x, uint32_t r) {
  glm::dvec3 c = TexelCenter(x, r);
  double u0 = 2.0 * x.s / r - 1.0, v0 = 2.0 * x.t / r - 1.0, h = 2.0 / r;
  double min_cos = 1.0;
  for (double du : {0.0, h})
    for (double dv : {0.0, h})
      min_cos = std::min(min_cos, glm::dot(c, glm::normalize(FaceDirection(x.face, u0 + du, v0 + dv))));
  return std::acos(std::clamp(min_cos, -1.0, 1.0));
}

}  // namespace ltb::cubemap
