// `ltbake relight vis.ltm --material mat.ltm --env sky.exr --eye X,Y,Z -o out.png`: relighting
// with the view and the lighting both changing, by triple product integrals in Haar wavelets
// (Ng, Ramamoorthi, Hanrahan 2004, §5 and §7; docs/TRIPLE.md "Rendering").
//
// Per vertex x the outgoing radiance towards the eye is B(x) = ∫ L(ω) V(x, ω) ρ̃(x, ω) dω:
// L the environment (RGB, per frame), V the visibility field (`sample --visibility`), ρ̃ the
// vertex's material — albedo × a Lambert field looked up at its normal plus ks × a Phong
// field looked up at the reflection of the view about the normal, each interpolated
// bilinearly between the four nearest sampled directions of the field. The image is the
// vertex values interpolated over the triangles the camera's primary rays hit (Embree).
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

namespace ltb::triple {

enum class TripleMethod {
  kLinear,     // every coefficient of the (approximated) inputs, parent sums by DP: O(R²) a vertex
  kSublinear,  // the kept terms only, lazy parent sums: O(terms · log R) a vertex
  kPixel,      // the reference Σ_p L_p V_p ρ̃(ω_p) Ω_p with ρ̃ evaluated exactly (no field, no terms)
  kShared,     // linear's result: each sampled BRDF row lit once a frame, ⟨V, Haar(L ⊙ ρ̃_row)⟩ a vertex
};
Result<TripleMethod> ParseTripleMethod(const std::string& name);
const char* TripleMethodName(TripleMethod m);

struct RenderOptions {
  std::string visibility;              // vis.ltm
  std::vector<std::string> materials;  // material fields (ltbake material); one Lambert, Phong per exponent
  std::string scene;                   // overrides the scene the visibility field names
  std::string env;                     // .exr / .hdr, or a 6R² × 3 cubemap .npy
  stages::EnvLayout env_layout = stages::EnvLayout::kAuto;
  bool clamp_env = false;
  double rotate_deg = 0;  // the environment about +Z

  glm::dvec3 eye{0, -3, 1.5}, target{0, 0, 0}, up{0, 0, 1};
  double fov_degrees = 40;  // vertical
  uint32_t width = 256, height = 256;
  // A camera path: `orbit_frames` frames, the eye turning by `orbit_deg` a frame about the
  // +Z axis through the target; `output` is then a printf pattern with one integer (%04d).
  double orbit_deg = 0;
  uint32_t orbit_frames = 0;
  // With orbit_frames: the environment turns this much further a frame about +Z (frame k is
  // lit by the map at rotate_deg + k·light_turn_deg): light and view changing together.
  double light_turn_deg = 0;

  TripleMethod method = TripleMethod::kShared;
  static constexpr uint64_t kAll = std::numeric_limits<uint64_t>::max();
  uint64_t light_terms = kAll;  // wavelet terms of the lighting (the N largest over the cube)
  uint64_t brdf_terms = kAll;   // wavelet terms kept of each sampled BRDF row (the largest)

  std::string output;         // .png, .exr or .npy (height·width × 3); empty: none
  std::string vertex_output;  // .npy, every vertex's B (rows × 3) for the first frame; empty: none
  double exposure = 0;        // PNG exposure (0: automatic)
  uint64_t mem_limit = 0;     // the environment map loader's budget; 0: its own cap
  int jobs = 2;
};

struct RenderResult {
  nlohmann::json report;             // docs/TRIPLE.md lists the keys
  std::vector<float> image;          // the first frame, height·width × 3
  std::vector<float> vertex_values;  // with vertex_output: rows × 3
};

Result<RenderResult> RunTripleRender(const RenderOptions& options, const Progress& progress);

}  // namespace ltb::triple
