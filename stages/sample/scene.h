// Scene description for `ltbake sample` (docs/SCENE.md): camera or vertex output, materials,
// objects (built-in plane, box, sphere; mesh files) with transforms. Parsed strictly:
// every unknown key is an error naming its line.
#pragma once

#include <cstdint>
#include <glm/vec3.hpp>
#include <string>
#include <vector>

#include "format/status.h"
#include "stages/mesh/triangle_mesh.h"
#include "stages/sample/camera.h"

namespace ltb::sample {

// Largest cube face resolution R the sampler takes (its texel table holds 6R² entries of
// ~100 bytes); scenes, recipes and --cube-res are checked against it.
inline constexpr uint32_t kMaxCubeRes = 1024;

struct Material {
  std::string name;
  // Per channel (r, g, b): the scene's `albedo` and `ks`, a scalar meaning grey
  // (docs/COLOUR.md). What `sample --channels rgb` bakes, channel by channel.
  glm::dvec3 albedo_rgb{0.8}, ks_rgb{0.0};
  // The monochrome bake's scalars: albedo_rgb = tint·albedo and ks_rgb = tint·ks, with the
  // tint's largest channel 1 (a grey material: its own albedo and ks, tint 1). The tint goes
  // into the per-row "reflectance" table relight applies, so a coloured direct bake costs
  // no extra matrix. separable = false when no one tint fits both (a white highlight on a
  // red base): such a material needs --channels rgb in image mode, where ks is rendered.
  double albedo = 0.8;  // Lambertian reflectance, f = albedo / π
  double ks = 0.0;      // normalised Phong lobe ks (n+2)/(2π) cos^n(r·ω); image mode only
  glm::dvec3 tint{1.0};
  bool separable = true;
  double exponent = 20.0;
  // The glossy lobe's BRDF for the triple-product path (docs/TRIPLE.md): "phong" (image mode
  // renders only this one), "blinn" (exponent), "ward" (roughness α), "cook-torrance"
  // (roughness m, f0).
  std::string brdf = "phong";
  double roughness = 0.2;
  double f0 = 0.04;
  bool Grey() const { return tint == glm::dvec3(1.0); }
};

// Splits albedo_rgb and ks_rgb into tint × (albedo, ks) and sets separable (ParseScene
// calls it; exposed for tests).
void SplitColour(Material* m);

struct Object {
  enum class Type { kPlane, kBox, kSphere, kMesh } type = Type::kPlane;
  std::string name;            // for vertex mode and messages
  std::string file;            // kMesh: absolute path (resolved against the scene file)
  int material = 0;            // index into SceneDesc::materials
  glm::dvec3 size{1, 1, 1};    // plane: size.x × size.y at z = 0; box: edge lengths
  glm::dvec3 center{0, 0, 0};  // sphere centre, box centre
  double radius = 0.5;         // sphere
  glm::dvec3 translate{0, 0, 0}, rotate_degrees{0, 0, 0}, scale{1, 1, 1};
  // The shading normal (docs/SCENE.md "Normals"). kAuto: flat (the face's) in image mode,
  // smooth (area-weighted vertex normals) in vertex mode; kSmooth: those vertex normals,
  // interpolated at an image-mode hit; kFlat: the face's (image mode only); kFile: the
  // mesh file's per-vertex normals, interpolated at an image-mode hit.
  enum class Normals { kAuto, kFile, kSmooth, kFlat } normals = Normals::kAuto;
  // Mesh files only: "file" multiplies the material's albedo by the file's per-vertex
  // colours (docs/SCENE.md "Vertex colours"); "none" (the default) ignores them.
  enum class Colours { kNone, kFile } colours = Colours::kNone;
  // Mesh objects with an OBJ file only: each `usemtl NAME` in the file selects the
  // [[material]] named NAME for the faces that follow; `material` covers the faces before
  // any usemtl (docs/SCENE.md "Materials from OBJ `usemtl`"). false: usemtl is ignored.
  bool usemtl = false;
  int line = 0;  // where it is defined, for messages
};

struct SceneDesc {
  std::string path;
  enum class Mode { kImage, kVertex } mode = Mode::kImage;
  Camera camera;
  std::vector<std::string> vertex_objects;  // vertex mode: names of the objects whose vertices are rows
  std::vector<Material> materials;
  std::vector<Object> objects;
  // [sampling] defaults, overridden by the command line.
  uint32_t cube_res = 32;
  uint32_t spp = 4;
  uint32_t bounces = 0;
  uint64_t seed = 1;
  // -1: the monochrome bake (materials' scalar albedo and ks); 0, 1, 2: the scene as
  // channel r, g or b sees it (ChannelScene): vertex colours multiply the albedo there.
  int channel = -1;
};

// The scene as channel c (0 r, 1 g, 2 b) sees it: every material's albedo and ks are its
// channel-c values (tint 1), and `channel` is c. What `sample --channel` bakes.
SceneDesc ChannelScene(const SceneDesc& s, int channel);

// Reads and checks a scene. Errors name the file, the line and the key, and the value:
// unknown keys, wrong types, non-finite numbers, a degenerate camera (eye == target, a
// zero up, up parallel to the view), cube_res not a power of two in 1..kMaxCubeRes. A
// path that is a directory or not a regular file is refused as such.
Result<SceneDesc> ParseScene(const std::string& path);

// "[x, y, z]" with 9 significant digits, for messages (stages/mesh/triangle_mesh.h).
using mesh::FormatVec3;

}  // namespace ltb::sample
