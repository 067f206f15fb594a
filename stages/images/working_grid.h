// Internal to the envmap library (stages/images/envmap.h is the public header): the working
// lat-long grid CubemapResampler integrates over (docs/ENVMAPS.md "Resampling", step 1).
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "format/progress.h"
#include "format/status.h"
#include "stages/images/envmap.h"

namespace ltb::stages::envmap_internal {

// The source reduced to the working lat-long grid: hw × ww × 3 values (`work`, row-major,
// row 0 at the top), and the source's power (Σ radiance × solid angle).
struct WorkingGrid {
  uint64_t hw = 0, ww = 0;
  uint64_t target_rows = 0, target_cols = 0;
  double power[3] = {0, 0, 0};
  std::vector<double> work;
};

// The working grid of any layout for an R-cubemap: a lat-long source averaged exactly onto
// it, crosses, faces and angular maps splatted into it.
Result<WorkingGrid> BuildWorkingGrid(const EnvMap& env, uint64_t R, const Progress& progress);

// The grid's values as one table (2 MB-aligned, huge pages advised when large, + 1 pad value
// for a 4-lane load at the end); shared by copies of a resampler.
Result<std::shared_ptr<double[]>> WorkingTable(const std::string& path, const WorkingGrid& g);

// "interrupted" when cancellation is asked for; polled every kRowsPerPoll of `i` (rows of a
// pass: a huge source or R = 512 takes seconds).
Status PollCancel(const Progress& progress, const std::string& path, uint64_t R, uint64_t i, const char* pass);

}  // namespace ltb::stages::envmap_internal
