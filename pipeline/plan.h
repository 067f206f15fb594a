// Planning a bake (`ltbake run`): for every step of the graph, whether it runs, resumes, is
// redone or skipped, and why. Pure logic over what the caller observed (the last run's
// records, the outputs on disk, the input hashes): nothing here reads a file, so every rule
// is unit-tested directly (tests/pipeline/plan_test.cpp).
#pragma once

#include <functional>
#include <map>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "pipeline/graph.h"
#include "pipeline/workdir.h"

namespace ltb::pipeline {

// What a step does in this run.
enum class Action {
  kRun,     // its output is not there (or has no record): made from scratch
  kResume,  // interrupted: the stage goes on from its committed chunks
  kRedo,    // made otherwise (parameters, inputs, a changed file, --force): removed and made again
  kSkip,    // up to date
  kGiven,   // before --from: its output is used as it is
};

// "run", "resume", "redo", "skip", "given" (as in run.json and the summary table).
const char* ActionName(Action a);

struct Decision {
  Action action = Action::kRun;
  std::string reason;
  bool runs() const { return action == Action::kRun || action == Action::kResume || action == Action::kRedo; }
};

// What this run knows of a work file's content_hash.
class FileHash {
 public:
  enum class State {
    kKnown,        // value() is its content_hash
    kBeingRemade,  // a step before it runs: known once that step is done
    kOnDisk,       // complete on disk but not hashed yet (a --from input): hashed when reached
  };
  FileHash() = default;
  static FileHash Known(std::string h) { return FileHash(State::kKnown, std::move(h)); }
  static FileHash BeingRemade() { return FileHash(State::kBeingRemade, {}); }
  static FileHash OnDisk() { return FileHash(State::kOnDisk, {}); }
  State state() const { return state_; }
  bool known() const { return state_ == State::kKnown; }
  const std::string& value() const { return value_; }
  // As a step's inputs record it in run.json: the hash, "" while being remade,
  // "(computed when run)" before it is hashed.
  std::string ForRecord() const;

 private:
  FileHash(State s, std::string v) : state_(s), value_(std::move(v)) {}
  State state_ = State::kBeingRemade;
  std::string value_;
};

// A record's "output" object (an empty one when it has none).
nlohmann::json RecordOutput(const nlohmann::json& record);

// "a.b 1 -> 2, c (default) -> true": what differs between two parameter objects.
std::string ParamDiff(const nlohmann::json& before, const nlohmann::json& now, const std::string& prefix);

// Decides one step. `record` is its entry in the last run.json (nullptr: none), `inputs`
// its inputs' hashes as ForRecord() gives them, `out` what is at its output; `needed`:
// a later step that runs reads its output (or the recipe keeps it), `needed_reason` why.
Decision Decide(const Node& n, const nlohmann::json* record, const nlohmann::json& inputs, const OutputState& out,
                bool forced, const std::string& needed_reason, bool needed);

// What the planner is told about the run.
struct PlanInput {
  const Graph* graph = nullptr;
  const std::map<std::string, nlohmann::json>* previous = nullptr;  // node name -> last record
  std::function<bool(const Node&)> before_from;                     // not run: given (--from)
  std::function<bool(const Node&)> forced;                          // --force
  std::function<OutputState(const Node&)> inspect;                  // what is at its output
  // The step's inputs as ForRecord() gives them, from the hashes known so far.
  std::function<nlohmann::json(const Node&, const std::map<std::string, FileHash>&)> inputs_of;
  std::map<std::string, FileHash> hashes;  // work file -> hash, before any step
  std::string from;                        // --from (for the reason of a given step)
};

struct Plan {
  std::vector<Decision> steps;                   // one per graph node
  std::map<std::string, std::string> needed_by;  // node -> why its output must exist
  std::vector<OutputState> outputs;              // what was on disk at each step's output
};

// Decides every step, then makes sure the files the running steps read will exist (an
// intermediate that was not kept is remade when a later step needs it again), to a fixed
// point.
Plan PlanSteps(const PlanInput& in);

// The first step that runs and reads the output of a step before --from that is not there
// (or not complete): its error, naming both and what to do. OK when there is none.
Status CheckGivenInputs(const Graph& g, const Plan& plan, const PlanInput& in, const std::string& from,
                        const std::function<std::string(const std::string&)>& path_of);

}  // namespace ltb::pipeline
