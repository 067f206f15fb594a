// The stages of `ltbake run`, one row each: what a stage reads and writes, whether it can
// run as shards, and how a recipe's keys become its command line. Recipe parsing (the
// stage names a recipe may target), the graph (dependencies, outputs), sharding and the
// command of each step all read this table, so adding a stage to bakes is adding a row
// here (plus its `cli/cmd_<stage>.cpp`).
#pragma once

#include <functional>
#include <nlohmann/json.hpp>
#include <string>
#include <string_view>
#include <vector>

#include "pipeline/recipe.h"

namespace ltb::pipeline {

// What one step of the graph runs: the work-directory files it reads, the parameters its
// output depends on (besides its inputs' content) and the stage command after the
// executable (without -o and the common flags).
struct StageCommand {
  std::vector<std::string> inputs;
  nlohmann::json params = nlohmann::json::object();
  std::vector<std::string> args;
};

// Paths in the work directory, and the scene file a sample step reads.
struct StageContext {
  std::function<std::string(const std::string&)> path;
  std::string scene_file;
};

struct StageInfo {
  std::string_view name;
  std::string_view output;  // the work-directory file it makes ("" for relight, material, triple: one per item)
  std::vector<std::string_view> needs;  // stages whose outputs it reads (relight's depend on the recipe)
  bool shardable = false;               // can run as shards and be committed (docs/cluster.md)
  std::string_view summary;             // one line, for plans and docs
  // The step's command from the recipe; empty for relight and triple (one step per map) and
  // material (one per material), built by the graph.
  std::function<StageCommand(const Recipe&, const StageContext&)> command;
  // A colour or factor set (docs/COLOUR.md, docs/GLOSSY.md) runs one step per member file.
  bool per_set_member = false;
  // Ray-casts the scene file: its step depends on the scene's (and its meshes') hash.
  bool reads_scene = false;
  // Flags every shard of it gets (docs/cluster.md).
  std::vector<std::string_view> shard_args = {};
  // Set for a stage that runs inside the one stage it needs, as one step, when that stage's
  // output is not kept (`keep`) and that stage is no target (sample + row-transform: no
  // raw.ltm): the flags the needed stage's command then also takes. The fused step is named
  // "NEEDED+STAGE", writes this stage's output and records both stages' params.
  std::function<std::vector<std::string>(const Recipe&)> fused_args = nullptr;
};
// Whether the step running `stages` (a node's) reads the scene (its first stage's row says).
bool ReadsScene(const std::vector<std::string>& stages);

// Every stage, in graph order (an input before the stages that read it).
const std::vector<StageInfo>& StageTable();
// nullptr when `name` is no stage.
const StageInfo* FindStage(std::string_view name);
// The stages a stage needs in this recipe (relight: the matrix it relights, and rows.ltm
// for a reference).
std::vector<std::string> StageNeeds(const Recipe& recipe, std::string_view name);
// The shortest text that reads back as the same double ("0.05", "1.1").
std::string Shortest(double v);

}  // namespace ltb::pipeline
