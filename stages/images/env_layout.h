// Internal to the envmap library (stages/images/envmap.h is the public header): where the
// faces of a cross or a face strip lie, and the angular (light-probe) map's projection;
// used by the loader's value check and by the resampler.
#pragma once

#include <cstdint>
#include <glm/vec3.hpp>
#include <numbers>

#include "stages/images/envmap.h"

namespace ltb::stages::envmap_internal {

inline constexpr double kPi = std::numbers::pi;

// Face (0..5) shown in cell (col, row) of a cross, -1 for an unused cell.
int CrossFace(EnvLayout layout, uint64_t col, uint64_t row);

// Angular (light-probe) maps, as Debevec distributes his probes: a square image whose
// inscribed disk holds every direction. With (u, v) in [-1, 1]² (u right, v up) and
// r = |(u, v)|, the direction at (u, v) lies at the angle π·r from the map's centre
// direction, towards the image direction (u, v); the disk's rim is the direction behind.
// The centre is the direction of a lat-long map's centre column (+X), up is +Z and right
// is the direction of increasing lat-long u at that centre (−Y), so a probe and its
// lat-long panorama converted centre to centre give the same cubemap (docs/ENVMAPS.md).
glm::dvec3 AngularDirection(double u, double v);

// The pixel (x, y) of a W×W angular map holding direction d.
void DirectionToAngular(const glm::dvec3& d, uint64_t w, uint64_t* x, uint64_t* y);

// Whether pixel (x, y) of a W×W angular map touches the disk (the pixels the resampler
// reads; the values of the others are never used, so they are not checked).
bool InAngularDisk(uint64_t x, uint64_t y, uint64_t w);

// Face size and the pixel origin of each face in a face layout.
struct FaceGeometry {
  uint64_t size = 0;
  uint64_t x0[6] = {}, y0[6] = {};
};

// The faces of a kHCross, kVCross or kFaces map.
FaceGeometry FacesOf(const EnvMap& env);

}  // namespace ltb::stages::envmap_internal
