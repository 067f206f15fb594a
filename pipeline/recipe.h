// A bake recipe (docs/RECIPE.md): the scene, each stage's parameters, which stages' results
// are wanted, which intermediates to keep, and the work directory. Parsed strictly: every
// unknown key is an error naming its line; every value is checked when the recipe is read,
// so a bad recipe fails before any stage runs.
#pragma once

#include <cstdint>
#include <glm/vec3.hpp>
#include <optional>
#include <set>
#include <string>
#include <vector>

#include "format/status.h"

namespace ltb::pipeline {

// The stages of a bake, in graph order (docs/RECIPE.md "The stage graph"): the names of
// the rows of StageTable() (pipeline/stage_table.h).
const std::vector<std::string>& StageNames();

// The intermediates a recipe may keep, by file stem (raw.ltm, rows.ltm, ...).
inline const std::vector<std::string>& IntermediateNames() {
  static const std::vector<std::string> names = {"raw", "rows", "cols", "cols4d"};
  return names;
}

struct EnvMap {
  std::string name;  // output image stem: relit-<name>.<format>
  std::string path;  // absolute, ${VAR}s expanded
  // The table's env_layout (relight --env-layout): "auto" reads the layout from the size.
  std::string layout = "auto";
};

struct Recipe {
  std::string path;  // absolute path of the recipe file
  std::string dir;   // its directory: relative paths in the recipe are relative to it
  std::string name;  // identifies the bake in its work directory (default: the file's stem)

  // The scene: a file, or the inline [scene] table written out as TOML (mesh paths made
  // absolute) that the run saves as scene.toml in the work directory.
  std::string scene_path;
  std::string inline_scene;

  std::string workdir;               // absolute; empty when the recipe gives none (then --workdir is needed)
  std::vector<std::string> targets;  // stages whose results are wanted (default: quantize, + relight if configured)
  std::set<std::string> keep;        // intermediates kept on disk (default: rows, cols, cols4d)

  struct Sample {
    std::optional<uint64_t> cube_res, spp, bounces, seed;  // unset: the scene's [sampling] values
    bool sparse = false;        // sparse precomputation (docs/SPARSE.md); the keys below are its flags
    bool sparse_force = false;  // sparse = "force": sparse regardless (--sparse); else --sparse auto
    std::optional<double> dense_fraction, radius, l1_lambda, max_residual;
    std::optional<uint64_t> features, neighbours;
    // "rgb": one matrix per colour channel, every later step once per channel file
    // (docs/COLOUR.md); "mono" (the default): one matrix.
    std::string channels = "mono";
    // The BRDF in-out factorisation's terms (docs/GLOSSY.md); 0: none. Each term is its own
    // step (sample --factor K --factor-term k), and so is every later container step.
    uint64_t factor = 0;
    // factor = "auto:T": the fewest terms within T (sample --factor auto:T), chosen from the
    // scene when the bake is planned (factor then holds it).
    std::optional<double> factor_target;
    // Converged sampling (sample --tolerance, --max-levels; docs/SAMPLE.md); unset: fixed spp.
    std::optional<double> tolerance;
    std::optional<uint64_t> max_levels;
  } sample;
  struct RowTransform {
    std::string filter = "haar";
    bool zstd = false;
  } row_transform;
  struct Transpose {
    bool zstd = false;
  } transpose;
  struct ColumnTransform {
    std::string filter = "legall53";
    std::string depth = "adaptive";
    std::string depth_where;  // "recipe.toml:12" when the recipe gives depth (for messages)
    // At most one of: keep (fraction of each column's terms), terms (per column), budget,
    // target_error (relative RMS error); none given means budget = "5%".
    std::optional<double> keep;
    std::optional<uint64_t> terms;
    std::optional<std::string> budget;
    std::optional<double> target_error;
    bool zstd = true;
  } column_transform;
  struct Quantize {
    // One step for the matrix (quantize --error-ratio) unless `bits` is given (per-column
    // maxima, quantize --bits, which scaling, dither and seed go with).
    double error_ratio = 1.1;
    std::optional<uint64_t> bits;
    std::string scaling = "level";
    bool dither = false;
    uint64_t seed = 1;
  } quantize;
  struct Cpca {
    bool present = false;               // a [cpca] table was given
    uint64_t clusters = 16, basis = 8;  // K clusters, S principal directions each
    uint64_t max_iterations = 30, seed = 1;
  } cpca;
  struct Relight {
    bool present = false;          // a [relight] table was given
    std::string matrix = "final";  // final | cpca
    std::vector<EnvMap> envs;
    uint64_t terms = 100;
    std::string weighting = "area";
    bool clamp = false;
    bool reference = false;      // compare with the uncompressed rows.ltm (which is then kept)
    std::string format = "png";  // png | exr | mp4 (mp4: with a sequence, the default then)
    double exposure = 0;
    std::string sequence;        // relight --sequence (docs/SEQUENCE.md); empty: one image a map
    std::string method = "pbi";  // with a sequence: pbi | bi | nwa
    // A view of a factored bake ([sample] factor; relight --eye): eye given, the rest theirs.
    std::optional<glm::dvec3> eye;
    glm::dvec3 target{0, 0, 0}, up{0, 0, 1};
    double fov = 40;
    uint64_t width = 256, height = 256;
  } relight;

  // The triple-product path (docs/TRIPLE.md): a visibility field, material fields and one
  // view per map of a vertex-mode scene.
  struct Triple {
    bool present = false;
    uint64_t cube_res = 32;  // the visibility and material fields' R
    std::optional<uint64_t> spp;
    std::vector<std::string> materials;  // --brdf specs: "lambert", "phong:64", ...
    std::vector<EnvMap> envs;
    glm::dvec3 eye{0, -3, 1.5}, target{0, 0, 0}, up{0, 0, 1};
    double fov = 40;
    uint64_t width = 256, height = 256;
    std::string method = "shared";
    std::string terms = "all", brdf_terms = "all";  // N or "all"
    bool clamp = false;
    std::string format = "png";  // png | exr | npy
    double exposure = 0;
  } triple;

  bool Keeps(const std::string& intermediate) const { return keep.count(intermediate) != 0; }
};

// Reads and checks a recipe. Errors name the file, the line and the key.
Result<Recipe> ParseRecipe(const std::string& path);

}  // namespace ltb::pipeline
