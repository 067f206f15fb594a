// One step of `ltbake run --shards N` (docs/cluster.md): the shards of a matrix stage that
// are not done yet run through the engine (a local process pool or Slurm job arrays), then
// all N are validated and committed as a stage manifest.
#pragma once

#include <nlohmann/json.hpp>
#include <string>

#include "pipeline/bake.h"
#include "pipeline/graph.h"

namespace ltb::pipeline {

// How a step of a bake ended.
struct StepEnd {
  BakeEnd end = BakeEnd::kOk;
  int signal = 0;            // kInterrupted: SIGINT or SIGTERM
  std::string failure;       // kFailed/kInterrupted: what happened and what to do
  std::string content_hash;  // kOk of a sharded step: the committed manifest's
};

struct ShardedStepInput {
  const Node* node = nullptr;
  std::string output;                      // the step's output path (the manifest)
  std::string logs;                        // the work directory's logs/
  std::string resume_command;              // `ltbake run ...` that continues this run (ContinueCommand)
  const nlohmann::json* record = nullptr;  // the step's entry in the last run.json
  bool trust_record = false;               // same parameters, inputs and shard count as that entry
  bool overwrite = false;
};

// Runs the step's shards that are not done and commits them, filling `entry` (its run.json
// record: engine, shards, wall and commit seconds, status on failure).
StepEnd RunShardedStep(const BakeOptions& o, const ShardedStepInput& in, nlohmann::json& entry);

}  // namespace ltb::pipeline
