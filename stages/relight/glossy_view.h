// `relight X.ltm --eye ...` for a factored bake (`sample --factor K`, docs/GLOSSY.md): the K
// terms T_k relit under the map once, P_k = T_k·L per vertex, then per view each vertex's
// B(x, ω_o) = Σ_k g_k(ω_o in x's tangent frame)·P_k(x) for its material's view factors,
// and the mesh rendered with Embree primary rays, B interpolated across each triangle.
#pragma once

#include <cstdint>
#include <glm/vec3.hpp>
#include <limits>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "format/progress.h"
#include "format/status.h"
#include "stages/images/envmap.h"

namespace ltb::stages {

struct GlossyViewOptions {
  std::string set;  // X.ltm, the set X.k0.ltm .. X.k{K−1}.ltm
  std::string env;
  EnvLayout env_layout = EnvLayout::kAuto;
  bool clamp_env = false;
  double rotate_deg = 0;
  static constexpr uint64_t kAll = std::numeric_limits<uint64_t>::max();
  uint64_t terms = kAll;   // lighting terms kept per T_k (the N largest, area weighting)
  uint32_t use_terms = 0;  // BRDF terms used: the first use_terms of K (0: all)
  glm::dvec3 eye{0, -3, 1.5}, target{0, 0, 0}, up{0, 0, 1};
  double fov_degrees = 40;
  uint32_t width = 256, height = 256;
  double orbit_deg = 0;       // the eye turning by this a frame about +Z through the target
  uint32_t orbit_frames = 0;  // 0: one view; else -o is a %d pattern
  std::string output;         // .png, .exr, .npy (height·width × 3)
  std::string vertex_output;  // .npy of every vertex's B for the first view
  double exposure = 0;
  uint64_t mem_limit = 0;
  int jobs = 2;
};

struct GlossyViewResult {
  nlohmann::json report;     // docs/GLOSSY.md lists the keys
  std::vector<float> image;  // the first view
};

Result<GlossyViewResult> RunGlossyView(const GlossyViewOptions& options, const Progress& progress);

}  // namespace ltb::stages
