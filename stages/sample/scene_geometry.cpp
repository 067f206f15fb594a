#include "stages/sample/scene_geometry.h"

#include <xxhash.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <glm/geometric.hpp>
#include <limits>

#include "format/version.h"
#include "stages/sample/geometry.h"
#include "stages/sample/sample.h"

namespace ltb::sample {

using namespace ltb::format;

namespace {

Status HashFile(const std::string& path, XXH3_state_t* st) {
  std::ifstream f(path, std::ios::binary);
  if (!f) return NotFound(path + ": cannot open");
  std::vector<char> buf(1 << 16);
  while (f) {
    f.read(buf.data(), static_cast<std::streamsize>(buf.size()));
    XXH3_64bits_update(st, buf.data(), static_cast<size_t>(f.gcount()));
  }
  return Status::Ok();
}

}  // namespace

namespace {

bool FloatFinite(double x) { return std::isfinite(static_cast<float>(x)); }

bool IsRowObject(const SceneDesc& s, const Object& o) {
  return s.mode == SceneDesc::Mode::kVertex &&
         std::find(s.vertex_objects.begin(), s.vertex_objects.end(), o.name) != s.vertex_objects.end();
}

// The object's normals after its transform: its vertex rows (vertex mode: the file's
// normals for normals = "file", else the area-weighted ones) and its shading normals at
// hits (primary hits in image mode, bounce hits in both modes) for "smooth" or "file"; an
// empty entry otherwise (the geometric normal); and its Geometry::RowMesh.
void AddNormals(const SceneDesc& s, const Object& o, TriangleMesh& mesh, Geometry* g) {
  const bool file = o.normals == Object::Normals::kFile;
  const std::vector<glm::dvec3>& n = file ? mesh.file_normals : mesh.normals;
  Geometry::RowMesh rm;
  rm.first_row = g->vertex_rows.size();
  if (IsRowObject(s, o)) {
    rm.triangles = mesh.triangles;
    for (size_t i = 0; i < mesh.positions.size(); ++i) {
      g->vertex_rows.push_back(
          {true, mesh.positions[i], n[i], n[i], o.material, mesh.colours.empty() ? glm::dvec3(1.0) : mesh.colours[i]});
    }
  }
  ShadingNormals sh;
  if (file || o.normals == Object::Normals::kSmooth) {
    sh.triangles = mesh.triangles;
    sh.normals = n;
  }
  g->shading.push_back(std::move(sh));
  g->row_meshes.push_back(std::move(rm));
  Geometry::VertexColours vc;
  if (!mesh.colours.empty()) {
    vc.triangles = mesh.triangles;
    vc.colours = mesh.colours;
  }
  g->colours.push_back(std::move(vc));
}

// Geometry::geometry_hash: every object's type, transform, shape parameters, normals mode and
// mesh file bytes, in order, then the vertex rows and their triangles.
std::string GeometryHash(const SceneDesc& s, const Geometry& g) {
  XXH3_state_t* st = XXH3_createState();
  XXH3_64bits_reset(st);
  auto add = [&](const void* p, size_t n) { XXH3_64bits_update(st, p, n); };
  for (const Object& o : s.objects) {
    const int type = static_cast<int>(o.type);
    add(&type, sizeof type);
    const glm::dmat4 m = ObjectTransform(o);
    add(&m, sizeof m);
    add(&o.size, sizeof o.size);
    add(&o.center, sizeof o.center);
    add(&o.radius, sizeof o.radius);
    const int normals = static_cast<int>(o.normals);
    add(&normals, sizeof normals);
    if (o.type == Object::Type::kMesh) (void)HashFile(o.file, st);  // read once already: it opens
  }
  for (const RowPoint& r : g.vertex_rows) {
    add(&r.p, sizeof r.p);
    add(&r.n, sizeof r.n);
  }
  for (const Geometry::RowMesh& m : g.row_meshes) {
    add(&m.first_row, sizeof m.first_row);
    add(m.triangles.data(), m.triangles.size() * sizeof(glm::uvec3));
  }
  const uint64_t h = XXH3_64bits_digest(st);
  XXH3_freeState(st);
  return Hex64(h).substr(2);
}

}  // namespace

glm::dvec3 Geometry::ShadingNormal(const Hit& h) const {
  if (h.geom_id >= shading.size() || shading[h.geom_id].normals.empty()) return h.normal;
  const ShadingNormals& sh = shading[h.geom_id];
  if (h.prim_id >= sh.triangles.size()) return h.normal;
  const glm::uvec3& t = sh.triangles[h.prim_id];
  const glm::dvec3 n = (1 - h.u - h.v) * sh.normals[t[0]] + h.u * sh.normals[t[1]] + h.v * sh.normals[t[2]];
  const double len = glm::length(n);
  return len > 0 && std::isfinite(len) ? n / len : h.normal;
}

glm::dvec3 Geometry::HitColour(const Hit& h) const {
  if (h.geom_id >= colours.size() || colours[h.geom_id].colours.empty()) return glm::dvec3(1.0);
  const VertexColours& vc = colours[h.geom_id];
  if (h.prim_id >= vc.triangles.size()) return glm::dvec3(1.0);
  const glm::uvec3& t = vc.triangles[h.prim_id];
  return (1 - h.u - h.v) * vc.colours[t[0]] + h.u * vc.colours[t[1]] + h.v * vc.colours[t[2]];
}

Result<Geometry> BuildGeometry(const SceneDesc& s, const Progress& progress) {
  Geometry g;
  LTB_ASSIGN_OR_RETURN(g.rays, RayScene::Create());
  XXH3_state_t* st = XXH3_createState();
  XXH3_64bits_reset(st);
  Status hs = HashFile(s.path, st);
  glm::dvec3 lo(std::numeric_limits<double>::infinity()), hi(-std::numeric_limits<double>::infinity());
  for (const Object& o : s.objects) {
    std::string where = s.path + ":" + std::to_string(o.line) + ": object \"" + o.name + "\"";
    if (o.type == Object::Type::kSphere) {
      glm::dvec3 sc = glm::abs(o.scale);
      if (std::fabs(sc.x - sc.y) > 1e-12 * sc.x || std::fabs(sc.x - sc.z) > 1e-12 * sc.x) {
        XXH3_freeState(st);
        return InvalidArgument(where + ": a sphere needs a uniform scale");
      }
      glm::dvec3 c = glm::dvec3(sample::ObjectTransform(o) * glm::dvec4(o.center, 1.0));
      double r = o.radius * sc.x;
      if (!FloatFinite(c.x) || !FloatFinite(c.y) || !FloatFinite(c.z) || !FloatFinite(r) || !(r > 0)) {
        XXH3_freeState(st);
        return InvalidArgument(where + ": after its transform the sphere has centre " + FormatVec3(c) + " and radius " +
                               std::to_string(r) +
                               ", outside what single-precision ray tracing holds; reduce "
                               "\"scale\", \"translate\", \"center\" or \"radius\"");
      }
      LTB_RETURN_IF_ERROR(g.rays->AddSphere(c, r));
      lo = glm::min(lo, c - r);
      hi = glm::max(hi, c + r);
      g.shading.emplace_back();  // a sphere's normal is its exact geometric one
      g.row_meshes.emplace_back();
      g.colours.emplace_back();
    } else {
      sample::TriangleMesh mesh;
      if (o.type == Object::Type::kMesh) {
        auto loaded = sample::LoadMeshFile(o.file, progress, o.normals == Object::Normals::kFile,
                                           o.colours == Object::Colours::kFile);
        if (!loaded.ok()) {
          XXH3_freeState(st);
          return loaded.status().WithContext(where);
        }
        mesh = std::move(loaded).value();
        if (hs.ok()) hs = HashFile(o.file, st);
      } else if (o.type == Object::Type::kPlane) {
        mesh = sample::MakePlane(o.size);
      } else {
        mesh = sample::MakeBox(o.size, o.center);
      }
      g.degenerate += mesh.degenerate_dropped;
      sample::ApplyTransform(sample::ObjectTransform(o), &mesh);
      for (size_t i = 0; i < mesh.positions.size(); ++i) {
        const glm::dvec3& p = mesh.positions[i];
        if (!FloatFinite(p.x) || !FloatFinite(p.y) || !FloatFinite(p.z)) {
          XXH3_freeState(st);
          return InvalidArgument(where + ": vertex " + std::to_string(i) + " is " + FormatVec3(p) +
                                 " after the object's transform, outside what single-precision ray tracing holds; "
                                 "reduce \"scale\" or \"translate\"");
        }
      }
      if (mesh.triangles.empty()) {
        XXH3_freeState(st);
        return InvalidArgument(where + ": has no triangles left after its transform (zero scale?)");
      }
      LTB_RETURN_IF_ERROR(g.rays->AddMesh(mesh));
      for (const auto& p : mesh.positions) {
        lo = glm::min(lo, p);
        hi = glm::max(hi, p);
      }
      AddNormals(s, o, mesh, &g);
    }
    g.geom_material.push_back(o.material);
  }
  if (s.mode == SceneDesc::Mode::kVertex) {
    for (const Object& o : s.objects) {
      if (o.type == Object::Type::kSphere &&
          std::find(s.vertex_objects.begin(), s.vertex_objects.end(), o.name) != s.vertex_objects.end()) {
        XXH3_freeState(st);
        return InvalidArgument(s.path + ":" + std::to_string(o.line) + ": object \"" + o.name +
                               "\" is a sphere, which has no vertices to be rows");
      }
    }
  }
  uint64_t h = XXH3_64bits_digest(st);
  XXH3_freeState(st);
  LTB_RETURN_IF_ERROR(hs);
  g.scene_hash = Hex64(h).substr(2);
  g.geometry_hash = GeometryHash(s, g);
  LTB_RETURN_IF_ERROR(g.rays->Commit(progress));
  g.epsilon = std::max(1e-6, 1e-5 * glm::length(hi - lo));
  return g;
}

}  // namespace ltb::sample

namespace ltb::stages {

using namespace ltb::format;

Result<std::string> SceneHash(const std::string& scene_path) {
  LTB_ASSIGN_OR_RETURN(sample::SceneDesc scene, sample::ParseScene(scene_path));
  XXH3_state_t* st = XXH3_createState();
  XXH3_64bits_reset(st);
  Status s = sample::HashFile(scene.path, st);  // the same bytes, in the same order, as BuildGeometry
  for (const sample::Object& obj : scene.objects) {
    if (s.ok() && obj.type == sample::Object::Type::kMesh) s = sample::HashFile(obj.file, st);
  }
  uint64_t h = XXH3_64bits_digest(st);
  XXH3_freeState(st);
  LTB_RETURN_IF_ERROR(s);
  return Hex64(h).substr(2);
}

}  // namespace ltb::stages
