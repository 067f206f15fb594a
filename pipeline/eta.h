// How long the rest of a bake will take (`ltbake run`'s step lines, docs/RECIPE.md "Progress"):
// a model of each stage's wall seconds as a + b·G, G the gigabytes of the bake's matrix
// (rows × columns × 4 bytes), per stage and the options that change its cost (the column
// transform's mode, a relight's reference), fitted on the 2-core machine
// (bench/eta_model.py), scaled by how fast this run's finished steps went against the model. Sampling's cost (spp,
// bounces, the scene's geometry) is not modelled: its own progress bar has an ETA, and the bake's appears once the
// matrix exists.
#pragma once

#include <cstdint>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <vector>

namespace ltb::pipeline {

// A step as the model sees it: the stages it does and its parameters (a node's: for a fused
// step, keyed by stage).
struct EtaStep {
  std::vector<std::string> stages;
  nlohmann::json params;
};

class BakeEta {
 public:
  // The matrix's size (rows × columns × 4 bytes), once known.
  void SetMatrixBytes(uint64_t bytes) { matrix_bytes_ = bytes; }
  bool known() const { return matrix_bytes_ > 0; }
  // A step that ran to its end in `wall_seconds`.
  void Finished(const EtaStep& step, double wall_seconds);
  // The wall seconds `steps` should take; nothing before the matrix's size is known or when
  // a step is not modelled (sampling, cpca, triple products).
  std::optional<double> Seconds(const std::vector<EtaStep>& steps) const;
  // This run's speed against the model: its finished modelled steps' seconds over the
  // model's (1 until one has finished).
  double speed_factor() const { return model_seconds_ > 0 ? measured_seconds_ / model_seconds_ : 1.0; }

 private:
  // The model's seconds for one step, or nothing for one it does not model.
  std::optional<double> Model(const EtaStep& step) const;
  uint64_t matrix_bytes_ = 0;
  double measured_seconds_ = 0, model_seconds_ = 0;
};

// "about 25 s" / "about 3 min" / "about 1.2 h".
std::string ApproxDuration(double seconds);

}  // namespace ltb::pipeline
