// `relight X.ltm --eye ...` for a vertex bake (docs/GLOSSY.md): a factored one (`sample
// --factor K`) or a plain one (diffuse: K = 1, g_0 = 1). The K terms T_k relit under the map
// once, P_k = T_k·L per vertex, then per view each vertex's
// B(x, ω_o) = Σ_k g_k(ω_o in x's tangent frame)·P_k(x) for its material's view factors,
// and the mesh rendered with Embree primary rays, B interpolated across each triangle.
// VertexRenderer does it for any number of lightings and views (ltbake view).
#pragma once

#include <cstdint>
#include <glm/vec3.hpp>
#include <limits>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "format/progress.h"
#include "format/status.h"
#include "stages/brdf/brdf_factor.h"
#include "stages/images/envmap.h"
#include "stages/relight/relight_matrix.h"
#include "stages/sample/camera.h"
#include "stages/sample/scene_geometry.h"

namespace ltb::stages {

// A vertex bake's terms, its mesh and its view factors, held for rendering from any eye.
class VertexRenderer {
 public:
  // `set`: a factored set X.ltm (X.k0.ltm ..), or one vertex bake (a file or a colour set);
  // the first `use_terms` BRDF terms are opened (0: all), each with mem_limit / their count.
  static Result<VertexRenderer> Open(const std::string& set, uint32_t use_terms, uint64_t mem_limit, int jobs,
                                     const Progress& progress);
  uint32_t terms_in_bake() const { return terms_in_bake_; }
  uint32_t terms_used() const { return static_cast<uint32_t>(m_.size()); }
  uint64_t vertices() const { return geo_.vertex_rows.size(); }
  const LightingBasis& basis() const { return m_.front().basis(); }
  // The vertex rows' bounding box (for a default view).
  glm::dvec3 low() const { return low_; }
  glm::dvec3 high() const { return high_; }
  // P_k = T_k·L for every term held: `cube` is the lighting (6R² × 3, pixel basis), `terms`
  // the lighting terms each keeps (the N largest, area weighting; kAll: every one).
  static constexpr uint64_t kAll = std::numeric_limits<uint64_t>::max();
  Status Relight(const std::vector<float>& cube, uint64_t terms);
  // Term 0's lighting terms of the last Relight (what `view` tints on its map strip), how
  // many the lighting has, and the fraction of its energy (Σ of squares) they hold.
  const LightTerms& terms() const { return terms0_; }
  uint64_t terms_available() const { return terms_available_; }
  double energy_kept() const { return energy_kept_; }
  // One view after Relight: every vertex's B (rows × 3) and the image (width·height × 3),
  // both × 2^exponent (the lighting was relit at 2^-exponent) and checked finite.
  Status Render(const glm::dvec3& eye, const sample::PinholeCamera& camera, int exponent, const std::string& env,
                std::vector<float>* b, std::vector<float>* image);

 private:
  VertexRenderer() = default;
  std::vector<RelightMatrix> m_;
  sample::Geometry geo_;
  // Per material, its view factors g_0..g_{K−1} (empty: a diffuse material, g_0 = 1).
  std::vector<std::vector<brdf::ParabolicTable>> g_;
  uint32_t terms_in_bake_ = 1;
  int jobs_ = 2;
  glm::dvec3 low_{0}, high_{0};
  std::vector<std::vector<float>> p_;  // P_k
  LightTerms terms0_;
  uint64_t terms_available_ = 0;
  double energy_kept_ = 1;
  std::vector<sample::PixelHit> hits_;
};

struct GlossyViewOptions {
  std::string set;  // X.ltm, the set X.k0.ltm .. X.k{K−1}.ltm, or one vertex bake
  std::string env;
  EnvLayout env_layout = EnvLayout::kAuto;
  bool clamp_env = false;
  double rotate_deg = 0;
  static constexpr uint64_t kAll = std::numeric_limits<uint64_t>::max();
  uint64_t terms = kAll;   // lighting terms kept per T_k (the N largest, area weighting); kAll: exact
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
