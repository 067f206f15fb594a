// The driver of `ltbake run`: prepares the work directory and the graph, plans
// (pipeline/plan.h), then runs the steps in order, recording each in run.json. Steps run as
// child processes (pipeline/process.h), or as shards (pipeline/sharded_step.h).
#include "pipeline/bake.h"

#include <algorithm>
#include <chrono>
#include <csignal>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <set>
#include <sstream>

#include "format/io/array_summary.h"
#include "format/io/atomic_file.h"
#include "format/io/container_reader.h"
#include "format/io/file_hash.h"
#include "format/io/file_lock.h"
#include "format/json_text.h"
#include "format/version.h"
#include "pipeline/eta.h"
#include "pipeline/graph.h"
#include "pipeline/plan.h"
#include "pipeline/process.h"
#include "pipeline/recipe.h"
#include "pipeline/run_report.h"
#include "pipeline/sharded_step.h"
#include "pipeline/stage_table.h"
#include "pipeline/workdir.h"
#include "stages/column_transform/column_transform.h"
#include "stages/sample/factor_choice.h"
#include "stages/sample/sample.h"
#include "stages/sample/scene.h"
#include "stages/wavelet/wavelet.h"

namespace ltb::pipeline {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

// Steps that run as shards when --shards N > 1: the matrix stages (cpca's clustering is
// global; relight makes an image).
// A sparse sample (docs/SPARSE.md) is one sequence of rounds: it runs whole.
bool Shardable(const Node& n) {
  const StageInfo* s = FindStage(n.stages.front());
  const json& sample = n.params.contains("sample") ? n.params["sample"] : n.params;
  const bool sparse = sample.is_object() && sample.contains("sparse");
  return !n.image && !sparse && s != nullptr && s->shardable;
}

}  // namespace

std::string ContinueCommand(const BakeOptions& o, const std::string& recipe_path) {
  const BakeOptions defaults;
  const EngineOptions engine_defaults;
  std::vector<std::string> c = {"ltbake", "run", recipe_path};
  auto add = [&c](const std::string& flag, const std::string& value) { c.insert(c.end(), {flag, value}); };
  if (!o.workdir.empty()) add("--workdir", o.workdir);
  if (!o.from.empty()) add("--from", o.from);
  if (!o.until.empty()) add("--until", o.until);
  if (o.jobs != defaults.jobs) add("--jobs", std::to_string(o.jobs));
  if (o.mem_limit != defaults.mem_limit) add("--mem-limit", o.mem_limit);
  const EngineOptions& e = o.cluster;
  if (e.engine != engine_defaults.engine) add("--engine", e.engine);
  if (e.shards != engine_defaults.shards) add("--shards", std::to_string(e.shards));
  if (!e.partition.empty()) add("--partition", e.partition);
  if (e.cpus_per_task != engine_defaults.cpus_per_task) add("--cpus-per-task", std::to_string(e.cpus_per_task));
  if (!e.mem.empty()) add("--mem", e.mem);
  for (const auto& a : e.sbatch_args) c.push_back("--sbatch-arg=" + a);
  if (e.retries != engine_defaults.retries) add("--retries", std::to_string(e.retries));
  return ShellQuote(c);
}

namespace {

StepEnd Interrupted(int sig, std::string failure) {
  return {BakeEnd::kInterrupted, sig == SIGTERM ? SIGTERM : SIGINT, std::move(failure), {}};
}

class Bake {
 public:
  Bake(const BakeOptions& o, Recipe r) : o_(o), r_(std::move(r)) {}

  Result<BakeOutcome> Run();

 private:
  std::string Path(const std::string& file) const { return (fs::path(workdir_) / file).string(); }
  // Before planning: the work directory (locked), the last run's records, the graph.
  Status OpenWorkdir();
  Status ReadPreviousReport();
  Status PrepareGraph();
  PlanInput MakePlanInput() const;
  BakeOutcome DryRun(const Plan& plan) const;
  // One step: given, skipped or run. kOk goes on to the next step.
  Result<StepEnd> RunStep(size_t i, const Plan& plan);
  Status GivenStep(const Node& n);
  StepEnd RunChildStep(const Node& n, const std::vector<std::string>& cmd, const std::string& log, json& e);
  StepEnd RecordDone(const Node& n, const std::string& known_hash, json& e);
  Result<BakeOutcome> Finish(const StepEnd& end);

