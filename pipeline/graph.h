// The graph of a bake (`ltbake run`): which steps a recipe's targets need, in order, each
// with the files it reads and writes, the parameters its output depends on and its stage
// command; --from/--until/--force are checked here. Pure logic on the recipe and the
// stage table (pipeline/stage_table.h): no files are read, so it is unit-tested directly
// (tests/pipeline/graph_test.cpp). bake.cpp decides and runs the steps.
#pragma once

#include <nlohmann/json.hpp>
#include <set>
#include <string>
#include <vector>

#include "format/status.h"
#include "pipeline/bake.h"
#include "pipeline/recipe.h"

namespace ltb::pipeline {

// One step of the bake: a stage run on files in the work directory.
struct Node {
  std::string name;                 // "sample", "sample+row-transform", "relight:sunset", ...
  std::vector<std::string> stages;  // the graph stages it does (for --from, --until, --force)
  std::vector<std::string> inputs;  // work-directory files made by earlier nodes
  std::string output;               // work-directory file it makes
  bool image = false;               // output is an image (relight), not a container
  std::string env;                  // relight: the environment map
  nlohmann::json params;            // what the output depends on besides its inputs' content
  std::vector<std::string> args;    // the stage command after the executable, without -o and common flags
};

struct Graph {
  std::vector<Node> nodes;
  std::set<std::string> targets;  // graph stages whose results are wanted
  std::set<std::string> wanted;   // work-directory files to leave on disk
};

// The position of a stage in StageNames() (its size when `s` is no stage).
int StageIndex(const std::string& s);

// The steps the recipe's targets (or --until) need; fused sample + row-transform when raw.ltm
// is neither kept nor wanted; one relight step per map. `scene_file` is what sample reads.
Result<Graph> BuildGraph(const Recipe& recipe, const BakeOptions& options, const std::string& workdir,
                         const std::string& scene_file);

// What a step runs after the executable: its stage command, -o `output` and the flags every
// step gets (--mem-limit, --jobs, --progress, --overwrite). `shard`: the command of each of
// its shards instead (no --jobs, progress never, the stage table's shard_args; the engine
// adds --shard, --nshards and --jobs). Bake and the sharded steps run exactly this, and
// tests/pipeline/stage_commands_test.cpp parses it through the real command line.
std::vector<std::string> StepArgs(const Node& n, const std::string& output, const BakeOptions& o, bool overwrite,
                                  bool shard = false);

}  // namespace ltb::pipeline
