#include "stages/images/env_layout.h"

#include <algorithm>
#include <cmath>
#include <glm/geometric.hpp>

namespace ltb::stages::envmap_internal {

int CrossFace(EnvLayout layout, uint64_t col, uint64_t row) {
  if (layout == EnvLayout::kHCross) {  // 4 × 3: +Y / −X +Z +X −Z / −Y
    static const int kRow1[4] = {1, 4, 0, 5};
    if (row == 1) return kRow1[col];
    if (col == 1) return row == 0 ? 2 : 3;
    return -1;
  }
  if (layout == EnvLayout::kVCross) {  // 3 × 4: +Y / −X +Z +X / −Y / −Z
    static const int kRow1[3] = {1, 4, 0};
    if (row == 1) return kRow1[col];
    if (col == 1) return row == 0 ? 2 : row == 2 ? 3 : 5;
    return -1;
  }
  return 0;
}

glm::dvec3 AngularDirection(double u, double v) {
  const double r = std::sqrt(u * u + v * v);
  const double s = r > 0 ? std::sin(kPi * r) / r : kPi;  // sin(πr)/r → π at the centre
  return {std::cos(kPi * r), -u * s, v * s};             // forward +X, right −Y, up +Z
}

void DirectionToAngular(const glm::dvec3& d, uint64_t w, uint64_t* x, uint64_t* y) {
  const glm::dvec3 n = glm::normalize(d);
  const double pu = -n.y, pv = n.z, len = std::sqrt(pu * pu + pv * pv);
  const double r = std::acos(std::clamp(n.x, -1.0, 1.0)) / kPi;
  const double u = len > 0 ? pu / len * r : 0.0, v = len > 0 ? pv / len * r : 0.0;
  *x = std::min<uint64_t>(w - 1, uint64_t(std::max(0.0, (u + 1.0) * 0.5 * double(w))));
  *y = std::min<uint64_t>(w - 1, uint64_t(std::max(0.0, (1.0 - v) * 0.5 * double(w))));
}

bool InAngularDisk(uint64_t x, uint64_t y, uint64_t w) {
  auto nearest = [](double a, double b) { return a > 0 ? a : b < 0 ? b : 0.0; };  // of [a, b] to 0
  const double u = nearest(2.0 * double(x) / double(w) - 1.0, 2.0 * double(x + 1) / double(w) - 1.0);
  const double v = nearest(1.0 - 2.0 * double(y + 1) / double(w), 1.0 - 2.0 * double(y) / double(w));
  return u * u + v * v <= 1.0;
}

FaceGeometry FacesOf(const EnvMap& env) {
  FaceGeometry g;
  if (env.layout == EnvLayout::kFaces) {
    g.size = env.width;
    for (int f = 0; f < 6; ++f) g.y0[f] = f * g.size;
    return g;
  }
  const uint64_t cols = env.layout == EnvLayout::kHCross ? 4 : 3, rows = env.layout == EnvLayout::kHCross ? 3 : 4;
  g.size = env.width / cols;
  for (uint64_t r = 0; r < rows; ++r)
    for (uint64_t c = 0; c < cols; ++c) {
      int f = CrossFace(env.layout, c, r);
      if (f >= 0) {
        g.x0[f] = c * g.size;
        g.y0[f] = r * g.size;
      }
    }
  return g;
}

}  // namespace ltb::stages::envmap_internal