  bool BeforeFrom(const Node& n) const;
  bool Forced(const Node& n) const;
  Result<std::string> ContentHashOf(const Node& n, const std::string& path) const;
  json InputsOf(const Node& n, const std::map<std::string, FileHash>& hashes) const;
  // Hashes again the files outside the work directory that step n reads (the scene and its
  // meshes, an environment map): they may have changed since the run was planned.
  Status RefreshSourceHashes(const Node& n);
  // After step n ran: a source file whose hash differs from the one taken just before it
  // ran changed while it ran, so what it read is unknown; its record says so, and the next
  // run does the step again.
  Status CheckSourcesUnchanged(const Node& n, const json& before, json& e);
  std::vector<std::string> Command(const Node& n, bool overwrite) const;
  void DeleteUnneeded(size_t upto);
  Status SaveReport();
  void Emit(StepEvent::Kind kind, const Node& n, const std::string& action, const std::string& reason,
            std::optional<double> eta = std::nullopt) const {
    const double elapsed = std::chrono::duration<double>(std::chrono::steady_clock::now() - started_).count();
    if (o_.on_step) o_.on_step({kind, n.name, action, reason, {}, {}, step_, g_.nodes.size(), eta, elapsed});
  }
  // The bake's matrix size for the ETA, from the first output that holds a "matrix" array.
  void LearnMatrixSize(const std::string& path);
  // The wall seconds steps i.. that run should take (BakeEta), recorded in step i's entry.
  std::optional<double> RemainingSeconds(size_t i, const Plan& plan) const;

