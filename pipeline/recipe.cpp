#include "pipeline/recipe.h"

#include <toml++/toml.h>

#include <algorithm>
#include <bit>
#include <cstdlib>
#include <filesystem>
#include <sstream>

#include "format/bits.h"
#include "stages/brdf/brdf.h"
#include "stages/column_transform/column_transform.h"
#include "stages/common/quantity.h"
#include "stages/common/toml_fields.h"
#include "stages/images/environment.h"
#include "stages/images/envmap.h"
#include "stages/relight/sequence_spec.h"
#include "stages/sample/scene.h"

namespace ltb::pipeline {
namespace {

namespace fs = std::filesystem;
using tomlf::CheckKeys;
using tomlf::GetBool;
using tomlf::GetNumber;
using tomlf::GetString;
using tomlf::GetUnsigned;
using tomlf::GetVec3;
using tomlf::Where;

std::string Join(const std::vector<std::string>& v) {
  std::string out;
  for (const auto& s : v) out += (out.empty() ? "" : ", ") + s;
  return out;
}

// "${VAR}" and "$VAR" replaced by the environment's values; an unset variable is an error.
Result<std::string> ExpandVariables(const std::string& where, const std::string& text) {
  std::string out;
  for (size_t i = 0; i < text.size(); ++i) {
    if (text[i] != '$' || i + 1 >= text.size()) {
      out += text[i];
      continue;
    }
    size_t start = i + 1, end;
    bool braced = text[start] == '{';
    if (braced) {
      end = text.find('}', start);
      if (end == std::string::npos) return InvalidArgument(where + ": unterminated \"${\" in \"" + text + "\"");
      ++start;
    } else {
      end = start;
      while (end < text.size() && (std::isalnum(static_cast<unsigned char>(text[end])) || text[end] == '_')) ++end;
      if (end == start) {
        out += '$';
        continue;
      }
    }
    std::string var = text.substr(start, end - start);
    const char* value = std::getenv(var.c_str());
    if (value == nullptr || *value == '\0') {
      std::string hint = var == "LTBAKE_ENVMAPS" ? " (e.g. export LTBAKE_ENVMAPS=$(scripts/find_envmaps.sh))" : "";
      return InvalidArgument(where + ": \"" + text + "\" uses the environment variable " + var +
                             ", which is not set; set it" + hint);
    }
    out += value;
    i = braced ? end : end - 1;
  }
  return out;
}

// Why `path` cannot be read as a `what`, or Ok: missing, a directory, not a regular file.
Status CheckRegular(const std::string& where, const std::string& what, const std::string& path) {
  std::error_code ec;
  fs::file_status st = fs::status(path, ec);
  if (st.type() == fs::file_type::not_found) return NotFound(where + ": " + what + " " + path + " does not exist");
  if (st.type() == fs::file_type::directory) {
    return InvalidArgument(where + ": " + what + " " + path + " is a directory; give the path of a file");
  }
  if (ec || st.type() != fs::file_type::regular) {
    return InvalidArgument(where + ": " + what + " " + path + " is not a regular file (a FIFO, socket or device?)");
  }
  return Status::Ok();
}

std::string Absolute(const std::string& dir, const std::string& p) {
  fs::path path(p);
  if (path.is_relative()) path = fs::path(dir) / path;
  return path.lexically_normal().string();
}

Result<std::vector<std::string>> GetStringList(const std::string& path, const toml::table& t, const char* key,
                                               const std::vector<std::string>& allowed) {
  std::vector<std::string> out;
  const toml::node* n = t.get(key);
  if (n == nullptr) return out;
  const toml::array* a = n->as_array();
  if (a == nullptr) return InvalidArgument(Where(path, *n) + ": \"" + key + "\" must be a list of strings");
  for (const auto& item : *a) {
    auto v = item.value<std::string>();
    if (!v) return InvalidArgument(Where(path, *n) + ": \"" + key + "\" must be a list of strings");
    if (!allowed.empty() && std::find(allowed.begin(), allowed.end(), *v) == allowed.end()) {
      return InvalidArgument(Where(path, *n) + ": \"" + key + "\" names \"" + *v +
                             "\", which is not one of: " + Join(allowed));
    }
    out.push_back(*v);
  }
  return out;
}

Result<std::string> GetChoice(const std::string& path, const toml::table& t, const char* key, std::string def,
                              const std::vector<std::string>& allowed) {
  LTB_ASSIGN_OR_RETURN(std::string v, GetString(path, t, key, def));
  if (std::find(allowed.begin(), allowed.end(), v) == allowed.end()) {
    return InvalidArgument(Where(path, *t.get(key)) + ": \"" + key + "\" is \"" + v +
                           "\"; expected one of: " + Join(allowed));
  }
  return v;
}

// The inline [scene] table as a scene file of its own, with mesh paths made absolute so it
// reads the same from the work directory.
Result<std::string> InlineScene(const std::string& path, const std::string& dir, const toml::table& scene) {
  toml::table copy = scene;
  if (toml::array* objects = copy["object"].as_array()) {
    for (auto& node : *objects) {
      toml::table* obj = node.as_table();
      if (obj == nullptr) continue;  // the scene parser reports it
      if (auto file = (*obj)["file"].value<std::string>()) {
        LTB_ASSIGN_OR_RETURN(std::string expanded, ExpandVariables(Where(path, node), *file));
        obj->insert_or_assign("file", Absolute(dir, expanded));
      }
    }
  }
  std::ostringstream out;
  out << "# Written by `ltbake run` from the [scene] table of " << path << "; edit the recipe, not this file.\n"
      << toml::toml_formatter(copy) << "\n";
  return out.str();
}

// A relative error in (0, 1): "2%" or 0.02; unset when the key is absent.
Result<std::optional<double>> GetRelativeError(const std::string& path, const toml::table& t, const char* key) {
  const toml::node* k = t.get(key);
  if (k == nullptr) return std::optional<double>();
  if (k->is_string()) {
    auto f = stages::ParseFraction(*k->value<std::string>());
    if (!f.ok()) return f.status().WithContext(Where(path, *k) + ": \"" + key + "\"");
    if (!(*f < 1)) return InvalidArgument(Where(path, *k) + ": \"" + key + "\" must be below 100%");
    return std::optional<double>(*f);
  }
  LTB_ASSIGN_OR_RETURN(double v, GetNumber(path, t, key, 0.01, 1e-9, 0.999999));
  return std::optional<double>(v);
}

// [sample] tolerance and max_levels: converged sampling, which traces rows its own way.
Status ParseConverged(const std::string& path, const toml::table& t, Recipe::Sample* s) {
  LTB_ASSIGN_OR_RETURN(s->tolerance, GetRelativeError(path, t, "tolerance"));
  if (const toml::node* m = t.get("max_levels")) {
    if (!s->tolerance) return InvalidArgument(Where(path, *m) + ": \"max_levels\" goes with \"tolerance\"");
    LTB_ASSIGN_OR_RETURN(uint64_t v, GetUnsigned(path, t, "max_levels", 5, 1, 12));
    s->max_levels = v;
  }
  if (s->tolerance && (s->sparse || s->channels == "rgb" || s->factor > 0)) {
    return InvalidArgument(Where(path, *t.get("tolerance")) +
                           ": [sample] tolerance (converged sampling) does not yet combine with sparse, channels = "
                           "\"rgb\" or factor (docs/SAMPLE.md \"Converged sampling\")");
  }
  return Status::Ok();
}

Status ParseSample(const std::string& path, const toml::table& t, Recipe::Sample* s) {
  LTB_RETURN_IF_ERROR(
      CheckKeys(path, t, "[sample]",
                {"cube_res", "spp", "bounces", "seed", "sparse", "dense_fraction", "radius", "features", "neighbours",
                 "l1_lambda", "max_residual", "channels", "factor", "tolerance", "max_levels"}));
  // sparse = true or "auto": --sparse auto (a pilot picks sparse or full); "force": --sparse.
  if (const toml::node* sp = t.get("sparse"); sp != nullptr && sp->is_string()) {
    const std::string v = *sp->value<std::string>();
    if (v != "auto" && v != "force") {
      return InvalidArgument(Where(path, *sp) + ": [sample] sparse is \"" + v +
                             "\" (expected true, false, \"auto\" (as true) or \"force\")");
    }
    s->sparse = true;
    s->sparse_force = v == "force";
  } else {
    LTB_ASSIGN_OR_RETURN(s->sparse, GetBool(path, t, "sparse", false));
  }
  LTB_ASSIGN_OR_RETURN(s->channels, GetString(path, t, "channels", "mono"));
  const toml::node* factor = t.get("factor");
  if (factor != nullptr && factor->is_string() && factor->value<std::string>()->starts_with("auto:")) {
    auto f = stages::ParseFraction(factor->value<std::string>()->substr(5));
    if (!f.ok()) return f.status().WithContext(Where(path, *factor) + ": \"factor\"");
    if (!(*f < 1)) return InvalidArgument(Where(path, *factor) + ": \"factor\" = \"auto:T\" needs T below 100%");
    s->factor_target = *f;
    s->factor = 1;  // a placeholder until the bake chooses K from the scene
  } else {
    LTB_ASSIGN_OR_RETURN(s->factor, GetUnsigned(path, t, "factor", 0, 1, 64));
  }
  if (s->factor > 0 && s->sparse) {
    return InvalidArgument(Where(path, *t.get("factor")) +
                           ": [sample] factor does not combine with sparse (docs/GLOSSY.md)");
  }
  if (s->channels != "mono" && s->channels != "rgb") {
    return InvalidArgument(Where(path, *t.get("channels")) + ": [sample] channels is \"" + s->channels +
                           "\" (expected \"mono\" or \"rgb\")");
  }
  for (const char* key : {"dense_fraction", "radius", "features", "neighbours", "l1_lambda", "max_residual"}) {
    if (t.contains(key) && !s->sparse) {
      return InvalidArgument(Where(path, *t.get(key)) + ": \"" + key +
                             "\" applies to sparse precomputation; add sparse = true or remove it");
    }
  }
  if (t.contains("dense_fraction")) {
    LTB_ASSIGN_OR_RETURN(double v, GetNumber(path, t, "dense_fraction", 0.25, 1e-9, 1.0));
    s->dense_fraction = v;
  }
  if (t.contains("radius")) {
    LTB_ASSIGN_OR_RETURN(double v, GetNumber(path, t, "radius", 1.0, 1e-300, 1e300));
    s->radius = v;
  }
  if (t.contains("l1_lambda")) {
    LTB_ASSIGN_OR_RETURN(double v, GetNumber(path, t, "l1_lambda", 1e-3, 0.0, 0.999999));
    s->l1_lambda = v;
  }
  if (t.contains("max_residual")) {
    LTB_ASSIGN_OR_RETURN(double v, GetNumber(path, t, "max_residual", 0.15, 1e-300, 1e300));
    s->max_residual = v;
  }
  if (t.contains("features")) {
    LTB_ASSIGN_OR_RETURN(uint64_t v, GetUnsigned(path, t, "features", 350, 1, uint64_t{6} << 20));
    s->features = v;
  }
  if (t.contains("neighbours")) {
    LTB_ASSIGN_OR_RETURN(uint64_t v, GetUnsigned(path, t, "neighbours", 16, 1, 64));
    s->neighbours = v;
  }
  if (t.contains("cube_res")) {
    LTB_ASSIGN_OR_RETURN(uint64_t r, GetUnsigned(path, t, "cube_res", 0, 1, sample::kMaxCubeRes));
    if (!std::has_single_bit(r)) {
      return InvalidArgument(Where(path, *t.get("cube_res")) + ": \"cube_res\" is " + std::to_string(r) +
                             ", which is not a power of two (the wavelets need 2^k: e.g. 8, 16, 32, 64)");
    }
    s->cube_res = r;
  }
  if (t.contains("spp")) {
    LTB_ASSIGN_OR_RETURN(uint64_t v, GetUnsigned(path, t, "spp", 0, 1, 1 << 16));
    s->spp = v;
  }
  if (t.contains("bounces")) {
    LTB_ASSIGN_OR_RETURN(uint64_t v, GetUnsigned(path, t, "bounces", 0, 0, 16));
    s->bounces = v;
  }
  if (t.contains("seed")) {
    LTB_ASSIGN_OR_RETURN(uint64_t v, GetUnsigned(path, t, "seed", 0, 0, uint64_t{1} << 62));
    s->seed = v;
  }
  return ParseConverged(path, t, s);
}

Status ParseColumnTransform(const std::string& path, const toml::table& t, Recipe::ColumnTransform* c) {
  LTB_RETURN_IF_ERROR(
      CheckKeys(path, t, "[column-transform]", {"filter", "depth", "keep", "terms", "budget", "target_error", "zstd"}));
  LTB_ASSIGN_OR_RETURN(
      c->filter, GetChoice(path, t, "filter", c->filter, {"legall53", "cdf97", "haar", "db1", "db2", "db3", "db4"}));
  if (const toml::node* d = t.get("depth")) {
    if (d->is_integer()) {  // never a float node's value<int64_t>() (a plain cast in toml++)
      c->depth = std::to_string(*d->value<int64_t>());
    } else if (auto s = d->value<std::string>()) {
      c->depth = *s;
    } else {
      return InvalidArgument(Where(path, *d) + ": \"depth\" must be \"adaptive\", \"none\", \"full\" or an integer");
    }
    auto mode = stages::ParseDepthMode(c->depth);
    if (!mode.ok()) return mode.status().WithContext(Where(path, *d) + ": \"depth\"");
    c->depth_where = Where(path, *d);
  }
  int given = t.contains("keep") + t.contains("terms") + t.contains("budget") + t.contains("target_error");
  if (given > 1) {
    return InvalidArgument(Where(path, t) +
                           ": [column-transform] gives more than one of \"keep\", \"terms\", "
                           "\"budget\", \"target_error\"; choose one");
  }
  LTB_ASSIGN_OR_RETURN(c->target_error, GetRelativeError(path, t, "target_error"));  // "2%", as --target-error
  if (const toml::node* k = t.get("keep"); k && k->is_string()) {                    // "5%", as --keep takes it
    auto f = stages::ParseFraction(*k->value<std::string>());
    if (!f.ok()) return f.status().WithContext(Where(path, *k) + ": \"keep\"");
    c->keep = *f;
  } else if (k) {
    LTB_ASSIGN_OR_RETURN(double v, GetNumber(path, t, "keep", 0.05, 1e-9, 1.0));
    c->keep = v;
  }
  if (t.contains("terms")) {
    LTB_ASSIGN_OR_RETURN(uint64_t n, GetUnsigned(path, t, "terms", 0, 1, uint64_t{1} << 40));
    c->terms = n;
  }
  if (const toml::node* b = t.get("budget")) {
    if (auto x = b->value<double>(); x && !b->is_string()) {
      std::ostringstream s;
      s << *x;
      c->budget = s.str();
    } else if (auto s = b->value<std::string>()) {
      c->budget = *s;
    } else {
      return InvalidArgument(Where(path, *b) +
                             ": \"budget\" must be a fraction, a count or a size (\"2%\", \"64MiB\")");
    }
    auto parsed = stages::ParseBudget(*c->budget);
    if (!parsed.ok()) return parsed.status().WithContext(Where(path, *b) + ": \"budget\"");
  }
  if (given == 0) c->budget = "5%";  // one rate-distortion budget (docs/COLUMN-TRANSFORM.md)
  LTB_ASSIGN_OR_RETURN(c->zstd, GetBool(path, t, "zstd", c->zstd));
  return Status::Ok();
}

// A map's shape, read when the recipe is (docs/RECIPE.md: a bad plan is refused before
// anything runs): an image's size must fit its layout (stages::CheckEnvMapShape; no pixel
// is decoded), a .npy cubemap must be a float (6R², 3) array for a power-of-two R (the
// R of the matrix it lights is checked by relight).
Status CheckEnvShape(const EnvMap& e, const std::string& table) {
  if (fs::path(e.path).extension() == ".npy") {
    if (e.layout != "auto") {
      return InvalidArgument(table + " envs: " + e.path + " is a cubemap .npy; env_layout = \"" + e.layout +
                             "\" is for images (.exr, .hdr)");
    }
    auto r = stages::CubemapNpyResolution(e.path);
    if (!r.ok()) return r.status().WithContext(table + " envs");
    return Status::Ok();
  }
  stages::EnvLoadOptions o;
  o.layout = *stages::ParseEnvLayout(e.layout);  // one of GetChoice's names
  auto layout = stages::CheckEnvMapShape(e.path, o);
  if (layout.ok()) return Status::Ok();
  std::string message = layout.status().message();
  if (message.find("--env-layout") != std::string::npos) {
    message += " (in a recipe: env_layout = \"...\" in " + table + ")";
  }
  return InvalidArgument(table + " envs: " + message);
}

// The "envs" list of [relight] or [triple]: absolute paths, each named by its file stem.
Status ParseEnvs(const std::string& path, const std::string& dir, const toml::table& t, const std::string& table,
                 std::vector<EnvMap>* out) {
  const toml::node* envs = t.get("envs");
  if (envs == nullptr || envs->as_array() == nullptr || envs->as_array()->empty()) {
    return InvalidArgument(Where(path, t) + ": " + table +
                           " needs \"envs\", a list of environment maps "
                           "(.exr/.hdr lat-long or cross, or a 6R²×3 .npy cubemap)");
  }
  LTB_ASSIGN_OR_RETURN(
      const std::string layout,
      GetChoice(path, t, "env_layout", "auto", {"auto", "latlong", "hcross", "vcross", "faces", "angular"}));
  for (const auto& item : *envs->as_array()) {
    auto text = item.value<std::string>();
    if (!text) return InvalidArgument(Where(path, *envs) + ": \"envs\" must be a list of file paths");
    LTB_ASSIGN_OR_RETURN(std::string expanded, ExpandVariables(Where(path, *envs), *text));
    EnvMap e;
    e.path = Absolute(dir, expanded);
    e.name = fs::path(e.path).stem().string();
    for (char& ch : e.name) {
      if (!std::isalnum(static_cast<unsigned char>(ch)) && ch != '-' && ch != '_' && ch != '.') ch = '_';
    }
    e.layout = layout;
    if (e.path.find("{face}") == std::string::npos) {
      LTB_RETURN_IF_ERROR(CheckRegular(Where(path, *envs), "environment map", e.path));
    }
    if (Status shape = CheckEnvShape(e, table); !shape.ok()) return shape.WithContext(Where(path, *envs));
    for (const EnvMap& other : *out) {
      if (other.name == e.name) {
        return InvalidArgument(Where(path, *envs) + ": two environment maps are named \"" + e.name +
                               "\" (the relit images would overwrite each other): " + other.path + " and " + e.path);
      }
    }
    out->push_back(e);
  }
  return Status::Ok();
}

// A view's "size": [width, height], each 1..16384; unchanged when absent.
Status GetImageSize(const std::string& path, const toml::table& t, const char* table, uint64_t* width,
                    uint64_t* height) {
  const toml::node* sz = t.get("size");
  if (sz == nullptr) return Status::Ok();
  const toml::array* a = sz->as_array();
  auto w = a && a->size() == 2 ? (*a)[0].value<int64_t>() : std::nullopt;
  auto h = a && a->size() == 2 ? (*a)[1].value<int64_t>() : std::nullopt;
  if (!w || !h || *w < 1 || *h < 1 || *w > 16384 || *h > 16384) {
    return InvalidArgument(Where(path, *sz) + ": " + table + " \"size\" must be [width, height], each 1..16384");
  }
  *width = static_cast<uint64_t>(*w);
  *height = static_cast<uint64_t>(*h);
  return Status::Ok();
}

Status ParseRelight(const std::string& path, const std::string& dir, const toml::table& t, Recipe::Relight* r) {
  LTB_RETURN_IF_ERROR(CheckKeys(path, t, "[relight]",
                                {"matrix", "envs", "env_layout", "terms", "weighting", "clamp", "reference", "format",
                                 "exposure", "sequence", "method", "eye", "target", "up", "fov", "size"}));
  r->present = true;
  if (t.contains("eye")) {
    LTB_ASSIGN_OR_RETURN(glm::dvec3 eye, GetVec3(path, t, "eye", glm::dvec3(0)));
    r->eye = eye;
  }
  for (const char* key : {"target", "up", "fov", "size"}) {
    if (t.contains(key) && !r->eye) {
      return InvalidArgument(Where(path, *t.get(key)) + ": [relight] \"" + key +
                             "\" places the camera of a factored bake's view; add eye = [x, y, z]");
    }
  }
  LTB_ASSIGN_OR_RETURN(r->target, GetVec3(path, t, "target", r->target));
  LTB_ASSIGN_OR_RETURN(r->up, GetVec3(path, t, "up", r->up));
  LTB_ASSIGN_OR_RETURN(r->fov, GetNumber(path, t, "fov", r->fov, 1e-3, 179.999));
  if (r->eye) {  // the view every renderer checks (sample::ValidateView), here before anything runs
    Status view = sample::ValidateView(*r->eye, r->target, r->up, r->fov);
    if (!view.ok()) return view.WithContext(Where(path, *t.get("eye")) + ": [relight] view");
  }
  LTB_RETURN_IF_ERROR(GetImageSize(path, t, "[relight]", &r->width, &r->height));
  LTB_ASSIGN_OR_RETURN(r->matrix, GetChoice(path, t, "matrix", r->matrix, {"final", "cpca"}));
  LTB_ASSIGN_OR_RETURN(r->terms, GetUnsigned(path, t, "terms", r->terms, 1, uint64_t{1} << 32));
  LTB_ASSIGN_OR_RETURN(r->weighting, GetChoice(path, t, "weighting", r->weighting, {"area", "transport", "none"}));
  LTB_ASSIGN_OR_RETURN(r->clamp, GetBool(path, t, "clamp", r->clamp));
  LTB_ASSIGN_OR_RETURN(r->reference, GetBool(path, t, "reference", r->reference));
  LTB_ASSIGN_OR_RETURN(r->format, GetChoice(path, t, "format", r->format, {"png", "exr", "mp4"}));
  LTB_ASSIGN_OR_RETURN(r->exposure, GetNumber(path, t, "exposure", r->exposure, 0, 64));
  LTB_ASSIGN_OR_RETURN(r->method, GetChoice(path, t, "method", r->method, {"pbi", "bi", "nwa"}));
  if (r->eye && (t.contains("sequence") || t.contains("reference") || t.contains("weighting"))) {
    return InvalidArgument(Where(path, *t.get("eye")) +
                           ": [relight] eye renders a view of a factored bake; \"sequence\", \"reference\" and "
                           "\"weighting\" are for the matrix path");
  }
  if (const toml::node* seq = t.get("sequence")) {
    auto text = seq->value<std::string>();
    if (!text)
      return InvalidArgument(Where(path, *seq) + ": [relight] sequence must be a string, e.g. \"rotate:3.6:100\"");
    auto parsed = stages::ParseSequence(*text);
    if (!parsed.ok()) return parsed.status().WithContext(Where(path, *seq) + ": [relight] sequence");
    r->sequence = *text;
    // A sequence in a recipe makes one file a map: an .mp4 (format left out means mp4).
    if (!t.contains("format")) r->format = "mp4";
    if (r->format != "mp4") {
      return InvalidArgument(Where(path, *seq) +
                             ": [relight] sequence writes an .mp4 a map; set format = \"mp4\" "
                             "or leave format out");
    }
  } else if (r->format == "mp4") {
    return InvalidArgument(Where(path, t) +
                           ": [relight] format = \"mp4\" needs a sequence (e.g. sequence = "
                           "\"rotate:3.6:100\")");
  } else if (t.contains("method")) {
    return InvalidArgument(Where(path, *t.get("method")) +
                           ": [relight] method belongs to a sequence; add sequence = "
                           "\"...\"");
  }
  return ParseEnvs(path, dir, t, "[relight]", &r->envs);
}

Status ParseTriple(const std::string& path, const std::string& dir, const toml::table& t, Recipe::Triple* r) {
  LTB_RETURN_IF_ERROR(CheckKeys(path, t, "[triple]",
                                {"cube_res", "spp", "materials", "envs", "env_layout", "eye", "target", "up", "fov",
                                 "size", "method", "terms", "brdf_terms", "clamp", "format", "exposure"}));
  r->present = true;
  LTB_ASSIGN_OR_RETURN(r->cube_res, GetUnsigned(path, t, "cube_res", r->cube_res, 1, 512));
  if (!IsPowerOfTwo(r->cube_res)) {
    return InvalidArgument(Where(path, *t.get("cube_res")) + ": [triple] cube_res " + std::to_string(r->cube_res) +
                           " is not a power of two");
  }
  if (t.contains("spp")) {
    LTB_ASSIGN_OR_RETURN(uint64_t spp, GetUnsigned(path, t, "spp", 4, 1, 1 << 16));
    r->spp = spp;
  }
  const toml::node* mats = t.get("materials");
  if (mats == nullptr || mats->as_array() == nullptr || mats->as_array()->empty()) {
    return InvalidArgument(Where(path, t) +
                           ": [triple] needs \"materials\", the material fields to make, e.g. [\"lambert\", "
                           "\"phong:64\"] (one Lambert, one Phong per exponent the scene uses)");
  }
  for (const auto& item : *mats->as_array()) {
    auto text = item.value<std::string>();
    if (!text) return InvalidArgument(Where(path, *mats) + ": \"materials\" must be a list of strings");
    auto parsed = brdf::ParseBrdf(*text);
    if (!parsed.ok()) return parsed.status().WithContext(Where(path, *mats) + ": \"materials\"");
    r->materials.push_back(*text);
  }
  LTB_RETURN_IF_ERROR(ParseEnvs(path, dir, t, "[triple]", &r->envs));
  LTB_ASSIGN_OR_RETURN(r->eye, GetVec3(path, t, "eye", r->eye));
  LTB_ASSIGN_OR_RETURN(r->target, GetVec3(path, t, "target", r->target));
  LTB_ASSIGN_OR_RETURN(r->up, GetVec3(path, t, "up", r->up));
  LTB_ASSIGN_OR_RETURN(r->fov, GetNumber(path, t, "fov", r->fov, 1e-3, 179.999));
  {
    Status view = sample::ValidateView(r->eye, r->target, r->up, r->fov);
    const toml::node* at = t.contains("eye") ? t.get("eye") : nullptr;
    if (!view.ok()) return view.WithContext((at != nullptr ? Where(path, *at) : Where(path, t)) + ": [triple] view");
  }
  LTB_RETURN_IF_ERROR(GetImageSize(path, t, "[triple]", &r->width, &r->height));
  LTB_ASSIGN_OR_RETURN(r->method, GetChoice(path, t, "method", r->method, {"shared", "sublinear", "linear", "pixel"}));
  for (auto [key, dst] : {std::pair{"terms", &r->terms}, std::pair{"brdf_terms", &r->brdf_terms}}) {
    const toml::node* n = t.get(key);
    if (n == nullptr) continue;
    if (auto s = n->value<std::string>(); s && *s == "all") {
      *dst = "all";
    } else {
      LTB_ASSIGN_OR_RETURN(uint64_t v, GetUnsigned(path, t, key, 1, 1, uint64_t{1} << 32));
      *dst = std::to_string(v);
    }
  }
  LTB_ASSIGN_OR_RETURN(r->clamp, GetBool(path, t, "clamp", r->clamp));
  LTB_ASSIGN_OR_RETURN(r->format, GetChoice(path, t, "format", r->format, {"png", "exr", "npy"}));
  LTB_ASSIGN_OR_RETURN(r->exposure, GetNumber(path, t, "exposure", r->exposure, 0, 64));
  return Status::Ok();
}

// [quantize]: one step for the matrix (error_ratio) or per-column maxima (bits, with their
// scaling, dither and seed).
Status ParseQuantize(const std::string& path, const toml::table& t, Recipe::Quantize* q) {
  LTB_RETURN_IF_ERROR(CheckKeys(path, t, "[quantize]", {"error_ratio", "bits", "scaling", "dither", "seed"}));
  if (t.contains("bits") && t.contains("error_ratio")) {
    return InvalidArgument(path +
                           ": [quantize] takes error_ratio (one step for the matrix) or bits (per-column "
                           "maxima), not both");
  }
  LTB_ASSIGN_OR_RETURN(q->error_ratio, GetNumber(path, t, "error_ratio", q->error_ratio, 1.000001, 100));
  if (t.contains("bits")) {
    LTB_ASSIGN_OR_RETURN(uint64_t bits, GetUnsigned(path, t, "bits", 9, 2, 24));
    q->bits = bits;
  }
  LTB_ASSIGN_OR_RETURN(q->scaling, GetChoice(path, t, "scaling", q->scaling, {"level", "none"}));
  LTB_ASSIGN_OR_RETURN(q->dither, GetBool(path, t, "dither", q->dither));
  LTB_ASSIGN_OR_RETURN(q->seed, GetUnsigned(path, t, "seed", q->seed, 0, uint64_t{1} << 62));
  for (const char* k : {"scaling", "dither", "seed"}) {
    if (t.contains(k) && !t.contains("bits")) {
      return InvalidArgument(path + ": [quantize] " + k +
                             " goes with bits (per-column quantization); the default "
                             "error_ratio mode has one step and no " +
                             k);
    }
  }
  return Status::Ok();
}

// [cpca]: clusters, basis size, iterations and seed.
Status ParseCpca(const std::string& path, const toml::table& t, Recipe::Cpca* c) {
  LTB_RETURN_IF_ERROR(CheckKeys(path, t, "[cpca]", {"clusters", "basis", "max_iterations", "seed"}));
  c->present = true;
  LTB_ASSIGN_OR_RETURN(c->clusters, GetUnsigned(path, t, "clusters", c->clusters, 1, 1 << 20));
  LTB_ASSIGN_OR_RETURN(c->basis, GetUnsigned(path, t, "basis", c->basis, 0, 1 << 16));
  LTB_ASSIGN_OR_RETURN(c->max_iterations, GetUnsigned(path, t, "max_iterations", c->max_iterations, 1, 100000));
  LTB_ASSIGN_OR_RETURN(c->seed, GetUnsigned(path, t, "seed", c->seed, 0, uint64_t{1} << 62));
  return Status::Ok();
}

}  // namespace

Result<Recipe> ParseRecipe(const std::string& path_in) {
  std::error_code ec;
  std::string path = fs::absolute(path_in, ec).lexically_normal().string();
  if (ec) path = path_in;
  LTB_ASSIGN_OR_RETURN(toml::table root, tomlf::ParseFile(path, "recipe"));
  Recipe r;
  r.path = path;
  r.dir = fs::path(path).parent_path().string();
  LTB_RETURN_IF_ERROR(CheckKeys(path, root, "the recipe",
                                {"name", "scene", "workdir", "targets", "keep", "sample", "row-transform", "transpose",
                                 "column-transform", "quantize", "cpca", "relight", "triple"}));
  LTB_ASSIGN_OR_RETURN(r.name, GetString(path, root, "name", fs::path(path).stem().string()));
  if (r.name.empty()) return InvalidArgument(Where(path, *root.get("name")) + ": \"name\" is empty");

  const toml::node* scene = root.get("scene");
  if (scene == nullptr) {
    return InvalidArgument(path +
                           ": the recipe names no scene: add scene = \"scene.toml\" (a path relative to the "
                           "recipe) or an inline [scene] table");
  }
  if (auto file = scene->value<std::string>()) {
    LTB_ASSIGN_OR_RETURN(std::string expanded, ExpandVariables(Where(path, *scene), *file));
    r.scene_path = Absolute(r.dir, expanded);
    LTB_RETURN_IF_ERROR(CheckRegular(Where(path, *scene), "scene file", r.scene_path));
  } else if (const toml::table* table = scene->as_table()) {
    LTB_ASSIGN_OR_RETURN(r.inline_scene, InlineScene(path, r.dir, *table));
  } else {
    return InvalidArgument(Where(path, *scene) + ": \"scene\" must be a file path or a [scene] table");
  }

  if (root.contains("workdir")) {
    LTB_ASSIGN_OR_RETURN(std::string w, GetString(path, root, "workdir", ""));
    LTB_ASSIGN_OR_RETURN(std::string expanded, ExpandVariables(Where(path, *root.get("workdir")), w));
    if (expanded.empty()) return InvalidArgument(Where(path, *root.get("workdir")) + ": \"workdir\" is empty");
    r.workdir = Absolute(r.dir, expanded);
  }

  auto table = [&](const char* key) -> Result<const toml::table*> {
    const toml::node* n = root.get(key);
    if (n == nullptr) return static_cast<const toml::table*>(nullptr);
    if (n->as_table() == nullptr)
      return InvalidArgument(Where(path, *n) + ": \"" + key + "\" must be a [" + key + "] table");
    return n->as_table();
  };
  static const toml::table kEmpty;
  LTB_ASSIGN_OR_RETURN(const toml::table* sample, table("sample"));
  LTB_RETURN_IF_ERROR(ParseSample(path, sample ? *sample : kEmpty, &r.sample));
  LTB_ASSIGN_OR_RETURN(const toml::table* rows, table("row-transform"));
  if (rows) {
    LTB_RETURN_IF_ERROR(CheckKeys(path, *rows, "[row-transform]", {"filter", "zstd"}));
    LTB_ASSIGN_OR_RETURN(r.row_transform.filter, GetChoice(path, *rows, "filter", r.row_transform.filter,
                                                           {"haar", "db1", "db2", "db3", "db4"}));
    LTB_ASSIGN_OR_RETURN(r.row_transform.zstd, GetBool(path, *rows, "zstd", r.row_transform.zstd));
  }
  LTB_ASSIGN_OR_RETURN(const toml::table* tr, table("transpose"));
  if (tr) {
    LTB_RETURN_IF_ERROR(CheckKeys(path, *tr, "[transpose]", {"zstd"}));
    LTB_ASSIGN_OR_RETURN(r.transpose.zstd, GetBool(path, *tr, "zstd", r.transpose.zstd));
  }
  LTB_ASSIGN_OR_RETURN(const toml::table* ct, table("column-transform"));
  LTB_RETURN_IF_ERROR(ParseColumnTransform(path, ct ? *ct : kEmpty, &r.column_transform));
  LTB_ASSIGN_OR_RETURN(const toml::table* q, table("quantize"));
  if (q) LTB_RETURN_IF_ERROR(ParseQuantize(path, *q, &r.quantize));
  LTB_ASSIGN_OR_RETURN(const toml::table* cpca, table("cpca"));
  if (cpca) LTB_RETURN_IF_ERROR(ParseCpca(path, *cpca, &r.cpca));
  LTB_ASSIGN_OR_RETURN(const toml::table* relight, table("relight"));
  if (relight) LTB_RETURN_IF_ERROR(ParseRelight(path, r.dir, *relight, &r.relight));
  LTB_ASSIGN_OR_RETURN(const toml::table* tri, table("triple"));
  if (tri) LTB_RETURN_IF_ERROR(ParseTriple(path, r.dir, *tri, &r.triple));

  LTB_ASSIGN_OR_RETURN(r.targets, GetStringList(path, root, "targets", StageNames()));
  if (!root.contains("targets")) {
    // A [triple] table means a vertex-mode scene, which has no image for quantize.
    r.targets = {r.triple.present ? "triple" : "quantize"};
    if (r.cpca.present) r.targets.push_back("cpca");
    if (r.relight.present) r.targets.push_back("relight");
  }
  if (r.targets.empty()) return InvalidArgument(Where(path, *root.get("targets")) + ": \"targets\" is empty");
  if (std::count(r.targets.begin(), r.targets.end(), "triple") && !r.triple.present) {
    return InvalidArgument(Where(path, *root.get("targets")) +
                           ": \"targets\" asks for triple but the recipe has no [triple] table (materials, envs, eye)");
  }
  if (std::count(r.targets.begin(), r.targets.end(), "relight") && !r.relight.present) {
    return InvalidArgument(Where(path, *root.get("targets")) +
                           ": \"targets\" asks for relight but the recipe has no [relight] table (envs, terms, ...)");
  }
  if (root.contains("keep")) {
    LTB_ASSIGN_OR_RETURN(std::vector<std::string> keep, GetStringList(path, root, "keep", IntermediateNames()));
    r.keep.insert(keep.begin(), keep.end());
  } else {
    r.keep = {"rows", "cols", "cols4d"};
  }
  if (r.relight.present && r.relight.reference) r.keep.insert("rows");  // the reference relighting reads rows.ltm
  return r;
}

}  // namespace ltb::pipeline
