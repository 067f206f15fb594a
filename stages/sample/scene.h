// Scene description for `ltbake sample` (docs/SCENE.md): camera or vertex output, materials,
// objects (built-in plane, box, sphere; mesh files) with transforms. Parsed strictly:
// every unknown key is an error naming its line.
#pragma once

#include <cstdint>
#include <glm/vec3.hpp>
#include <string>
#include <vector>

#include "format/status.h"

namespace ltb::sample {

// Largest cube face resolution R the sampler takes (its texel table holds 6R² entries of
// ~100 bytes); scenes, recipes and --cube-res are checked against it.
inline constexpr uint32_t kMaxCubeRes = 1024;

struct Material {
  std::string name;
  double albedo = 0.8;  // Lambertian reflectance, f = albedo / π
  double ks = 0.0;      // normalised Phong lobe ks (n+2)/(2π) cos^n(r·ω); image mode only
  double exponent = 20.0;
  // The glossy lobe's BRDF for the triple-product path (docs/TRIPLE.md): "phong" (image mode
  // renders only this one), "blinn" (exponent), "ward" (roughness α), "cook-torrance"
  // (roughness m, f0).
  std::string brdf = "phong";
  double roughness = 0.2;
  double f0 = 0.04;
};

struct Camera {
  glm::dvec3 eye{0, -3, 1.5}, target{0, 0, 0}, up{0, 0, 1};
  double fov_degrees = 40.0;  // vertical
  uint32_t width = 64, height = 64;
};

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
};

// Reads and checks a scene. Errors name the file, the line and the key, and the value:
// unknown keys, wrong types, non-finite numbers, a degenerate camera (eye == target, a
// zero up, up parallel to the view), cube_res not a power of two in 1..kMaxCubeRes. A
// path that is a directory or not a regular file is refused as such.
Result<SceneDesc> ParseScene(const std::string& path);

// "[x, y, z]" with 9 significant digits, for messages.
std::string FormatVec3(const glm::dvec3& v);

}  // namespace ltb::sample