  const BakeOptions& o_;
  Recipe r_;
  std::string workdir_, scene_file_, scene_hash_;
  bool workdir_existed_ = false;
  io::FileLock lock_;
  int from_ = -1;    // StageIndex of --from; -1: none
  size_t step_ = 0;  // the step RunStep is at, from 1 (for the step events)
  Graph g_;
  std::map<std::string, json> previous_;                 // node -> its entry in the last run.json
  std::set<std::string> ours_;                           // files earlier runs of this recipe made
  std::map<std::string, FileHash> hash_of_;              // work file -> content_hash, as known this run
  mutable std::map<std::string, std::string> env_hash_;  // environment map -> its bytes' hash
  json entries_ = json::array();
  json report_;
  std::set<std::string> forced_;
  BakeEta eta_;
  std::chrono::steady_clock::time_point started_ = std::chrono::steady_clock::now();
};

void Bake::LearnMatrixSize(const std::string& path) {
  if (eta_.known()) return;
  auto r = io::ContainerReader::Open(path);
  if (!r.ok()) return;  // a manifest of shards, an image, a missing file: another step's output tells
  const int a = r->metadata().FindArray("matrix");
  if (a < 0) return;
  const format::ArraySpec& m = r->metadata().arrays[static_cast<size_t>(a)];
  eta_.SetMatrixBytes(m.rows * m.cols * 4);
}

std::optional<double> Bake::RemainingSeconds(size_t i, const Plan& plan) const {
  std::vector<EtaStep> steps;
  for (size_t j = i; j < g_.nodes.size(); ++j)
    if (j == i || (j < plan.steps.size() && plan.steps[j].runs()))
      steps.push_back({g_.nodes[j].stages, g_.nodes[j].params});
  return eta_.Seconds(steps);
}

bool Bake::BeforeFrom(const Node& n) const {
  if (from_ < 0) return false;
  for (const auto& s : n.stages)
    if (StageIndex(s) >= from_) return false;
  return true;
}

// Steps that ray-cast the scene file (the stage table's reads_scene): their output depends
// on its (and its meshes') hash.
bool ReadsScene(const Node& n) { return pipeline::ReadsScene(n.stages); }

bool Bake::Forced(const Node& n) const {
  for (const auto& s : n.stages)
    if (forced_.count(s)) return true;
  return false;
}

std::vector<std::string> Bake::Command(const Node& n, bool overwrite) const {
  std::vector<std::string> c = {o_.ltbake};
  for (std::string& a : StepArgs(n, Path(n.output), o_, overwrite)) c.push_back(std::move(a));
  return c;
}

Result<std::string> Bake::ContentHashOf(const Node& n, const std::string& path) const {
  if (n.image) return io::HashFileHex(path);
  LTB_ASSIGN_OR_RETURN(io::ContainerReader reader, io::ContainerReader::Open(path));
  // The stage's writer recorded it while writing (a manifest: its shards' writers did).
  if (std::string recorded = reader.RecordedContentHash(0); !recorded.empty()) return recorded;
  LTB_ASSIGN_OR_RETURN(io::ArraySummary s, io::SummarizeArray(reader, 0, o_.jobs));
  if (s.content_hash.empty()) return FailedPrecondition(path + ": is incomplete");
  return s.content_hash;
}

json Bake::InputsOf(const Node& n, const std::map<std::string, FileHash>& hashes) const {
  json in = json::object();
  if (ReadsScene(n)) in["scene"] = scene_hash_;
  for (const auto& f : n.inputs) {
    auto it = hashes.find(f);
    in[f] = it == hashes.end() ? std::string() : it->second.ForRecord();
  }
  if (n.image) {
    // Hashed once per run: every planning round and the step itself ask again.
    auto it = env_hash_.find(n.env);
    if (it == env_hash_.end()) {
      auto h = io::HashFileHex(n.env);
      it = env_hash_.emplace(n.env, h.ok() ? *h : std::string("unreadable")).first;
    }
    in["env"] = it->second;
  }
  return in;
}

Status Bake::RefreshSourceHashes(const Node& n) {
  if (n.image) env_hash_.erase(n.env);
  if (ReadsScene(n) && !(o_.dry_run && !r_.inline_scene.empty())) {
    auto h = stages::SceneHash(scene_file_);
    if (!h.ok()) return h.status().WithContext("scene of recipe " + r_.path);
    scene_hash_ = *h;
  }
  return Status::Ok();
}

Status Bake::CheckSourcesUnchanged(const Node& n, const json& before, json& e) {
  LTB_RETURN_IF_ERROR(RefreshSourceHashes(n));
  const json after = InputsOf(n, hash_of_);
  for (const char* key : {"scene", "env"}) {
    if (!before.contains(key) || after.value(key, json()) == before[key]) continue;
    const std::string what = std::string(key) == "env" ? "environment map " + n.env : "scene " + scene_file_;
    e["inputs"][key] = "changed while the step ran (" + before[key].get<std::string>() + " before, " +
                       after.value(key, std::string()) + " after)";
    e["warning"] = "the " + what + " changed while " + n.name +
                   " ran, so which version it read is unknown: the next run does this step again";
    if (o_.say) o_.say("ltbake run: warning: " + e["warning"].get<std::string>());
  }
  return Status::Ok();
}

// This run's entries, then the records of nodes it has not reached (or does not have:
// --until, a recipe that changed) so that no record is lost when a run stops early.
Status Bake::SaveReport() {
  json all = entries_;
  std::set<std::string> seen;
  for (const auto& e : entries_) seen.insert(e.value("node", ""));
  for (const auto& [name, e] : previous_) {
    if (!seen.count(name)) all.push_back(e);
  }
  report_["stages"] = all;
  report_["updated"] = Now();
  LTB_RETURN_IF_ERROR(io::WriteFileAtomically(Path(kRunReport), JsonText(report_, 2) + "\n"));
  return io::WriteFileAtomically(Path(kRunReportPage), RunReportHtml(report_));
}

// Removes intermediates that are not kept once nothing left in this run reads them.
void Bake::DeleteUnneeded(size_t upto) {
  for (size_t i = 0; i < g_.nodes.size() && i <= upto; ++i) {
    const Node& n = g_.nodes[i];
    if (n.image || g_.wanted.count(n.output)) continue;
    bool still_read = false;
    for (size_t j = upto + 1; j < g_.nodes.size(); ++j) {
      for (const auto& f : g_.nodes[j].inputs) still_read = still_read || f == n.output;
    }
    std::error_code ec;
    if (still_read || !fs::exists(Path(n.output), ec)) continue;
    RemoveOutput(Path(n.output), ec);
    for (auto& e : entries_) {
      if (e.value("node", "") == n.name && e.contains("output")) e["output"]["deleted"] = true;
    }
  }
}

Status Bake::OpenWorkdir() {
  workdir_ = !o_.workdir.empty() ? fs::absolute(o_.workdir).lexically_normal().string() : r_.workdir;
  if (workdir_.empty()) {
    return InvalidArgument(r_.path +
                           ": the recipe names no work directory: add workdir = \"DIR\" or pass --workdir DIR");
  }
  for (const auto& f : o_.force) {
    if (f == "all" || f.empty()) {
      for (const auto& s : StageNames()) forced_.insert(s);
    } else {
      forced_.insert(f);
    }
  }
  // The work directory: another recipe's bake there is refused, not overwritten.
  std::error_code ec;
  workdir_existed_ = fs::exists(workdir_, ec);
  if (workdir_existed_ && !fs::is_directory(workdir_, ec)) {
    return InvalidArgument(workdir_ + ": exists and is not a directory");
  }
  // Locked before run.json is read: a run that waited out another one sees what it did.
  if (!o_.dry_run) {
    fs::create_directories(fs::path(workdir_) / "logs", ec);
    if (ec) return IoError(workdir_ + "/logs: cannot create", ec.value());
    LTB_ASSIGN_OR_RETURN(lock_, LockWorkdir(workdir_, o_.pending_signal));
  }
  return ReadPreviousReport();
}

Status Bake::ReadPreviousReport() {
  std::error_code ec;
  if (!workdir_existed_ || !fs::exists(Path(kRunReport), ec)) return Status::Ok();
  std::ifstream in(Path(kRunReport), std::ios::binary);
  std::ostringstream text;
  text << in.rdbuf();
  auto parsed = ParseJson(text.str());
  if (!parsed.ok()) {
    return DataLoss(Path(kRunReport) + ": is not valid JSON (" + parsed.status().message() +
                    "); move it away to start this bake afresh");
  }
  const json prev = std::move(*parsed);
  std::string other = prev.value("recipe", json::object()).value("name", "");
  if (other != r_.name && forced_.size() < StageNames().size()) {
    return FailedPrecondition("work directory " + workdir_ + " holds the bake of another recipe (\"" + other +
                              "\", from " + prev.value("recipe", json::object()).value("path", "?") +
                              "; see its run.json), not \"" + r_.name +
                              "\": use another --workdir, or pass --force to redo every stage there for this recipe");
  }
  if (other == r_.name) {
    for (const auto& e : prev.value("stages", json::array())) {
      previous_[e.value("node", "")] = e;
      if (e.contains("output")) ours_.insert(e["output"].value("file", ""));
    }
  }
  return Status::Ok();
}

Status Bake::PrepareGraph() {
  // The scene: a file, or the recipe's inline table saved in the work directory.
  if (!r_.inline_scene.empty()) {
    scene_file_ = Path("scene.toml");
    if (!o_.dry_run) LTB_RETURN_IF_ERROR(WriteTextIfChanged(scene_file_, r_.inline_scene));
  } else {
    scene_file_ = r_.scene_path;
  }
  if (r_.sample.factor_target) {  // [sample] factor = "auto:T": K from the scene's lobes, as sample chooses it
    auto scene = sample::ParseScene(scene_file_);
    if (!scene.ok()) return scene.status().WithContext("scene of recipe " + r_.path);
    const stages::SampleOptions grid;  // the bake's tables: sample's default grid (a recipe sets no other)
    auto c =
        sample::ChooseFactorTerms(*scene, *r_.sample.factor_target, grid.factor_incident_res, grid.factor_view_res);
    if (!c.ok()) return c.status().WithContext("recipe " + r_.path + ": [sample] factor");
    r_.sample.factor = c->terms;
    if (o_.say && !o_.quiet) {
      char b[200];
      std::snprintf(b, sizeof b, "[sample] factor = \"auto:%g\": K = %u (%s at %.3g)", *r_.sample.factor_target,
                    c->terms, c->worst_material.empty() ? "no glossy material" : c->worst_material.c_str(),
                    c->worst_error);
      o_.say(b);
    }
  }
  LTB_ASSIGN_OR_RETURN(g_, BuildGraph(r_, o_, workdir_, scene_file_));
  from_ = o_.from.empty() ? -1 : StageIndex(o_.from);
  std::error_code ec;
  // Vertex rows have no image for the column transform: say so now, not three stages in.
  if (g_.targets.size() && fs::exists(scene_file_, ec)) {
    auto scene = sample::ParseScene(scene_file_);
    if (!scene.ok()) return scene.status().WithContext("scene of recipe " + r_.path);
    bool column_stages = false;  // "column-transform", or a set's "column-transform.k0", ...
    for (const Node& n : g_.nodes) {
      column_stages =
          column_stages || std::find(n.stages.begin(), n.stages.end(), "column-transform") != n.stages.end();
    }
    const std::string& depth = r_.column_transform.depth;
    const std::string at = r_.column_transform.depth_where.empty() ? r_.path : r_.column_transform.depth_where;
    if (scene->mode == sample::SceneDesc::Mode::kVertex && column_stages && depth != "none") {
      return InvalidArgument(at + ": the scene " + scene_file_ +
                             " has vertex rows (mode = \"vertex\"), which have no image for the adaptive column "
                             "transform (depth = \"" +
                             depth +
                             "\"); set [column-transform] depth = \"none\" (the 2D method), or compress vertex bakes "
                             "with cpca: targets = [\"cpca\"] and a [cpca] table");
    }
    if (scene->mode == sample::SceneDesc::Mode::kImage && column_stages) {
      auto mode = stages::ParseDepthMode(depth);
      const int deepest = wavelet::MaxDepth(scene->camera.width, scene->camera.height);
      if (mode.ok() && mode->kind == stages::DepthMode::Kind::kFixed && mode->fixed > deepest) {
        return InvalidArgument(
            at + ": [column-transform] depth = " + depth + ": the scene's " + std::to_string(scene->camera.width) +
            "x" + std::to_string(scene->camera.height) + " image has at most " + std::to_string(deepest) +
            " analysis steps; give a depth of 0.." + std::to_string(deepest) + ", or \"adaptive\" or \"full\"");
      }
    }
  }
  for (const Node& n : g_.nodes) {
    if (!ReadsScene(n)) continue;
    if (o_.dry_run && !r_.inline_scene.empty() && !fs::exists(scene_file_, ec)) {
      scene_hash_ = "(inline scene, not written yet)";
    } else {
      auto h = stages::SceneHash(scene_file_);
      if (!h.ok()) return h.status().WithContext("scene of recipe " + r_.path);
      scene_hash_ = *h;
    }
  }
  return Status::Ok();
}

PlanInput Bake::MakePlanInput() const {
  PlanInput in;
  in.graph = &g_;
  in.previous = &previous_;
  in.before_from = [this](const Node& n) { return BeforeFrom(n); };
  in.forced = [this](const Node& n) { return Forced(n); };
  in.inspect = [this](const Node& n) { return InspectOutput(n, Path(n.output)); };
  in.inputs_of = [this](const Node& n, const std::map<std::string, FileHash>& h) { return InputsOf(n, h); };
  in.hashes = hash_of_;
  in.from = o_.from;
  return in;
}

BakeOutcome Bake::DryRun(const Plan& plan) const {
  BakeOutcome outcome;
  outcome.recipe_path = r_.path;
  outcome.workdir = workdir_;
  for (size_t i = 0; i < g_.nodes.size(); ++i) {
    const Node& n = g_.nodes[i];
    const Decision& d = plan.steps[i];
    const bool overwrite = ours_.count(n.output) > 0;
    PlannedStep p{n.name, ActionName(d.action), d.reason, d.runs() ? ShellQuote(Command(n, overwrite)) : std::string()};
    if (d.runs() && o_.cluster.engine == "slurm" && o_.cluster.shards > 1 && Shardable(n)) {
      std::vector<std::string> stage = {o_.ltbake};
      for (std::string& a : StepArgs(n, Path(n.output), o_, overwrite, /*shard=*/true)) stage.push_back(std::move(a));
      std::vector<uint64_t> all(o_.cluster.shards);
      for (uint64_t k = 0; k < all.size(); ++k) all[k] = k;
      std::string step = n.name;
      std::replace(step.begin(), step.end(), ':', '-');
      EngineOptions eo = o_.cluster;
      eo.jobs = o_.jobs;
      const SlurmSubmission sub = PlanSlurm(eo, stage, all, step, Path("logs"), eo.sbatch, "ltbake-" + step + "-RUN");
      p.script_path = sub.script_path;
      p.script = sub.script;
      p.submit = ShellQuote(sub.command);
    }
    outcome.plan.push_back(std::move(p));
  }
  return outcome;
}

Result<BakeOutcome> Bake::Finish(const StepEnd& end) {
  static const char* const kStatus[] = {"ok", "failed", "interrupted"};
  report_["status"] = kStatus[static_cast<int>(end.end)];
  if (o_.exit_code_for) report_["exit_code"] = o_.exit_code_for(end.end, end.signal);
  report_["finished"] = Now();
  Status s = SaveReport();
  BakeOutcome outcome;
  outcome.end = end.end;
  outcome.signal = end.signal;
  outcome.failure = end.failure;
  outcome.report_path = Path(kRunReport);
  outcome.recipe_path = r_.path;
  outcome.workdir = workdir_;
  outcome.stages = entries_;
  if (!s.ok() && end.end == BakeEnd::kOk) return s.WithContext("writing the run report");
  if (!s.ok()) outcome.failure += "\n(the run report could not be written: " + s.message() + ")";
  return outcome;
}

// A step before --from: its output is used as it is (hashed if this run does not know it).
Status Bake::GivenStep(const Node& n) {
  const std::string out_path = Path(n.output);
  OutputState out = InspectOutput(n, out_path);
  json entry = {{"node", n.name}, {"stages", n.stages}, {"params", n.params}};
  if (previous_.count(n.name)) entry = previous_[n.name];
  FileHash& h = hash_of_[n.output];
  if (!h.known() || h.value().empty()) {
    LTB_ASSIGN_OR_RETURN(std::string value, ContentHashOf(n, out_path));
    h = FileHash::Known(value);
  }
  entry["action"] = "given";
  entry["reason"] = "before --from " + o_.from;
  for (const char* k : {"wall_seconds", "cpu_seconds", "disk_bytes", "peak_rss_bytes"}) entry.erase(k);
  entry["output"] = {{"file", n.output},
                     {"path", out_path},
                     {"bytes", out.bytes},
                     {"content_hash", h.value()},
                     {"fingerprint", out.fingerprint}};
  if (!entry.contains("status")) entry["status"] = "given";
  entries_.push_back(entry);
  return Status::Ok();
}

// Runs the stage command of a step that is not sharded, filling its record `e`.
StepEnd Bake::RunChildStep(const Node& n, const std::vector<std::string>& cmd, const std::string& log, json& e) {
  ChildIo cio;
  cio.log_path = log;
  if (!o_.quiet && !n.image) cio.on_stdout = o_.stage_stdout;  // relight's JSON goes to run.json
  cio.on_stderr = o_.stage_stderr;
  cio.pending_signal = o_.pending_signal;
  auto child = RunChild(cmd, cio);
  if (!child.ok()) {
    e["status"] = "failed";
    return {BakeEnd::kFailed, 0, "stage " + n.name + " could not be started: " + child.status().message(), {}};
  }
  e["wall_seconds"] = child->wall_seconds;
  e["cpu_seconds"] = {{"user", child->user_seconds}, {"system", child->system_seconds}};
  e["disk_bytes"] = {{"read", child->disk_read_bytes}, {"written", child->disk_write_bytes}};
  e["peak_rss_bytes"] = child->peak_rss_bytes;
  e["exit_code"] = child->exit_code;
  if (n.image) {
    if (auto metrics = ParseJson(child->stdout_text); metrics.ok()) e["metrics"] = std::move(*metrics);
  }
  const int sig = o_.pending_signal ? o_.pending_signal() : 0;
  if (child->exit_code == 130 || child->exit_code == 143 || (child->term_signal == SIGINT) ||
      (child->term_signal == SIGTERM)) {
    e["status"] = "interrupted";
    const bool term = child->exit_code == 143 || child->term_signal == SIGTERM || sig == SIGTERM;
    return Interrupted(term ? SIGTERM : SIGINT, "interrupted during " + n.name +
                                                    "; what it committed is kept: rerun `" +
                                                    ContinueCommand(o_, r_.path) + "` to resume");
  }
  if (child->exit_code == 0) return {};
  e["status"] = "failed";
  std::string why;
  for (const auto& line : child->errors) why += "\n  " + line;
  if (child->term_signal) {
    why += "\n  killed by signal " + std::to_string(child->term_signal) +
           (child->term_signal == SIGKILL ? " (out of memory? try a smaller --mem-limit)" : "");
  }
  if (why.empty()) why = "\n  (no error message; see the log)";
  if (why.find("--overwrite") != std::string::npos) {
    why += "\n  (" + n.output + " in the work directory was not made by this recipe's runs; `ltbake run --force " +
           n.stages.front() + "` replaces it)";
  }
  e["errors"] = child->errors;
  return {BakeEnd::kFailed,
          0,
          "stage " + n.name + " failed (exit " + std::to_string(child->exit_code) + "):" + why + "\n  log: " + log +
              "\n  re-run just this stage: " + ShellQuote(cmd) +
              "\n  or resume the whole bake: " + ContinueCommand(o_, r_.path),
          {}};
}

// A step's stage finished: records what it made (its content_hash read back unless the
// commit of its shards gave it).
StepEnd Bake::RecordDone(const Node& n, const std::string& known_hash, json& e) {
  const std::string out_path = Path(n.output);
  OutputState made = InspectOutput(n, out_path);
  auto t0 = std::chrono::steady_clock::now();
  auto h = known_hash.empty() ? ContentHashOf(n, out_path) : Result<std::string>(known_hash);
  if (!h.ok()) {
    e["status"] = "failed";
    return {BakeEnd::kFailed,
            0,
            "stage " + n.name + " finished but its output cannot be read back: " + h.status().message(),
            {}};
  }
  hash_of_[n.output] = FileHash::Known(*h);
  e["status"] = "done";
  e["finished"] = Now();
  e["output"] = {{"file", n.output},
                 {"path", out_path},
                 {"bytes", made.bytes},
                 {"content_hash", *h},
                 {"fingerprint", made.fingerprint},
                 {"hash_seconds", std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count()}};
  if (n.image && o_.on_step) {
    o_.on_step({StepEvent::Kind::kImageWritten, n.name, "", "", out_path, e.value("metrics", json::object())});
  }
  return {};
}

Result<StepEnd> Bake::RunStep(size_t i, const Plan& plan) {
  const Node& n = g_.nodes[i];
  step_ = i + 1;
  const std::string out_path = Path(n.output);
  if (int sig = o_.pending_signal ? o_.pending_signal() : 0; sig != 0) {
    return Interrupted(sig, "interrupted before " + n.name + "; rerun `" + ContinueCommand(o_, r_.path) + "` to go on");
  }
  if (BeforeFrom(n)) {
    LTB_RETURN_IF_ERROR(GivenStep(n));
    LearnMatrixSize(out_path);
    return StepEnd{};
  }
  LTB_RETURN_IF_ERROR(RefreshSourceHashes(n));
  json inputs = InputsOf(n, hash_of_);
  OutputState out = InspectOutput(n, out_path);
  const json* rec = previous_.count(n.name) ? &previous_[n.name] : nullptr;
  auto why = plan.needed_by.find(n.name);
  const bool needed = why != plan.needed_by.end() || g_.wanted.count(n.output) > 0;
  Decision d = Decide(n, rec, inputs, out, Forced(n), why != plan.needed_by.end() ? why->second : "", needed);
  if (o_.cluster.shards > 1 && Shardable(n) && d.action == Action::kRedo && !out.problem.empty() && !Forced(n) &&
      rec->value("params", json()) == n.params && rec->value("inputs", json()) == inputs) {
    // A manifest that no longer opens (a shard deleted, truncated, rewritten): rerun only the shards
    // that are not intact, then commit again.
    d = {Action::kResume, n.output + " is unreadable (" + out.problem + "); rerunning the shards that are not intact"};
  }
  if (!d.runs()) {
    LearnMatrixSize(out_path);
    Emit(StepEvent::Kind::kSkipped, n, ActionName(d.action), d.reason);
    json entry = *rec;
    entry["action"] = "skip";
    entry["reason"] = d.reason;
    for (const char* k : {"wall_seconds", "cpu_seconds", "disk_bytes", "peak_rss_bytes"}) entry.erase(k);
    hash_of_[n.output] = FileHash::Known(RecordOutput(*rec).value("content_hash", ""));
    entries_.push_back(entry);
    return StepEnd{};
  }
  const bool overwrite = ours_.count(n.output) > 0 || Forced(n);
  if (d.action == Action::kRedo) {
    // Made otherwise (or forced): start afresh, so that not even a file whose metadata
    // happens to match is resumed.
    std::error_code rm;
    RemoveOutput(out_path, rm);
    if (rm) return IoError(out_path + ": cannot remove it to redo " + n.name, rm.value());
  }
  std::vector<std::string> cmd = Command(n, overwrite);
  std::string log = Path("logs/" + std::string(n.name.begin(), n.name.end()) + ".log");
  std::replace(log.begin() + static_cast<long>(Path("logs/").size()), log.end(), ':', '-');
  json entry = {{"node", n.name}, {"stages", n.stages}, {"params", n.params}, {"inputs", inputs}};
  entry["input_paths"] = json::array();
  std::vector<std::string> in_paths;
  for (const auto& f : n.inputs) in_paths.push_back(Path(f));
  if (n.image) in_paths.push_back(n.env);
  if (ReadsScene(n)) in_paths.push_back(scene_file_);
  for (const auto& p : in_paths) {
    std::error_code size_ec;
    uint64_t bytes = fs::file_size(p, size_ec);
    entry["input_paths"].push_back({{"path", p}, {"bytes", size_ec ? json(nullptr) : json(bytes)}});
  }
  entry["action"] = ActionName(d.action);
  entry["reason"] = d.reason;
  entry["command"] = ShellQuote(cmd);
  entry["log"] = log;
  entry["status"] = "running";
  entry["started"] = Now();
  entry["output"] = {{"file", n.output}, {"path", out_path}};
  const std::optional<double> eta = RemainingSeconds(i, plan);
  if (eta) entry["eta_seconds"] = *eta;  // what the step line said was left, this step included
  entries_.push_back(entry);
  ours_.insert(n.output);
  // Record the attempt before it starts: a killed run's next run knows the file is its own.
  if (Status s = SaveReport(); !s.ok()) return s.WithContext("writing the run report");
  Emit(StepEvent::Kind::kStarting, n, ActionName(d.action), d.reason, eta);
  json& e = entries_.back();
  StepEnd ran;
  if (o_.cluster.shards > 1 && Shardable(n)) {
    ShardedStepInput si;
    si.node = &n;
    si.output = out_path;
    si.logs = Path("logs");
    si.resume_command = ContinueCommand(o_, r_.path);
    si.record = rec;
    si.trust_record = rec != nullptr && d.action != Action::kRedo && rec->value("params", json()) == n.params &&
                      rec->value("inputs", json()) == inputs && rec->value("nshards", uint64_t{0}) == o_.cluster.shards;
    si.overwrite = overwrite;
    ran = RunShardedStep(o_, si, e);
  } else {
    ran = RunChildStep(n, cmd, log, e);
  }
  if (ran.end != BakeEnd::kOk) return ran;
  const int sig = o_.pending_signal ? o_.pending_signal() : 0;
  StepEnd done = RecordDone(n, ran.content_hash, e);
  if (done.end != BakeEnd::kOk) return done;
  if (d.action == Action::kRun || d.action == Action::kRedo)  // a resumed step's time is a part's
    eta_.Finished({n.stages, n.params}, e.value("wall_seconds", -1.0));
  LearnMatrixSize(out_path);
  LTB_RETURN_IF_ERROR(CheckSourcesUnchanged(n, inputs, e));
  DeleteUnneeded(i);
  if (sig != 0) {  // the stage finished just as the signal came: stop here
    return Interrupted(sig, "interrupted after " + n.name + "; rerun `" + ContinueCommand(o_, r_.path) + "` to go on");
  }
  if (Status s = SaveReport(); !s.ok()) return s.WithContext("writing the run report");
  return StepEnd{};
}

Result<BakeOutcome> Bake::Run() {
  LTB_RETURN_IF_ERROR(OpenWorkdir());
  LTB_RETURN_IF_ERROR(PrepareGraph());
  report_ = {{"ltbake", std::string(kToolVersion)},
             {"recipe", {{"name", r_.name}, {"path", r_.path}}},
             {"workdir", workdir_},
             {"started", Now()},
             {"command",
              {{"jobs", o_.jobs},
               {"mem_limit", o_.mem_limit},
               {"from", o_.from},
               {"until", o_.until},
               {"force", o_.force},
               {"dry_run", o_.dry_run}}}};
  // Plan: decide every step, and which outputs that were not kept must be made again.
  const PlanInput plan_input = MakePlanInput();
  const Plan plan = PlanSteps(plan_input);
  // A step asked for before its input exists.
  LTB_RETURN_IF_ERROR(
      CheckGivenInputs(g_, plan, plan_input, o_.from, [this](const std::string& f) { return Path(f); }));
  if (o_.dry_run) return DryRun(plan);

  report_["status"] = "running";
  for (size_t i = 0; i < g_.nodes.size(); ++i) {
    LTB_ASSIGN_OR_RETURN(StepEnd end, RunStep(i, plan));
    if (end.end != BakeEnd::kOk) return Finish(end);
  }
  // Intermediates left over by an earlier run that stopped before removing them.
  DeleteUnneeded(g_.nodes.size());
  return Finish(StepEnd{});
}

}  // namespace

Result<BakeOutcome> RunBake(const BakeOptions& options) {
  LTB_ASSIGN_OR_RETURN(Recipe recipe, ParseRecipe(options.recipe));
  Bake bake(options, std::move(recipe));
  return bake.Run();
}

}  // namespace ltb::pipeline
