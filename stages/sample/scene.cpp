#include "stages/sample/scene.h"

#include <toml++/toml.h>

#include <algorithm>
#include <bit>
#include <cctype>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <glm/geometric.hpp>
#include <glm/trigonometric.hpp>
#include <map>
#include <set>

#include "stages/common/toml_fields.h"

namespace ltb::sample {
namespace {

using tomlf::CheckKeys;
using tomlf::GetBool;
using tomlf::GetNumber;
using tomlf::GetString;
using tomlf::GetUnsigned;
using tomlf::GetVec3;
using tomlf::Where;

// The camera must give Embree a well-defined frame (ValidateView); its message gets the
// scene file's line of the key it is about.
Status CheckCamera(const std::string& path, const toml::table& cam, const Camera& c) {
  Status s = ValidateView(c.eye, c.target, c.up, c.fov_degrees);
  if (s.ok()) return s;
  const std::string& m = s.message();
  std::string key = m.substr(0, m.find(' '));  // "eye", "target", "up" or "fov"
  if (m.find(" equals target ") != std::string::npos && cam.contains("target")) key = "target";
  const toml::node* n = cam.get(key);
  return InvalidArgument((n != nullptr ? Where(path, *n) : Where(path, cam)) + ": [camera] " + m);
}

}  // namespace

namespace {

// [output]: the mode and, for vertex mode, the objects whose vertices are rows.
Status ParseOutput(const std::string& path, const toml::table& root, SceneDesc* s) {
  if (const toml::table* out = root["output"].as_table()) {
    LTB_RETURN_IF_ERROR(CheckKeys(path, *out, "[output]", {"mode", "objects"}));
    LTB_ASSIGN_OR_RETURN(std::string mode, GetString(path, *out, "mode", "image"));
    if (mode == "image")
      s->mode = SceneDesc::Mode::kImage;
    else if (mode == "vertex")
      s->mode = SceneDesc::Mode::kVertex;
    else
      return InvalidArgument(Where(path, *out->get("mode")) + ": mode is \"" + mode +
                             "\" (expected \"image\" or \"vertex\")");
    if (const toml::array* objs = (*out)["objects"].as_array()) {
      for (const auto& n : *objs) {
        auto name = n.value<std::string>();
        if (!name) return InvalidArgument(Where(path, n) + ": [output] objects must be a list of object names");
        s->vertex_objects.push_back(*name);
      }
    }
  }
  return Status::Ok();
}

// [camera] (required in image mode).
Status ParseCamera(const std::string& path, const toml::table& root, SceneDesc* s) {
  if (const toml::table* cam = root["camera"].as_table()) {
    LTB_RETURN_IF_ERROR(CheckKeys(path, *cam, "[camera]", {"eye", "target", "up", "fov", "width", "height"}));
    LTB_ASSIGN_OR_RETURN(s->camera.eye, GetVec3(path, *cam, "eye", s->camera.eye));
    LTB_ASSIGN_OR_RETURN(s->camera.target, GetVec3(path, *cam, "target", s->camera.target));
    LTB_ASSIGN_OR_RETURN(s->camera.up, GetVec3(path, *cam, "up", s->camera.up));
    LTB_ASSIGN_OR_RETURN(s->camera.fov_degrees, GetNumber(path, *cam, "fov", s->camera.fov_degrees, 1.0, 179.0));
    LTB_ASSIGN_OR_RETURN(uint64_t w, GetUnsigned(path, *cam, "width", s->camera.width, 1, 1 << 16));
    LTB_ASSIGN_OR_RETURN(uint64_t h, GetUnsigned(path, *cam, "height", s->camera.height, 1, 1 << 16));
    s->camera.width = static_cast<uint32_t>(w);
    s->camera.height = static_cast<uint32_t>(h);
    LTB_RETURN_IF_ERROR(CheckCamera(path, *cam, s->camera));
  } else if (s->mode == SceneDesc::Mode::kImage) {
    return InvalidArgument(path + ": image mode needs a [camera] table");
  }
  return Status::Ok();
}

// [sampling]: the defaults the command line overrides.
Status ParseSampling(const std::string& path, const toml::table& root, SceneDesc* s) {
  if (const toml::table* smp = root["sampling"].as_table()) {
    LTB_RETURN_IF_ERROR(CheckKeys(path, *smp, "[sampling]", {"cube_res", "spp", "bounces", "seed"}));
    LTB_ASSIGN_OR_RETURN(uint64_t r, GetUnsigned(path, *smp, "cube_res", s->cube_res, 1, kMaxCubeRes));
    if (!std::has_single_bit(r)) {
      return InvalidArgument(Where(path, *smp->get("cube_res")) + ": \"cube_res\" is " + std::to_string(r) +
                             ", which is not a power of two (the wavelets need 2^k: e.g. 8, 16, 32, 64)");
    }
    LTB_ASSIGN_OR_RETURN(uint64_t spp, GetUnsigned(path, *smp, "spp", s->spp, 1, 1 << 16));
    LTB_ASSIGN_OR_RETURN(uint64_t b, GetUnsigned(path, *smp, "bounces", s->bounces, 0, 16));
    LTB_ASSIGN_OR_RETURN(s->seed, GetUnsigned(path, *smp, "seed", s->seed, 0, uint64_t{1} << 62));
    s->cube_res = static_cast<uint32_t>(r);
    s->spp = static_cast<uint32_t>(spp);
    s->bounces = static_cast<uint32_t>(b);
  }
  return Status::Ok();
}

// A material's "albedo" or "ks": a number in [0, 1] (grey) or [r, g, b], each in [0, 1].
Result<glm::dvec3> GetColour(const std::string& path, const toml::table& m, const char* key,
                             const std::string& material, glm::dvec3 def) {
  LTB_ASSIGN_OR_RETURN(glm::dvec3 v, GetVec3(path, m, key, def, /*allow_scalar=*/true));
  for (int c = 0; c < 3; ++c) {
    if (v[c] < 0.0 || v[c] > 1.0) {
      const bool scalar = m.get(key)->is_number();
      return InvalidArgument(Where(path, *m.get(key)) + ": material \"" + material + "\": \"" + key + "\" is " +
                             tomlf::ValueText(*m.get(key)) + ", outside [0, 1]" +
                             (scalar ? std::string() : std::string(" in channel ") + "rgb"[c]));
    }
  }
  return v;
}

// [[material]] entries (a "default" one when there are none); *index: name -> index of
// the materials defined.
Status ParseMaterials(const std::string& path, const toml::table& root, SceneDesc* s,
                      std::map<std::string, int>* index) {
  std::map<std::string, int>& material_index = *index;
  if (const toml::array* mats = root["material"].as_array()) {
    for (const auto& node : *mats) {
      const toml::table* m = node.as_table();
      if (m == nullptr) return InvalidArgument(Where(path, node) + ": [[material]] entries must be tables");
      LTB_RETURN_IF_ERROR(CheckKeys(path, *m, "[[material]] at line " + std::to_string(node.source().begin.line),
                                    {"name", "albedo", "ks", "exponent", "brdf", "roughness", "f0"}));
      Material mat;
      LTB_ASSIGN_OR_RETURN(mat.name, GetString(path, *m, "name", ""));
      if (mat.name.empty()) return InvalidArgument(Where(path, node) + ": [[material]] needs a name");
      LTB_ASSIGN_OR_RETURN(mat.albedo_rgb, GetColour(path, *m, "albedo", mat.name, mat.albedo_rgb));
      LTB_ASSIGN_OR_RETURN(mat.ks_rgb, GetColour(path, *m, "ks", mat.name, mat.ks_rgb));
      SplitColour(&mat);
      LTB_ASSIGN_OR_RETURN(mat.exponent, GetNumber(path, *m, "exponent", mat.exponent, 0.0, 1e5));
      LTB_ASSIGN_OR_RETURN(mat.brdf, GetString(path, *m, "brdf", mat.brdf));
      if (mat.brdf != "phong" && mat.brdf != "blinn" && mat.brdf != "ward" && mat.brdf != "cook-torrance") {
        return InvalidArgument(Where(path, *m->get("brdf")) + ": material \"" + mat.name + "\" has brdf \"" + mat.brdf +
                               "\"; expected phong, blinn, ward or cook-torrance");
      }
      LTB_ASSIGN_OR_RETURN(mat.roughness, GetNumber(path, *m, "roughness", mat.roughness, 1e-4, 10.0));
      LTB_ASSIGN_OR_RETURN(mat.f0, GetNumber(path, *m, "f0", mat.f0, 0.0, 1.0));
      if (s->mode == SceneDesc::Mode::kImage && mat.ks > 0 && mat.brdf != "phong") {
        return InvalidArgument(Where(path, node) + ": material \"" + mat.name + "\" has brdf \"" + mat.brdf +
                               "\", which only the triple-product path renders (a vertex-mode scene, relight "
                               "--material; docs/TRIPLE.md); image mode renders the Phong lobe");
      }
      for (int c = 0; c < 3; ++c) {
        if (mat.albedo_rgb[c] + mat.ks_rgb[c] > 1.0) {
          const bool grey = mat.albedo_rgb == glm::dvec3(mat.albedo_rgb.x) && mat.ks_rgb == glm::dvec3(mat.ks_rgb.x);
          return InvalidArgument(Where(path, node) + ": material \"" + mat.name +
                                 "\" has albedo + ks = " + std::to_string(mat.albedo_rgb[c] + mat.ks_rgb[c]) + " > 1" +
                                 (grey ? "" : std::string(" in channel ") + "rgb"[c]) + " (it would create energy)");
        }
      }
      if (!material_index.emplace(mat.name, static_cast<int>(s->materials.size())).second) {
        return InvalidArgument(Where(path, node) + ": material \"" + mat.name + "\" defined twice");
      }
      s->materials.push_back(mat);
    }
  }
  if (s->materials.empty()) s->materials.push_back(Material{"default"});
  return Status::Ok();
}

// An object's "normals": "auto" (the default) for every object; "file", "smooth" and
// "flat" for meshes, "flat" in image mode only.
Result<Object::Normals> ParseNormals(const std::string& path, const toml::table& o, const Object& obj,
                                     const std::string& type, SceneDesc::Mode mode) {
  LTB_ASSIGN_OR_RETURN(std::string v, GetString(path, o, "normals", "auto"));
  if (v == "auto") return Object::Normals::kAuto;
  const std::string where = Where(path, *o.get("normals")) + ": object \"" + obj.name + "\": normals is \"" + v + "\"";
  if (obj.type != Object::Type::kMesh) {
    return InvalidArgument(where + "; a " + type + " takes only \"auto\" (\"file\", \"smooth\" and \"flat\" are for " +
                           "type = \"mesh\")");
  }
  Object::Normals n;
  if (v == "file") {
    n = Object::Normals::kFile;
  } else if (v == "smooth") {
    n = Object::Normals::kSmooth;
  } else if (v == "flat") {
    n = Object::Normals::kFlat;
  } else {
    return InvalidArgument(where + " (expected \"auto\", \"file\", \"smooth\" or \"flat\")");
  }
  if (n == Object::Normals::kFlat && mode == SceneDesc::Mode::kVertex) {
    return InvalidArgument(where + ": vertex mode has no single flat normal per vertex; use \"smooth\" or \"file\"");
  }
  return n;
}

// An object's "usemtl": a boolean, true only for a mesh whose file is OBJ (obj.file set).
Result<bool> ParseUsemtl(const std::string& path, const toml::table& o, const Object& obj, const std::string& type) {
  LTB_ASSIGN_OR_RETURN(bool usemtl, GetBool(path, o, "usemtl", false));
  if (!usemtl) return false;
  const std::string where = Where(path, *o.get("usemtl")) + ": object \"" + obj.name + "\": usemtl = true";
  if (obj.type != Object::Type::kMesh) {
    return InvalidArgument(where + " is for type = \"mesh\" with an OBJ file (its usemtl statements pick the " +
                           "materials); a " + type + " has none: leave usemtl out and set \"material\"");
  }
  std::string ext = std::filesystem::path(obj.file).extension().string();
  for (char& c : ext) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  if (ext != ".obj") {
    return InvalidArgument(where + " needs an OBJ file (its usemtl statements pick the materials), but \"" + obj.file +
                           "\" is " +
                           (ext.empty() ? std::string("a file without an extension") : "a \"" + ext + "\" file") +
                           "; leave usemtl out and set \"material\", or convert the mesh to OBJ");
  }
  return true;
}

// One [[object]] entry; `names` holds the names used so far, `base` the scene's folder
// (mesh files are resolved against it).
Result<Object> ParseObject(const std::string& path, const toml::node& node, const SceneDesc& s,
                           const std::map<std::string, int>& material_index, const std::filesystem::path& base,
                           std::set<std::string>* names) {
  const toml::table* o = node.as_table();
  if (o == nullptr) return InvalidArgument(Where(path, node) + ": [[object]] entries must be tables");
  Object obj;
  obj.line = static_cast<int>(node.source().begin.line);
  LTB_ASSIGN_OR_RETURN(std::string type, GetString(path, *o, "type", ""));
  std::set<std::string> keys{"type", "name", "material", "translate", "rotate", "scale", "normals", "usemtl"};
  if (type == "mesh") keys.insert("colours");
  if (type == "plane") {
    obj.type = Object::Type::kPlane;
    keys.insert("size");
  } else if (type == "box") {
    obj.type = Object::Type::kBox;
    keys.insert({"size", "center"});
  } else if (type == "sphere") {
    obj.type = Object::Type::kSphere;
    keys.insert({"center", "radius"});
  } else if (type == "mesh") {
    obj.type = Object::Type::kMesh;
    keys.insert("file");
  } else {
    return InvalidArgument(Where(path, node) + ": [[object]] type is \"" + type +
                           "\" (expected plane, box, sphere or mesh)");
  }
  LTB_RETURN_IF_ERROR(CheckKeys(path, *o, "[[object]] (" + type + ") at line " + std::to_string(obj.line), keys));
  LTB_ASSIGN_OR_RETURN(obj.name, GetString(path, *o, "name", type + "@" + std::to_string(obj.line)));
  if (!names->insert(obj.name).second)
    return InvalidArgument(Where(path, node) + ": object name \"" + obj.name + "\" used twice");
  LTB_ASSIGN_OR_RETURN(std::string mat, GetString(path, *o, "material", s.materials.front().name));
  auto mi = material_index.find(mat);
  if (mi == material_index.end() && !(material_index.empty() && mat == "default")) {
    return InvalidArgument(Where(path, node) + ": object \"" + obj.name + "\" uses material \"" + mat +
                           "\", which no [[material]] defines");
  }
  obj.material = mi == material_index.end() ? 0 : mi->second;
  glm::dvec3 def_size = obj.type == Object::Type::kPlane ? glm::dvec3(2, 2, 0) : glm::dvec3(1, 1, 1);
  if (obj.type == Object::Type::kPlane && o->contains("size")) {
    const toml::array* a = (*o)["size"].as_array();
    if (a == nullptr || a->size() != 2 || !(*a)[0].value<double>() || !(*a)[1].value<double>() ||
        !std::isfinite(*(*a)[0].value<double>()) || !std::isfinite(*(*a)[1].value<double>())) {
      return InvalidArgument(Where(path, *o->get("size")) + ": plane \"size\" must be [x, y], two finite numbers");
    }
    obj.size = {*(*a)[0].value<double>(), *(*a)[1].value<double>(), 0};
  } else {
    LTB_ASSIGN_OR_RETURN(obj.size, GetVec3(path, *o, "size", def_size));
  }
  LTB_ASSIGN_OR_RETURN(obj.center, GetVec3(path, *o, "center", obj.center));
  LTB_ASSIGN_OR_RETURN(obj.radius, GetNumber(path, *o, "radius", obj.radius, 1e-9, 1e9));
  LTB_ASSIGN_OR_RETURN(obj.translate, GetVec3(path, *o, "translate", obj.translate));
  LTB_ASSIGN_OR_RETURN(obj.rotate_degrees, GetVec3(path, *o, "rotate", obj.rotate_degrees));
  LTB_ASSIGN_OR_RETURN(obj.scale, GetVec3(path, *o, "scale", obj.scale, /*allow_scalar=*/true));
  LTB_ASSIGN_OR_RETURN(obj.normals, ParseNormals(path, *o, obj, type, s.mode));
  if (obj.type == Object::Type::kMesh) {
    LTB_ASSIGN_OR_RETURN(std::string file, GetString(path, *o, "file", ""));
    if (file.empty()) return InvalidArgument(Where(path, node) + ": mesh object \"" + obj.name + "\" needs \"file\"");
    std::filesystem::path f(file);
    obj.file = (f.is_absolute() ? f : base / f).lexically_normal().string();
    LTB_ASSIGN_OR_RETURN(std::string colours, GetString(path, *o, "colours", "none"));
    if (colours == "file") {
      obj.colours = Object::Colours::kFile;
    } else if (colours != "none") {
      return InvalidArgument(Where(path, *o->get("colours")) + ": object \"" + obj.name + "\": colours is \"" +
                             colours + "\" (expected \"none\" or \"file\")");
    }
  }
  LTB_ASSIGN_OR_RETURN(obj.usemtl, ParseUsemtl(path, *o, obj, type));
  return obj;
}

// Vertex mode: the objects whose vertices are rows (every mesh when [output] names none)
// must exist.
Status CheckVertexObjects(const std::string& path, const std::set<std::string>& names, SceneDesc* s) {
  if (s->vertex_objects.empty()) {
    for (const Object& o : s->objects)
      if (o.type == Object::Type::kMesh) s->vertex_objects.push_back(o.name);
  }
  for (const std::string& n : s->vertex_objects) {
    if (names.count(n) == 0)
      return InvalidArgument(path + ": [output] objects names \"" + n + "\", which no [[object]] has");
  }
  if (s->vertex_objects.empty()) return InvalidArgument(path + ": vertex mode needs [output] objects = [names]");
  return Status::Ok();
}

}  // namespace

Result<SceneDesc> ParseScene(const std::string& path) {
  LTB_ASSIGN_OR_RETURN(toml::table root, tomlf::ParseFile(path, "scene file"));
  SceneDesc s;
  s.path = path;
  LTB_RETURN_IF_ERROR(CheckKeys(path, root, "the scene", {"output", "camera", "sampling", "material", "object"}));
  LTB_RETURN_IF_ERROR(ParseOutput(path, root, &s));
  LTB_RETURN_IF_ERROR(ParseCamera(path, root, &s));
  LTB_RETURN_IF_ERROR(ParseSampling(path, root, &s));
  std::map<std::string, int> material_index;
  LTB_RETURN_IF_ERROR(ParseMaterials(path, root, &s, &material_index));

  const toml::array* objs = root["object"].as_array();
  if (objs == nullptr || objs->empty()) return InvalidArgument(path + ": the scene has no [[object]]");
  std::filesystem::path base = std::filesystem::path(path).parent_path();
  std::set<std::string> names;
  for (const auto& node : *objs) {
    LTB_ASSIGN_OR_RETURN(Object obj, ParseObject(path, node, s, material_index, base, &names));
    s.objects.push_back(obj);
  }
  if (s.mode == SceneDesc::Mode::kVertex) LTB_RETURN_IF_ERROR(CheckVertexObjects(path, names, &s));
  return s;
}

void SplitColour(Material* m) {
  const glm::dvec3 a = m->albedo_rgb, k = m->ks_rgb;
  const double amax = std::max({a.x, a.y, a.z}), kmax = std::max({k.x, k.y, k.z});
  // The tint follows the albedo, or the lobe when there is no albedo; a scalar (grey)
  // material divides by itself: tint exactly 1, albedo and ks exactly as given.
  m->tint = amax > 0 ? a / amax : kmax > 0 ? k / kmax : glm::dvec3(1.0);
  m->albedo = amax;
  m->ks = kmax;
  m->separable = true;
  if (amax > 0 && kmax > 0) {
    // ks must be tint·K for one K: K from the albedo's brightest channel, every channel within
    // 1e-6 of it (relative to the brightest ks).
    int c0 = a.x == amax ? 0 : a.y == amax ? 1 : 2;
    m->ks = k[c0];
    for (int c = 0; c < 3; ++c) {
      if (std::fabs(k[c] - m->tint[c] * m->ks) > 1e-6 * kmax) m->separable = false;
    }
    if (!m->separable) m->ks = kmax;
  }
}

SceneDesc ChannelScene(const SceneDesc& s, int channel) {
  SceneDesc c = s;
  c.channel = channel;
  for (Material& m : c.materials) {
    m.albedo = m.albedo_rgb[channel];
    m.ks = m.ks_rgb[channel];
    m.tint = glm::dvec3(1.0);
    m.separable = true;
  }
  return c;
}

}  // namespace ltb::sample
