#include "stages/sample/ray_scene.h"

#include <algorithm>
#include <cmath>
#include <glm/geometric.hpp>
#include <limits>

namespace ltb::sample {

namespace {
const char* ErrorName(RTCError code) {
  switch (code) {
    case RTC_ERROR_NONE:
      return "no error";
    case RTC_ERROR_UNKNOWN:
      return "unknown error";
    case RTC_ERROR_INVALID_ARGUMENT:
      return "invalid argument";
    case RTC_ERROR_INVALID_OPERATION:
      return "invalid operation";
    case RTC_ERROR_OUT_OF_MEMORY:
      return "out of memory";
    case RTC_ERROR_UNSUPPORTED_CPU:
      return "unsupported CPU";
    case RTC_ERROR_CANCELLED:
      return "cancelled";
  }
  return "error";
}
}  // namespace

void RayScene::OnError(void* user, RTCError code, const char* message) {
  auto* self = static_cast<RayScene*>(user);
  std::lock_guard<std::mutex> lock(self->mu_);
  if (self->error_.ok()) {
    self->error_ = Internal(std::string("Embree: ") + ErrorName(code) + (message ? std::string(": ") + message : ""));
  }
}

RayScene::~RayScene() {
  if (scene_) rtcReleaseScene(scene_);
  if (device_) rtcReleaseDevice(device_);
}

Result<std::unique_ptr<RayScene>> RayScene::Create() {
  std::unique_ptr<RayScene> s(new RayScene());
  s->device_ = rtcNewDevice(nullptr);
  if (s->device_ == nullptr) {
    return Internal(std::string("Embree: cannot create a device: ") + ErrorName(rtcGetDeviceError(nullptr)));
  }
  rtcSetDeviceErrorFunction(s->device_, &RayScene::OnError, s.get());
  s->scene_ = rtcNewScene(s->device_);
  rtcSetSceneBuildQuality(s->scene_, RTC_BUILD_QUALITY_HIGH);
  LTB_RETURN_IF_ERROR(s->error());
  return s;
}

Status RayScene::AddMesh(const mesh::TriangleMesh& mesh) {
  RTCGeometry g = rtcNewGeometry(device_, RTC_GEOMETRY_TYPE_TRIANGLE);
  auto* v = static_cast<float*>(rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3,
                                                        3 * sizeof(float), mesh.positions.size()));
  auto* idx = static_cast<unsigned*>(rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3,
                                                             3 * sizeof(unsigned), mesh.triangles.size()));
  if (v == nullptr || idx == nullptr) {
    rtcReleaseGeometry(g);
    return error().ok() ? Internal("Embree: cannot allocate geometry buffers") : error();
  }
  for (size_t i = 0; i < mesh.positions.size(); ++i)
    for (int k = 0; k < 3; ++k) v[3 * i + k] = static_cast<float>(mesh.positions[i][k]);
  for (size_t i = 0; i < mesh.triangles.size(); ++i)
    for (int k = 0; k < 3; ++k) idx[3 * i + k] = mesh.triangles[i][k];
  rtcCommitGeometry(g);
  rtcAttachGeometry(scene_, g);
  rtcReleaseGeometry(g);
  return error();
}

Status RayScene::AddSphere(const glm::dvec3& c, double r) {
  RTCGeometry g = rtcNewGeometry(device_, RTC_GEOMETRY_TYPE_SPHERE_POINT);
  auto* v = static_cast<float*>(
      rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT4, 4 * sizeof(float), 1));
  if (v == nullptr) {
    rtcReleaseGeometry(g);
    return error().ok() ? Internal("Embree: cannot allocate a sphere") : error();
  }
  v[0] = static_cast<float>(c.x);
  v[1] = static_cast<float>(c.y);
  v[2] = static_cast<float>(c.z);
  v[3] = static_cast<float>(r);
  rtcCommitGeometry(g);
  rtcAttachGeometry(scene_, g);
  rtcReleaseGeometry(g);
  return error();
}

