// Cubemap conventions (docs/CUBEMAP.md): face order +X, −X, +Y, −Y, +Z, −Z; column
// face·R² + t·R + s; face coordinates u = 2(s+0.5)/R − 1, v = 2(t+0.5)/R − 1 at texel
// centres; OpenGL cube-map directions; exact texel solid angles.
#pragma once

#include <cstdint>
#include <glm/vec3.hpp>

namespace ltb::cubemap {

struct Texel {
  int face = 0;
  uint32_t s = 0, t = 0;
};

// Unnormalised direction through face point (u, v) in [-1, 1]² (|d| = sqrt(1 + u² + v²)).
inline glm::dvec3 FaceDirection(int face, double u, double v) {
  switch (face) {
    case 0:
      return {1, -v, -u};
    case 1:
      return {-1, -v, u};
    case 2:
      return {u, 1, v};
    case 3:
      return {u, -1, -v};
    case 4:
      return {u, -v, 1};
    default:
      return {-u, -v, -1};
  }
}
// Face and face coordinates (u, v) of a direction (any length > 0).
void DirectionToFace(const glm::dvec3& d, int* face, double* u, double* v);
// The texel a direction falls in.
Texel DirectionToTexel(const glm::dvec3& d, uint32_t r);
inline uint64_t Column(const Texel& x, uint32_t r) { return uint64_t(x.face) * r * r + uint64_t(x.t) * r + x.s; }
inline Texel ColumnToTexel(uint64_t column, uint32_t r) {
  uint64_t rr = uint64_t(r) * r;
  return {static_cast<int>(column / rr), static_cast<uint32_t>(column % rr % r),
          static_cast<uint32_t>(column % rr / r)};
}
// Unit direction through the texel centre.
glm::dvec3 TexelCenter(const Texel& x, uint32_t r);
// Exact solid angle of the face region [u0,u1]×[v0,v1], and of a texel.
double SolidAngle(double u0, double v0, double u1, double v1);
double TexelSolidAngle(const Texel& x, uint32_t r);
// Half-angle of the smallest cone around the texel centre holding the whole texel.
double TexelAngularRadius(const Texel& x, uint32_t r);

}  // namespace ltb::cubemap
