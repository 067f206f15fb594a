// `ltbake run RECIPE`: runs the stage graph a recipe asks for, like make but keyed on
// content and parameters (docs/RECIPE.md). Each stage runs as a child process
// (`ltbake <stage> ...`); a stage whose output is complete and was made from the same
// input content_hash with the same parameters is skipped, an interrupted one resumes, one
// made otherwise is redone. Every decision, each stage's log, wall time, peak RSS, paths,
// sizes and content_hash go into run.json in the work directory.
#pragma once

#include <cstdint>
#include <functional>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "format/status.h"
#include "pipeline/shards.h"

namespace ltb::pipeline {

struct BakeOptions {
  std::string recipe;
  std::string workdir;             // overrides the recipe's
  std::string from, until;         // stage names; empty: the whole graph
  std::vector<std::string> force;  // stages to redo; "all" redoes every stage
  bool dry_run = false;
  int jobs = 2;
  std::string mem_limit = "1GiB";  // given to each stage in turn (stages run one at a time)
  bool progress = false;           // ask stages to draw progress bars (forwarded to stderr)
  bool quiet = false;
  std::string ltbake;  // the ltbake executable stages are run with
  // Sharding (docs/cluster.md): with shards > 1, stages other than cpca and relight run as
  // shards through the engine ("local": a process pool; "slurm": job arrays), then are
  // committed. jobs, say and pending_signal are taken from these options.
  EngineOptions cluster;
  // Where messages go (the library does not print): say() for stdout, stage output is
  // passed on through stage_stdout()/stage_stderr().
  std::function<void(const std::string&)> say;
  std::function<void(std::string_view)> stage_stdout, stage_stderr;
  std::function<int()> pending_signal;  // SIGINT/SIGTERM received (0: none)
};

struct BakeOutcome {
  int exit_code = 0;        // 0 ok, 1 a stage failed, 130/143 interrupted
  std::string report_path;  // run.json (empty for --dry-run)
  std::string summary;      // the summary table (or the plan, for --dry-run)
  std::string failure;      // what failed, the log and the command that re-runs just that stage
};

// Errors (a bad recipe, a work directory of another bake, an input that does not exist)
// come back as a Status; stage failures and interruptions as an outcome with its exit code.
Result<BakeOutcome> RunBake(const BakeOptions& options);

}  // namespace ltb::pipeline
