// The sampler's scene side: the parsed scene's Embree geometry, the material of each
// Embree geometry, the rows of vertex mode, the ray offset ε and the scene's content hash.
#pragma once

#include <cstdint>
#include <glm/mat4x4.hpp>
#include <glm/vec3.hpp>
#include <memory>
#include <string>
#include <vector>

#include "format/progress.h"
#include "format/status.h"
#include "stages/sample/ray_scene.h"
#include "stages/sample/scene.h"

namespace ltb::sample {

// An object's placement: scale, rotate (degrees about x, then y, then z), translate.
glm::dmat4 ObjectTransform(const Object& o);

// A row's point: p, normal n (facing the camera in image mode), direction to the viewer
// ω_o and material; valid = false for a pixel that sees no geometry.
struct RowPoint {
  bool valid = false;
  glm::dvec3 p{0}, n{0, 0, 1}, wo{0, 0, 1};
  int material = 0;
  glm::dvec3 colour{1.0};  // the vertex colour there (objects with colours = "file"), else 1
};

// Per-vertex shading normals of one mesh (image mode, normals = "smooth" or "file"): the
// triangles as Embree holds them (primitive id -> vertex ids) and a unit normal per vertex.
struct ShadingNormals {
  std::vector<glm::uvec3> triangles;
  std::vector<glm::dvec3> normals;
};

// One Embree geometry per object, except an object with usemtl = true: one per material its
// triangles use (in order of first appearance), each with all the object's vertices and
// that material's triangles. Every per-geometry vector below has one entry per Embree
// geometry id.
struct Geometry {
  std::unique_ptr<RayScene> rays;
  std::vector<int> geom_material;  // Embree geometry id -> material
  std::vector<int> geom_object;    // Embree geometry id -> index into SceneDesc::objects
  // Embree geometry id -> shading normals; an empty entry (or none): the geometric normal.
  std::vector<ShadingNormals> shading;
  // Embree geometry id -> per-vertex colours (colours = "file"; docs/COLOUR.md) with the
  // triangles as Embree holds them; an empty entry (or none): colour 1.
  struct VertexColours {
    std::vector<glm::uvec3> triangles;
    std::vector<glm::dvec3> colours;
  };
  std::vector<VertexColours> colours;
  std::vector<RowPoint> vertex_rows;
  // Vertex mode, per Embree geometry id: the first vertex row of its object and its
  // triangles (primitive id -> vertex ids within the object), for renderers that shade by
  // vertex; empty triangles for an object whose vertices are not rows. The geometries of
  // one usemtl object share first_row: its vertices are rows once.
  struct RowMesh {
    uint64_t first_row = 0;
    std::vector<glm::uvec3> triangles;
  };
  std::vector<RowMesh> row_meshes;
  double epsilon = 1e-4;
  uint64_t degenerate = 0;
  std::string scene_hash;
  // XXH3 of what rays see and what the vertex rows are — every object's transformed
  // triangles (and spheres), each vertex row's position and normal — but not the materials:
  // the triple-product renderer checks it, so materials may change after the visibility bake
  // (how a usemtl object's triangles split by material does not enter it either).
  std::string geometry_hash;

  // The unit shading normal at a hit, not oriented: the vertex normals interpolated with the
  // hit's barycentrics, normalize((1−u−v)·n0 + u·n1 + v·n2), for a geometry that has them;
  // else (or when they cancel) the geometric normal.
  glm::dvec3 ShadingNormal(const Hit& h) const;
  // The vertex colour at a hit, (1−u−v)·c0 + u·c1 + v·c2, for a geometry that has them; else 1.
  glm::dvec3 HitColour(const Hit& h) const;
};

// Loads every object of the scene into one committed Embree scene. Every object's
// coordinates after its transform must be finite in single precision (what Embree
// traces); Cancelled when `progress` asks to stop (mesh reading, the BVH build).
Result<Geometry> BuildGeometry(const SceneDesc& s, const Progress& progress = Progress{});

}  // namespace ltb::sample
