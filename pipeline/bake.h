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
#include <optional>
#include <string>
#include <vector>

#include "format/status.h"
#include "pipeline/shards.h"

namespace ltb::pipeline {

// How a bake (or one of its steps) ended.
enum class BakeEnd {
  kOk,
  kFailed,       // a stage failed, or its output cannot be read back
  kInterrupted,  // SIGINT/SIGTERM: what was committed is kept, a rerun resumes
};

// A step of the bake as it happens, for the caller to show (the library does not print).
struct StepEvent {
  enum class Kind {
    kSkipped,       // up to date (or not needed): not run
    kStarting,      // about to run, resume or redo
    kImageWritten,  // a relight step wrote its image; `metrics` is relight's JSON
  };
  Kind kind = Kind::kStarting;
  std::string node;            // "sample+row-transform", "relight:sunset", ...
  std::string action;          // "skip", "run", "resume", "redo" (pipeline/plan.h ActionName)
  std::string reason;          // why
  std::string path;            // kImageWritten: the image
  nlohmann::json metrics;      // kImageWritten
  size_t step = 0, steps = 0;  // this is step `step` (from 1) of the bake's `steps`
  // kStarting: the wall seconds this step and the ones after it that run should take
  // (pipeline/eta.h; nothing before the matrix exists or when a step is not modelled), and
  // those since the bake started.
  std::optional<double> eta_seconds;
  double elapsed_seconds = 0;
};

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
  // Where messages go (the library does not print): on_step() for each step's decision and
  // result, say() for the engine's lines about shards, stage output is passed on through
  // stage_stdout()/stage_stderr().
  std::function<void(const StepEvent&)> on_step;
  std::function<void(const std::string&)> say;
  std::function<void(std::string_view)> stage_stdout, stage_stderr;
  std::function<int()> pending_signal;  // SIGINT/SIGTERM received (0: none)
  // The process exit code of an ending (the CLI's table), recorded in run.json.
  std::function<int(BakeEnd, int signal)> exit_code_for;
};

// A step of a --dry-run plan.
struct PlannedStep {
  std::string node;
  std::string action;  // "run", "resume", "redo", "skip", "given"
  std::string reason;
  std::string command;  // the stage command, shell-quoted, for a step that runs
  // A sharded step on the Slurm engine: its job script (path and text) and the sbatch line
  // of its job array (every shard; those already done are left out when it runs).
  std::string script_path, script, submit;
};

struct BakeOutcome {
  BakeEnd end = BakeEnd::kOk;
  int signal = 0;                 // kInterrupted: SIGINT or SIGTERM
  std::string report_path;        // run.json (empty for --dry-run)
  std::string recipe_path;        // the recipe, absolute
  std::string workdir;            // the work directory, absolute
  nlohmann::json stages;          // run.json's step records, in graph order (the summary)
  std::vector<PlannedStep> plan;  // --dry-run: every step, decided
  std::string failure;            // what failed, the log and the command that re-runs just that stage
};

// The command that continues this run where it stopped: `ltbake run RECIPE` with every
// option that changes where or how it runs (--workdir, --from, --until, --jobs, --mem-limit,
// the engine's), shell-quoted; --force and --dry-run are left out (a rerun should resume,
// not redo). Every hint that says "rerun" prints this.
std::string ContinueCommand(const BakeOptions& options, const std::string& recipe_path);

// Errors (a bad recipe, a work directory of another bake, an input that does not exist)
// come back as a Status; stage failures and interruptions as an outcome with its exit code.
Result<BakeOutcome> RunBake(const BakeOptions& options);

}  // namespace ltb::pipeline
