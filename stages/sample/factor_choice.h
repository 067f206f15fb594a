// `sample --factor auto:T` (docs/GLOSSY.md "Choosing K"): the fewest BRDF terms K whose in-out
// factorisation of every glossy material the vertex rows use has a relative L2 error of ρ·cos
// at most T, from the factorisation's own singular values (the error the sampler prints).
#pragma once

#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include "format/status.h"
#include "stages/sample/scene.h"

namespace ltb::sample {

// The most terms auto may choose (sample --factor's own limit).
inline constexpr uint32_t kMaxFactorTerms = 64;

struct FactorChoice {
  uint32_t terms = 1;          // K: 1 when no material the rows use is glossy
  double worst_error = 0;      // the largest of the materials' errors at K
  std::string worst_material;  // whose it is ("" for none)
  // Per glossy material the rows use: its errors at K = 1..kMaxFactorTerms.
  std::vector<std::pair<std::string, std::vector<double>>> errors;
};

// K for `target` (0 < target < 1) on the vertex scene `s`, tables of incident_res² and
// view_res² parabolic cells (as the bake's). FailedPrecondition when a material's lobe needs
// more than kMaxFactorTerms, naming it, its error there and the triple-product path.
Result<FactorChoice> ChooseFactorTerms(const SceneDesc& s, double target, uint32_t incident_res, uint32_t view_res);

}  // namespace ltb::sample
