// The Embree side of the sampler: one device and one scene for the whole stage; triangle
// meshes and exact spheres; closest-hit queries for camera rays and bounces, stream
// occlusion queries for transport. Embree errors arrive through the device error
// callback and become a Status.
#pragma once

#include <embree3/rtcore.h>

#include <glm/vec3.hpp>
#include <memory>
#include <mutex>
#include <vector>

#include "format/progress.h"
#include "format/status.h"
#include "stages/mesh/triangle_mesh.h"

namespace ltb::sample {

struct Hit {
  bool hit = false;
  double t = 0;
  glm::dvec3 normal{0, 0, 1};  // unit geometric normal as Embree reports it (not oriented)
  unsigned geom_id = 0;
  unsigned prim_id = 0;  // the triangle within the geometry
  double u = 0, v = 0;   // barycentrics: the hit is (1−u−v)·p0 + u·p1 + v·p2
};

// A batch of occlusion rays in structure-of-arrays form, as rtcOccludedNp reads it. The
// sampler writes directions and tfar (+inf: trace; -inf: an inactive slot, tnear > tfar);
// tnear, time, mask, id and flags are constant, and the origin is shared by the batch.
// After Occluded, tfar[k] is -inf for an occluded (or inactive) ray.
struct RayBatch {
  std::vector<float> org_x, org_y, org_z, tnear, dir_x, dir_y, dir_z, time, tfar;
  std::vector<unsigned> mask, id, flags;
  // Room for n rays (keeps what is there; new slots get the constant fields).
  void Reserve(size_t n);
  // The origin of slots [0, n): fills only what is not filled yet with this origin.
  void SetOrigin(float x, float y, float z, size_t n);

 private:
  float ox_ = 0, oy_ = 0, oz_ = 0;
  size_t origin_filled_ = 0;
};

class RayScene {
 public:
  ~RayScene();
  RayScene(const RayScene&) = delete;
  RayScene& operator=(const RayScene&) = delete;

  static Result<std::unique_ptr<RayScene>> Create();
  // Geometry ids are assigned in the order of these calls, from 0.
  Status AddMesh(const mesh::TriangleMesh& mesh);
  Status AddSphere(const glm::dvec3& center, double radius);
  // Builds the BVH; Cancelled when `progress` asks to stop while it builds.
  Status Commit(const Progress& progress = Progress{});

  Hit Intersect(const glm::dvec3& origin, const glm::dvec3& dir) const;
  // Occlusion of every ray in place: an occluded ray's tfar becomes -inf. Thread-safe.
  void Occluded(RTCRay* rays, size_t count) const;
  // The same for the first `count` slots of a structure-of-arrays batch (rtcOccludedNp,
  // coherent flag).
  void Occluded(RayBatch& batch, size_t count) const;
  // The first error Embree reported, if any.
  Status error() const;

 private:
  RayScene() = default;
  static void OnError(void* user, RTCError code, const char* message);

  RTCDevice device_ = nullptr;
  RTCScene scene_ = nullptr;
  mutable std::mutex mu_;
  Status error_;
};

}  // namespace ltb::sample
