// `ltbake relight MATRIX --env ENV -o IMAGE` as a library call (docs/RELIGHT.md): opens the
// matrix (final.ltm / cols4d.ltm / cols.ltm in memory with Eq. 8, cpca.ltm per cluster,
// rows.ltm / raw.ltm streamed), the environment (a map resampled to the bake's cubemap, or
// a ready cubemap .npy), keeps the N-term lighting approximation, relights, applies the
// output policy (mask-0 rows black, negatives clamped), writes IMAGE, optionally times
// rotating frames and measures the errors against an uncompressed reference. The CLI
// (cli/cmd_relight.cpp) only parses flags and prints the report.
#pragma once

#include <cstdint>
#include <limits>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "format/progress.h"
#include "format/status.h"
#include "stages/images/envmap.h"
#include "stages/relight/relight.h"

namespace ltb::stages {

struct RelightOptions {
  std::string matrix;
  std::string env;  // .exr / .hdr (EnvLoadOptions) or a 6R² × 3 cubemap .npy
  // Instead of `env`: a 6R² × 3 cubemap in memory (the Python module); `env` names it.
  std::vector<float> env_cubemap;
  std::string output;  // .exr, .png or .npy; empty: none written (return_image)
  static constexpr uint64_t kAllTerms = std::numeric_limits<uint64_t>::max();
  uint64_t terms = 100;  // ≥ 1; kAllTerms keeps every nonzero coefficient
  Weighting weighting = Weighting::kArea;
  std::string reference;  // uncompressed matrix for the error metrics (empty: none)
  int frames = 0;         // timing frames, the environment rotating once about +Z
  // Rotation of the environment about +Z for the written image, within ±kMaxRotateDegrees
  // (beyond that a double no longer holds a fraction of a turn).
  static constexpr double kMaxRotateDegrees = 1e6;
  double rotate_deg = 0;
  double exposure = 0;         // PNG exposure, 0..kMaxExposure (image_io.h; 0: automatic)
  bool keep_negative = false;  // --no-clamp-output
  EnvLayout env_layout = EnvLayout::kAuto;
  bool clamp_env = false;
  uint64_t mem_limit = 1ull << 30;
  int jobs = 2;
  // RelightResult::image holds the image written (for the Python module): the values a
  // .npy output holds, bit for bit.
  bool return_image = false;
};

// The report `--json` prints (docs/RELIGHT.md lists its keys): matrix, env, terms,
// weighting, load and per-frame times, terms_used / terms_basis / terms_available /
// lighting_energy_kept, output (masked_rows, clamped_values), frames, and with a reference
// error / error_lighting_only / error_matrix_only.
struct RelightResult {
  nlohmann::json report;
  std::vector<float> image;  // rows × 3, with RelightOptions::return_image
};

// How reports spell a terms count: N, or "all" for RelightOptions::kAllTerms.
nlohmann::json TermsJson(uint64_t terms);

// rotate_deg finite and within ±kMaxRotateDegrees, exposure in [0, kMaxExposure]: an
// InvalidArgument naming the flag and the value otherwise (a caller other than the CLI, whose
// flags are checked while parsing, may pass anything).
Status CheckRelightNumbers(const RelightOptions& o);

// Cancelled (progress.Cancelled()) between timing frames, after the image is written.
Result<RelightResult> RunRelight(const RelightOptions& options, const Progress& progress);

}  // namespace ltb::stages
