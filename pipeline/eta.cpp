#include "pipeline/eta.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <string>

namespace ltb::pipeline {
namespace {

// Wall seconds a + b·G of a stage on the 2-core machine, G the matrix's gigabytes: least
// squares over the bundled medium scene's bake (samples/medium-bake.toml's options, and two
// variants of its column transform) at R = 8, 16 and 32 (0.10, 0.40 and 1.61 GB); bench/
// eta_model.py prints the fit again and checks it on bakes it never saw.
struct Cost {
  const char* key;  // the stage, or stage/variant (Key)
  double a, b;
};
constexpr Cost kCosts[] = {
    {"row-transform", 0.00, 1.01},           {"transpose", 0.00, 2.99},  // the fit's a is −0.06
    {"column-transform/budget", 0.38, 9.34}, {"column-transform/adaptive", 0.22, 2.92},
    {"column-transform/fixed", 0.15, 1.83},  {"quantize", 0.24, 1.40},
    {"relight/reference", 0.10, 1.34},       {"relight", 0.11, 0.31},
};

// The stage's entry in kCosts: the column transform by its mode (a budget or an error
// target over every column, an adaptive depth per column, a fixed depth), a relight by
// whether it also relights the reference exactly.
std::string Key(const std::string& stage, const nlohmann::json& p) {
  if (stage == "column-transform") {
    if (p.contains("budget") || p.contains("target_error")) return stage + "/budget";
    return stage + (p.value("depth", std::string("adaptive")) == "adaptive" ? "/adaptive" : "/fixed");
  }
  if (stage == "relight") return p.value("reference", false) ? stage + "/reference" : stage;
  return stage;
}

}  // namespace

std::optional<double> BakeEta::Model(const EtaStep& step) const {
  if (matrix_bytes_ == 0 || step.stages.empty()) return std::nullopt;
  const double g = static_cast<double>(matrix_bytes_) / 1e9;
  double seconds = 0;
  for (const std::string& s : step.stages) {
    // A fused step's parameters are keyed by stage.
    const nlohmann::json& p = step.stages.size() > 1 && step.params.contains(s) ? step.params[s] : step.params;
    const std::string key = Key(s, p.is_object() ? p : nlohmann::json::object());
    const Cost* c = nullptr;
    for (const Cost& k : kCosts)
      if (key == k.key) c = &k;
    if (c == nullptr) return std::nullopt;  // sampling, cpca, triple products: not modelled
    seconds += c->a + c->b * g;
  }
  return seconds;
}

void BakeEta::Finished(const EtaStep& step, double wall_seconds) {
  const std::optional<double> m = Model(step);
  if (!m || !(wall_seconds >= 0)) return;
  measured_seconds_ += wall_seconds;
  model_seconds_ += *m;
}

std::optional<double> BakeEta::Seconds(const std::vector<EtaStep>& steps) const {
  double total = 0;
  for (const EtaStep& step : steps) {
    const std::optional<double> m = Model(step);
    if (!m) return std::nullopt;
    total += *m;
  }
  return total * speed_factor();
}

std::string ApproxDuration(double seconds) {
  char b[48];
  if (seconds < 90) {
    std::snprintf(b, sizeof b, "about %.0f s", std::max(1.0, std::round(seconds)));
  } else if (seconds < 5400) {
    std::snprintf(b, sizeof b, "about %.0f min", std::round(seconds / 60));
  } else {
    std::snprintf(b, sizeof b, "about %.1f h", seconds / 3600);
  }
  return b;
}

}  // namespace ltb::pipeline