Status RayScene::Commit(const Progress& progress) {
  // Embree polls the monitor while it builds; returning false cancels the build.
  rtcSetSceneProgressMonitorFunction(
      scene_, [](void* p, double) -> bool { return !static_cast<const Progress*>(p)->Cancelled(); },
      const_cast<Progress*>(&progress));
  rtcCommitScene(scene_);
  rtcSetSceneProgressMonitorFunction(scene_, nullptr, nullptr);
  if (progress.Cancelled()) return Cancelled("interrupted while building the ray-tracing acceleration structure");
  return error();
}

Hit RayScene::Intersect(const glm::dvec3& o, const glm::dvec3& d) const {
  RTCIntersectContext ctx;
  rtcInitIntersectContext(&ctx);
  RTCRayHit rh{};
  rh.ray.org_x = static_cast<float>(o.x);
  rh.ray.org_y = static_cast<float>(o.y);
  rh.ray.org_z = static_cast<float>(o.z);
  rh.ray.dir_x = static_cast<float>(d.x);
  rh.ray.dir_y = static_cast<float>(d.y);
  rh.ray.dir_z = static_cast<float>(d.z);
  rh.ray.tnear = 0.0f;
  rh.ray.tfar = std::numeric_limits<float>::infinity();
  rh.ray.mask = 0xFFFFFFFFu;
  rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
  rtcIntersect1(scene_, &ctx, &rh);
  Hit h;
  if (rh.hit.geomID == RTC_INVALID_GEOMETRY_ID) return h;
  h.hit = true;
  h.t = rh.ray.tfar;
  glm::dvec3 n(rh.hit.Ng_x, rh.hit.Ng_y, rh.hit.Ng_z);
  double len = glm::length(n);
  h.normal = len > 0 ? n / len : glm::dvec3(0, 0, 1);
  h.geom_id = rh.hit.geomID;
  h.prim_id = rh.hit.primID;
  h.u = rh.hit.u;
  h.v = rh.hit.v;
  return h;
}

void RayScene::Occluded(RTCRay* rays, size_t count) const {
  if (count == 0) return;
  RTCIntersectContext ctx;
  rtcInitIntersectContext(&ctx);
  ctx.flags = RTC_INTERSECT_CONTEXT_FLAG_COHERENT;  // rays of one texel share an origin and nearly a direction
  rtcOccluded1M(scene_, &ctx, rays, static_cast<unsigned>(count), sizeof(RTCRay));
}

void RayBatch::Reserve(size_t n) {
  if (tfar.size() >= n) return;
  for (auto* v : {&org_x, &org_y, &org_z, &dir_x, &dir_y, &dir_z, &tfar}) v->resize(n);
  tnear.resize(n, 0.0f);
  time.resize(n, 0.0f);
  mask.resize(n, 0xFFFFFFFFu);
  id.resize(n, 0u);
  flags.resize(n, 0u);
  origin_filled_ = 0;
}

void RayBatch::SetOrigin(float x, float y, float z, size_t n) {
  if (x != ox_ || y != oy_ || z != oz_ || std::signbit(x) != std::signbit(ox_) ||
      std::signbit(y) != std::signbit(oy_) || std::signbit(z) != std::signbit(oz_)) {
    ox_ = x;
    oy_ = y;
    oz_ = z;
    origin_filled_ = 0;
  }
  if (n <= origin_filled_) return;
  std::fill(org_x.begin() + origin_filled_, org_x.begin() + n, x);
  std::fill(org_y.begin() + origin_filled_, org_y.begin() + n, y);
  std::fill(org_z.begin() + origin_filled_, org_z.begin() + n, z);
  origin_filled_ = n;
}

void RayScene::Occluded(RayBatch& b, size_t count) const {
  if (count == 0) return;
  RTCIntersectContext ctx;
  rtcInitIntersectContext(&ctx);
  ctx.flags = RTC_INTERSECT_CONTEXT_FLAG_COHERENT;  // rays of one texel share an origin and nearly a direction
  RTCRayNp r{b.org_x.data(), b.org_y.data(), b.org_z.data(), b.tnear.data(), b.dir_x.data(), b.dir_y.data(),
             b.dir_z.data(), b.time.data(),  b.tfar.data(),  b.mask.data(),  b.id.data(),    b.flags.data()};
  rtcOccludedNp(scene_, &ctx, &r, static_cast<unsigned>(count));
}

Status RayScene::error() const {
  std::lock_guard<std::mutex> lock(mu_);
  return error_;
}

}  // namespace ltb::sample
