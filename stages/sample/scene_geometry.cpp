#include "stages/sample/scene_geometry.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <glm/geometric.hpp>
#include <glm/gtc/matrix_transform.hpp>
#include <limits>
#include <memory>
#include <tuple>

#include "format/io/file_hash.h"
#include "format/version.h"
#include "stages/mesh/triangle_mesh.h"
#include "stages/sample/sample.h"

namespace ltb::sample {

glm::dmat4 ObjectTransform(const Object& o) {
  glm::dmat4 m(1.0);
  m = glm::translate(m, o.translate);
  m = glm::rotate(m, glm::radians(o.rotate_degrees.z), glm::dvec3(0, 0, 1));
  m = glm::rotate(m, glm::radians(o.rotate_degrees.y), glm::dvec3(0, 1, 0));
  m = glm::rotate(m, glm::radians(o.rotate_degrees.x), glm::dvec3(1, 0, 0));
  m = glm::scale(m, o.scale);
  return m;
}

using namespace ltb::format;

namespace {

// Within what Embree traces (sample::kMaxTraceCoordinate): rays start on the geometry.
bool Traceable(double x) { return std::fabs(x) <= kMaxTraceCoordinate; }

std::string TraceLimit() {
  char b[32];
  std::snprintf(b, sizeof b, "%g", kMaxTraceCoordinate);
  return b;
}

bool IsRowObject(const SceneDesc& s, const Object& o) {
  return s.mode == SceneDesc::Mode::kVertex &&
         std::find(s.vertex_objects.begin(), s.vertex_objects.end(), o.name) != s.vertex_objects.end();
}

// The object's vertex rows (vertex mode, an object [output] objects lists), after its
// transform: one per vertex, with the file's normal for normals = "file", else the
// area-weighted one; the material vertex_material[i] (empty: the object's); the vertex
// colour. Returns the object's first row (the rows so far, whether or not it adds any).
uint64_t AddRows(const SceneDesc& s, const Object& o, const mesh::TriangleMesh& mesh,
                 const std::vector<int>& vertex_material, Geometry* g) {
  const uint64_t first_row = g->vertex_rows.size();
  if (!IsRowObject(s, o)) return first_row;
  const std::vector<glm::dvec3>& n = o.normals == Object::Normals::kFile ? mesh.file_normals : mesh.normals;
  for (size_t i = 0; i < mesh.positions.size(); ++i) {
    g->vertex_rows.push_back({true, mesh.positions[i], n[i], n[i],
                              vertex_material.empty() ? o.material : vertex_material[i],
                              mesh.colours.empty() ? glm::dvec3(1.0) : mesh.colours[i]});
  }
  return first_row;
}

// The entries of one Embree geometry of object `object`, holding `triangles` of its mesh
// (all of them, or those of one material): its shading normals at hits (primary hits in
// image mode, bounce hits in both modes) for "smooth" or "file", an empty entry otherwise
// (the geometric normal); its vertex colours; its Geometry::RowMesh (`first_row`: the
// object's); its material and object.
void AddEntries(const SceneDesc& s, size_t object, int material, const mesh::TriangleMesh& mesh,
                const std::vector<glm::uvec3>& triangles, uint64_t first_row, Geometry* g) {
  const Object& o = s.objects[object];
  const bool file = o.normals == Object::Normals::kFile;
  Geometry::RowMesh rm;
  rm.first_row = first_row;
  if (IsRowObject(s, o)) rm.triangles = triangles;
  ShadingNormals sh;
  if (file || o.normals == Object::Normals::kSmooth) {
    sh.triangles = triangles;
    sh.normals = file ? mesh.file_normals : mesh.normals;
  }
  g->shading.push_back(std::move(sh));
  g->row_meshes.push_back(std::move(rm));
  Geometry::VertexColours vc;
  if (!mesh.colours.empty()) {
    vc.triangles = triangles;
    vc.colours = mesh.colours;
  }
  g->colours.push_back(std::move(vc));
  g->geom_material.push_back(material);
  g->geom_object.push_back(static_cast<int>(object));
}

// usemtl = true: the scene material of each of the mesh's usemtl groups that holds a
// triangle (-1 for the others): group 0 (the faces before any usemtl) the object's, every
// other the [[material]] its name names; a name no [[material]] defines is an error.
Result<std::vector<int>> GroupMaterials(const SceneDesc& s, const Object& o, const mesh::TriangleMesh& mesh,
                                        const std::string& where) {
  std::vector<char> used(mesh.group_names.size(), 0);
  for (uint32_t k : mesh.triangle_group) used[k] = 1;
  std::vector<int> material(mesh.group_names.size(), -1);
  for (size_t k = 0; k < used.size(); ++k) {
    if (!used[k]) continue;  // a usemtl no face follows (the Cornell box's "light"): ignored
    if (k == 0) {
      material[k] = o.material;
      continue;
    }
    const std::string& name = mesh.group_names[k];
    for (size_t m = 0; m < s.materials.size() && material[k] < 0; ++m)
      if (s.materials[m].name == name) material[k] = static_cast<int>(m);
    if (material[k] >= 0) continue;
    std::string names;
    for (const Material& m : s.materials) names += (names.empty() ? "\"" : ", \"") + m.name + "\"";
    return InvalidArgument(where + ": " + o.file + ":" + std::to_string(mesh.group_lines[k]) + ": usemtl \"" + name +
                           "\" names no [[material]] of the scene (it has " + names +
                           "); add a [[material]] with name = \"" + name + "\", or leave usemtl out of the object");
  }
  return material;
}

// The object's mesh, after its transform, as Embree geometry with its rows and entries:
// one geometry, or with usemtl = true one per material its triangles use, in order of first
// appearance, each with all the vertices (Embree copies them) and that material's triangles;
// a vertex row's material is then that of the first triangle (in file order) using it.
Status AddMeshObject(const SceneDesc& s, size_t object, const std::string& where, mesh::TriangleMesh* mesh,
                     Geometry* g) {
  const Object& o = s.objects[object];
  if (!o.usemtl) {
    LTB_RETURN_IF_ERROR(g->rays->AddMesh(*mesh));
    const uint64_t first_row = AddRows(s, o, *mesh, {}, g);
    AddEntries(s, object, o.material, *mesh, mesh->triangles, first_row, g);
    return Status::Ok();
  }
  if (mesh->triangle_group.size() != mesh->triangles.size()) {
    return Internal(where + ": " + std::to_string(mesh->triangle_group.size()) + " usemtl groups for " +
                    std::to_string(mesh->triangles.size()) + " triangles");
  }
  LTB_ASSIGN_OR_RETURN(std::vector<int> group_material, GroupMaterials(s, o, *mesh, where));
  std::vector<int> part_of(s.materials.size(), -1), part_material;
  std::vector<std::vector<glm::uvec3>> parts;
  std::vector<int> vertex_material(mesh->positions.size(), -1);
  for (size_t i = 0; i < mesh->triangles.size(); ++i) {
    const int m = group_material[mesh->triangle_group[i]];
    if (part_of[m] < 0) {
      part_of[m] = static_cast<int>(parts.size());
      part_material.push_back(m);
      parts.emplace_back();
    }
    const glm::uvec3& t = mesh->triangles[i];
    parts[part_of[m]].push_back(t);
    for (int k = 0; k < 3; ++k)
      if (vertex_material[t[k]] < 0) vertex_material[t[k]] = m;
  }
  for (int& m : vertex_material)
    if (m < 0) m = o.material;  // no triangle uses the vertex
  const uint64_t first_row = AddRows(s, o, *mesh, vertex_material, g);
  for (size_t p = 0; p < parts.size(); ++p) {
    std::swap(mesh->triangles, parts[p]);  // the part's triangles over all the vertices
    Status added = g->rays->AddMesh(*mesh);
    std::swap(mesh->triangles, parts[p]);
    LTB_RETURN_IF_ERROR(added);
    AddEntries(s, object, part_material[p], *mesh, parts[p], first_row, g);
  }
  return Status::Ok();
}

// Geometry::geometry_hash: every object's type, transform, shape parameters, normals mode and
// mesh file bytes, in order, then the vertex rows and their triangles.
std::string GeometryHash(const SceneDesc& s, const Geometry& g) {
  io::StreamHash st;
  auto add = [&](const void* p, size_t n) { st.AddBytes(p, n); };
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
    if (o.type == Object::Type::kMesh) (void)st.AddFile(o.file);  // read once already: it opens
    if (o.usemtl) {  // only when set: the hashes of scenes without it stay what they were
      static const char kUsemtl[] = "usemtl";
      add(kUsemtl, sizeof kUsemtl);
    }
  }
  for (const RowPoint& r : g.vertex_rows) {
    add(&r.p, sizeof r.p);
    add(&r.n, sizeof r.n);
  }
  for (size_t id = 0; id < g.row_meshes.size();) {
    const int object = g.geom_object[id];
    if (!s.objects[static_cast<size_t>(object)].usemtl) {
      const Geometry::RowMesh& m = g.row_meshes[id++];
      add(&m.first_row, sizeof m.first_row);
      add(m.triangles.data(), m.triangles.size() * sizeof(glm::uvec3));
      continue;
    }
    // A usemtl object's geometries (consecutive ids) as one: its row triangles sorted, so
    // that how the materials split them (which the object's "material" can change) does not
    // enter the hash.
    add(&g.row_meshes[id].first_row, sizeof g.row_meshes[id].first_row);
    std::vector<glm::uvec3> all;
    for (; id < g.row_meshes.size() && g.geom_object[id] == object; ++id)
      all.insert(all.end(), g.row_meshes[id].triangles.begin(), g.row_meshes[id].triangles.end());
    std::sort(all.begin(), all.end(), [](const glm::uvec3& a, const glm::uvec3& b) {
      return std::tie(a.x, a.y, a.z) < std::tie(b.x, b.y, b.z);
    });
    add(all.data(), all.size() * sizeof(glm::uvec3));
  }
  return st.Hex();
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
  io::StreamHash st;
  Status hs = st.AddFile(s.path);
  glm::dvec3 lo(std::numeric_limits<double>::infinity()), hi(-std::numeric_limits<double>::infinity());
  for (size_t object = 0; object < s.objects.size(); ++object) {
    const Object& o = s.objects[object];
    std::string where = s.path + ":" + std::to_string(o.line) + ": object \"" + o.name + "\"";
    if (o.type == Object::Type::kSphere) {
      glm::dvec3 sc = glm::abs(o.scale);
      if (std::fabs(sc.x - sc.y) > 1e-12 * sc.x || std::fabs(sc.x - sc.z) > 1e-12 * sc.x) {
        return InvalidArgument(where + ": a sphere needs a uniform scale");
      }
      glm::dvec3 c = glm::dvec3(sample::ObjectTransform(o) * glm::dvec4(o.center, 1.0));
      double r = o.radius * sc.x;
      if (!Traceable(c.x) || !Traceable(c.y) || !Traceable(c.z) || !Traceable(r) || !(r > 0) ||
          !Traceable(std::fabs(c.x) + r) || !Traceable(std::fabs(c.y) + r) || !Traceable(std::fabs(c.z) + r)) {
        return InvalidArgument(where + ": after its transform the sphere has centre " + FormatVec3(c) + " and radius " +
                               std::to_string(r) + ", outside what ray tracing holds (each coordinate within ±" +
                               TraceLimit() +
                               "); reduce "
                               "\"scale\", \"translate\", \"center\" or \"radius\"");
      }
      LTB_RETURN_IF_ERROR(g.rays->AddSphere(c, r));
      lo = glm::min(lo, c - r);
      hi = glm::max(hi, c + r);
      g.shading.emplace_back();  // a sphere's normal is its exact geometric one
      g.row_meshes.emplace_back();
      g.colours.emplace_back();
      g.geom_material.push_back(o.material);
      g.geom_object.push_back(static_cast<int>(object));
    } else {
      mesh::TriangleMesh mesh;
      if (o.type == Object::Type::kMesh) {
        auto loaded = mesh::LoadMeshFile(o.file, progress, o.normals == Object::Normals::kFile,
                                         o.colours == Object::Colours::kFile, o.usemtl);
        if (!loaded.ok()) return loaded.status().WithContext(where);
        mesh = std::move(loaded).value();
        if (hs.ok()) hs = st.AddFile(o.file);
      } else if (o.type == Object::Type::kPlane) {
        mesh = mesh::MakePlane(o.size);
      } else {
        mesh = mesh::MakeBox(o.size, o.center);
      }
      g.degenerate += mesh.degenerate_dropped;
      mesh::ApplyTransform(sample::ObjectTransform(o), &mesh);
      for (size_t i = 0; i < mesh.positions.size(); ++i) {
        const glm::dvec3& p = mesh.positions[i];
        if (!Traceable(p.x) || !Traceable(p.y) || !Traceable(p.z)) {
          return InvalidArgument(where + ": vertex " + std::to_string(i) + " is " + FormatVec3(p) +
                                 " after the object's transform, outside what ray tracing holds (each coordinate " +
                                 "within ±" + TraceLimit() + "); reduce \"scale\" or \"translate\"");
        }
      }
      if (mesh.triangles.empty()) {
        return InvalidArgument(where + ": has no triangles left after its transform (zero scale?)");
      }
      LTB_RETURN_IF_ERROR(AddMeshObject(s, object, where, &mesh, &g));
      for (const auto& p : mesh.positions) {
        lo = glm::min(lo, p);
        hi = glm::max(hi, p);
      }
    }
  }
  if (s.mode == SceneDesc::Mode::kVertex) {
    for (const Object& o : s.objects) {
      if (o.type == Object::Type::kSphere &&
          std::find(s.vertex_objects.begin(), s.vertex_objects.end(), o.name) != s.vertex_objects.end()) {
        return InvalidArgument(s.path + ":" + std::to_string(o.line) + ": object \"" + o.name +
                               "\" is a sphere, which has no vertices to be rows");
      }
    }
  }
  LTB_RETURN_IF_ERROR(hs);
  g.scene_hash = st.Hex();
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
  io::StreamHash st;
  Status s = st.AddFile(scene.path);  // the same bytes, in the same order, as BuildGeometry
  for (const sample::Object& obj : scene.objects) {
    if (s.ok() && obj.type == sample::Object::Type::kMesh) s = st.AddFile(obj.file);
  }
  LTB_RETURN_IF_ERROR(s);
  return st.Hex();
}

}  // namespace ltb::stages
