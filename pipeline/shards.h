// Running one stage of a bake as shards (docs/cluster.md): the shards that are not done
// yet run through an engine, each writing its own file (`--shard I --nshards N`), and the
// step finishes with io::CommitShards, which writes the stage manifest.
//   local: a process pool on this machine (min(shards, jobs) at a time).
//   slurm: one job array per round, `sbatch --wait --array=LIST`; failed shards are
//          resubmitted up to `retries` times. No dependency chains (after a failed task
//          they stay pending forever), so a failure always comes back to this process.
// Each shard's log is WORKDIR/logs/<step>.shard-<I>.log; what each shard did goes into
// run.json through ShardRun.
#pragma once

#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "format/status.h"

namespace ltb::pipeline {

struct EngineOptions {
  std::string engine = "local";  // local | slurm
  uint64_t shards = 1;
  int jobs = 2;  // local: threads in all, split among the processes running at once
                 // (set from BakeOptions::jobs)
  // slurm
  std::string partition;
  int cpus_per_task = 0;  // 0: jobs
  std::string mem;        // --mem per task, e.g. 4G (empty: the cluster's default)
  std::vector<std::string> sbatch_args;
  int retries = 2;  // resubmissions of failed shards
  std::string sbatch = "sbatch", scancel = "scancel";
  // Set from BakeOptions by `ltbake run`:
  std::function<void(const std::string&)> say;
  std::function<int()> pending_signal;
};

struct ShardRun {
  uint64_t index = 0;
  std::string status;  // done | failed | interrupted | skipped (done before this run)
  int attempts = 0;
  std::string log;
  double wall_seconds = 0;  // local engine (slurm: the array's wall time is the step's)
  uint64_t peak_rss_bytes = 0;
  int exit_code = -1;
  std::vector<std::string> errors;  // its "ltbake: error: ..." lines
};

struct ShardedStep {
  std::vector<ShardRun> shards;  // ordered by index; only those asked for
  bool interrupted = false;
  int signal = 0;
  std::vector<std::string> submit_commands;  // slurm: each sbatch command line
};

// Whether shard `index` of `count` of `output` is a sealed, complete shard file.
bool ShardFileComplete(const std::string& output, uint64_t index, uint64_t count, std::string* fingerprint = nullptr);

// What the Slurm engine submits for the shards `todo` of `stage` (argv as for RunShards):
// the job script (its path under `log_dir` and its text, one shard per array task) and the
// sbatch command line of the first round (`sbatch`: the program; `job_name`: unique per
// submission). `ltbake run --dry-run --engine slurm` prints it; RunShards submits it.
struct SlurmSubmission {
  std::string script_path, script;
  std::vector<std::string> command;
};
SlurmSubmission PlanSlurm(const EngineOptions& o, const std::vector<std::string>& stage,
                          const std::vector<uint64_t>& todo, const std::string& step, const std::string& log_dir,
                          const std::string& sbatch, const std::string& job_name);

// Runs the shards in `todo` of `stage` (argv of the stage command, without --shard,
// --nshards and --jobs). `step` names logs and the Slurm job; logs go to `log_dir`.
Result<ShardedStep> RunShards(const EngineOptions& o, const std::vector<std::string>& stage, const std::string& output,
                              const std::vector<uint64_t>& todo, const std::string& step, const std::string& log_dir);

}  // namespace ltb::pipeline
