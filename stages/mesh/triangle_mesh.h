// Triangle meshes: mesh files (our own readers for OFF, PLY, OBJ and STL,
// stages/mesh/mesh_reader.h; Draco for .drc), built-in primitives and transforms. Knows
// nothing of scenes (stages/sample places meshes in one).
#pragma once

#include <cstdint>
#include <glm/mat4x4.hpp>
#include <glm/vec3.hpp>
#include <string>
#include <vector>

#include "format/progress.h"
#include "format/status.h"

namespace ltb::mesh {

struct TriangleMesh {
  std::vector<glm::dvec3> positions;
  std::vector<glm::uvec3> triangles;
  std::vector<glm::dvec3> normals;  // per vertex, unit (area-weighted face normals)
  // Per vertex, the normals the file stores (normals = "file"); empty unless the reader was
  // asked for them. LoadMeshFile leaves them unit length; ApplyTransform transforms them.
  std::vector<glm::dvec3> file_normals;
  // Per vertex, the colours the file stores as linear RGB (colours = "file", docs/SCENE.md
  // "Vertex colours"); empty unless the reader was asked for them. ApplyTransform and
  // Finalize keep them (the vertices do not change).
  std::vector<glm::dvec3> colours;
  // OBJ `usemtl` groups (docs/SCENE.md "Materials from OBJ `usemtl`"); empty unless the
  // reader was asked for them. group_names: the distinct usemtl names in order of first
  // appearance, after group 0, "" (the faces before any usemtl); group_lines: per group,
  // the file line of the usemtl statement that selected its first triangle (the first
  // usemtl naming it if none did; 0 for group 0); triangle_group: per triangle, aligned
  // with `triangles` (every triangle of a fan-triangulated face has the face's group).
  // Finalize keeps triangle_group aligned when it drops triangles.
  std::vector<std::string> group_names;
  std::vector<uint64_t> group_lines;
  std::vector<uint32_t> triangle_group;
  uint64_t degenerate_dropped = 0;  // zero-area or repeated-vertex faces removed
};

// Loads a mesh file; polygons are triangulated. Fails naming the file and the reason when
// it is not a regular file, cannot be read, holds no triangles, has a non-finite vertex or
// a face with an out-of-range vertex index; Cancelled when `progress` asks to stop. With
// `file_normals`, also the per-vertex normals the file stores (docs/SCENE.md "Normals"):
// a format that stores none (STL), a file without them, or a vertex whose normal is
// missing, zero or not finite is an error naming the file (and the vertex). With
// `file_colours`, also the per-vertex colours the file stores, as linear RGB (docs/SCENE.md
// "Vertex colours"): a format that stores none (STL), or a file without them, is an error
// naming the file and saying what to add. With `groups` (OBJ only; any other format is an
// error naming the file), also the usemtl groups (TriangleMesh::group_names).
Result<TriangleMesh> LoadMeshFile(const std::string& path, const Progress& progress = Progress{},
                                  bool file_normals = false, bool file_colours = false, bool groups = false);

// "[1, 2, 3]" (each %.9g), for messages.
std::string FormatVec3(const glm::dvec3& v);

TriangleMesh MakePlane(const glm::dvec3& size);  // size.x × size.y at z = 0, normal +z
TriangleMesh MakeBox(const glm::dvec3& size, const glm::dvec3& center);

// Positions by m; file normals by the inverse transpose of m's 3×3 part, renormalised (so
// they stay perpendicular to the surface under a non-uniform scale); then Finalize.
void ApplyTransform(const glm::dmat4& m, TriangleMesh* mesh);
// Drops zero-area triangles (counting them), and their triangle_group entries when the mesh
// has groups, and recomputes vertex normals.
void Finalize(TriangleMesh* mesh);

}  // namespace ltb::mesh
