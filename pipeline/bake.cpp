#include "pipeline/bake.h"

#include <fcntl.h>
#include <sys/file.h>
#include <unistd.h>
#include <xxhash.h>

#include <algorithm>
#include <cerrno>
#include <charconv>
#include <chrono>
#include <csignal>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <map>
#include <set>
#include <sstream>
#include <thread>

#include "format/io/array_summary.h"
#include "format/io/atomic_file.h"
#include "format/io/container_reader.h"
#include "format/io/file.h"
#include "format/io/file_lock.h"
#include "format/io/manifest.h"
#include "format/version.h"
#include "pipeline/graph.h"
#include "pipeline/process.h"
#include "pipeline/recipe.h"
#include "pipeline/shards.h"
#include "pipeline/stage_table.h"
#include "stages/common/basis.h"
#include "stages/sample/sample.h"
#include "stages/sample/scene.h"

namespace ltb::pipeline {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

constexpr const char* kReport = "run.json";

std::string Hex(uint64_t h) {
  char b[17];
  std::snprintf(b, sizeof b, "%016llx", static_cast<unsigned long long>(h));
  return b;
}

Result<std::string> HashFileBytes(const std::string& path) {
  // A FIFO or a device would block the read or never end: refused before opening.
  LTB_RETURN_IF_ERROR(io::RequireRegularFile(path));
  std::ifstream f(path, std::ios::binary);
  if (!f) return NotFound(path + ": cannot open");
  XXH3_state_t* st = XXH3_createState();
  XXH3_64bits_reset(st);
  std::vector<char> buf(1 << 16);
  while (f) {
    f.read(buf.data(), static_cast<std::streamsize>(buf.size()));
    XXH3_64bits_update(st, buf.data(), static_cast<size_t>(f.gcount()));
  }
  uint64_t h = XXH3_64bits_digest(st);
  XXH3_freeState(st);
  return Hex(h);
}

std::string Now() {
  std::time_t t = std::time(nullptr);
  char b[32];
  std::strftime(b, sizeof b, "%Y-%m-%dT%H:%M:%S%z", std::localtime(&t));
  return b;
}

std::string HumanBytes(uint64_t b) {
  char s[32];
  if (b >= (1ull << 30))
    std::snprintf(s, sizeof s, "%.2f GiB", b / double(1ull << 30));
  else if (b >= (1ull << 20))
    std::snprintf(s, sizeof s, "%.1f MiB", b / double(1ull << 20));
  else if (b >= 1024)
    std::snprintf(s, sizeof s, "%.1f KiB", b / 1024.0);
  else
    std::snprintf(s, sizeof s, "%llu B", static_cast<unsigned long long>(b));
  return s;
}

// What is on disk at a node's output.
struct OutputState {
  bool exists = false;
  bool complete = false;    // sealed container, or an image file
  std::string fingerprint;  // stages::Fingerprint, or the image file's hash
  uint64_t committed = 0, total = 0;
  uint64_t bytes = 0;
  std::string problem;  // unreadable: why
};

OutputState Inspect(const Node& n, const std::string& path) {
  OutputState s;
  std::error_code ec;
  if (!fs::exists(path, ec)) return s;
  s.exists = true;
  s.bytes = fs::file_size(path, ec);
  if (n.image) {
    auto h = HashFileBytes(path);
    s.complete = h.ok();
    if (h.ok()) s.fingerprint = *h;
    return s;
  }
  auto reader = io::ContainerReader::Open(path);
  if (!reader.ok()) {
    s.problem = reader.status().message();
    return s;
  }
  s.complete = reader->sealed();
  if (reader->is_manifest()) s.bytes = reader->file_size();  // the manifest and its shards
  for (uint32_t a = 0; a < reader->metadata().arrays.size(); ++a) {
    s.committed += reader->committed(a);
    s.total += reader->metadata().arrays[a].ChunkCount();
  }
  if (s.complete) s.fingerprint = stages::Fingerprint(*reader);
  return s;
}

struct Decision {
  bool run = false;
  std::string action;  // skip | run | resume | redo
  std::string reason;
};

std::string ParamDiff(const json& before, const json& now, const std::string& prefix) {
  std::string out;
  if (before.is_object() && now.is_object()) {
    std::set<std::string> keys;
    for (auto it = before.begin(); it != before.end(); ++it) keys.insert(it.key());
    for (auto it = now.begin(); it != now.end(); ++it) keys.insert(it.key());
    for (const auto& k : keys) {
      json b = before.contains(k) ? before[k] : json(nullptr), a = now.contains(k) ? now[k] : json(nullptr);
      if (b == a) continue;
      std::string d = ParamDiff(b, a, prefix + (prefix.empty() ? "" : ".") + k);
      out += (out.empty() ? "" : ", ") + d;
    }
    return out;
  }
  auto show = [](const json& v) { return v.is_null() ? std::string("(default)") : v.dump(); };
  return prefix + " " + show(before) + " -> " + show(now);
}

// inputs: file -> content_hash ("" while it is being remade).
Decision Decide(const Node& n, const json* record, const json& inputs, const OutputState& out, bool forced,
                const std::string& needed_reason, bool needed) {
  Decision d;
  d.run = true;
  if (forced) {
    d.action = "redo";
    d.reason = "forced (--force)";
    return d;
  }
  for (auto it = inputs.begin(); it != inputs.end(); ++it) {
    if (it.value().get<std::string>().empty()) {
      d.action = out.exists && record ? "redo" : "run";
      d.reason = "its input " + it.key() + " is being remade (skipped if its content comes out the same)";
      return d;
    }
  }
  const bool done = record && record->value("status", "") == "done";
  const bool same_params = record && record->contains("params") && (*record)["params"] == n.params;
  const bool same_inputs = record && record->contains("inputs") && (*record)["inputs"] == inputs;
  if (record && !same_params) {
    d.action = out.exists ? "redo" : "run";
    d.reason = "parameters changed: " + ParamDiff((*record)["params"], n.params, "");
    return d;
  }
  if (record && !same_inputs) {
    d.action = out.exists ? "redo" : "run";
    std::string what;
    const json& before = (*record)["inputs"];
    for (auto it = inputs.begin(); it != inputs.end(); ++it) {
      std::string old = before.contains(it.key()) ? before[it.key()].get<std::string>() : "(none)";
      if (old != it.value().get<std::string>()) {
        what += (what.empty() ? "" : ", ") + it.key() + " " + old + " -> " + it.value().get<std::string>();
      }
    }
    d.reason = "input changed: " + what;
    return d;
  }
  if (!out.exists) {
    if (done && (*record)["output"].value("deleted", false) && !needed) {
      d.run = false;
      d.action = "skip";
      d.reason = "up to date (" + n.output + " was not kept)";
      return d;
    }
    d.action = "run";
    d.reason =
        done ? n.output + " is missing" + (needed_reason.empty() ? "" : " and " + needed_reason) : "not made yet";
    return d;
  }
  if (!out.problem.empty()) {
    d.action = record ? "redo" : "run";
    d.reason = n.output + " is unreadable (" + out.problem + ")";
    return d;
  }
  if (!out.complete) {
    d.action = "resume";
    d.reason =
        "interrupted: " + std::to_string(out.committed) + " of " + std::to_string(out.total) + " chunks committed";
    return d;
  }
  if (!done) {
    d.action = "run";
    d.reason = n.output +
               " exists but run.json has no record of it: the stage checks it (a no-op if it was made "
               "with the same parameters and input)";
    return d;
  }
  if ((*record)["output"].value("fingerprint", "") != out.fingerprint) {
    d.action = "redo";
    d.reason = n.output + " changed since it was made (fingerprint " + (*record)["output"].value("fingerprint", "") +
               " -> " + out.fingerprint + ")";
    return d;
  }
  d.run = false;
  d.action = "skip";
  d.reason = "up to date";
  return d;
}

Status WriteJsonAtomically(const std::string& path, const json& j) {
  return io::WriteFileAtomically(path, j.dump(2) + "\n");
}

Status WriteTextIfChanged(const std::string& path, const std::string& text) {
  std::ifstream in(path, std::ios::binary);
  if (in) {
    std::string old((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    if (old == text) return Status::Ok();
  }
  return io::WriteFileAtomically(path, text);
}

// Holds the work directory for one bake at a time (io::FileLock, the same lock as a stage
// output's). The descriptor is inherited by the stage processes, so a stage orphaned by a
// killed run still holds it until it dies; for that the lock file is never removed.
Result<io::FileLock> LockWorkdir(const std::string& workdir, const std::function<int()>& pending_signal) {
  io::LockOptions o;
  if (pending_signal) o.cancelled = [&pending_signal] { return pending_signal() != 0; };
  o.wait_seconds = 5;  // a run that is just finishing
  o.inherit = true;
  o.remove_on_release = false;
  o.busy_message = [&workdir](const std::string& holder) {
    return "work directory " + workdir + " is in use by " + holder +
           " (another `ltbake run`, or a stage it started that is still finishing); wait for it, or use another "
           "--workdir";
  };
  return io::FileLock::Acquire((fs::path(workdir) / ".ltbake-run.lock").string(), o);
}

std::string Pad(std::string s, size_t w) {
  s.resize(std::max(w, s.size() + 1), ' ');  // a column wider than its field still ends in a space
  return s;
}

std::string SummaryTable(const json& stages) {
  std::ostringstream t;
  t << Pad("stage", 22) << Pad("action", 12) << Pad("wall", 10) << Pad("peak RSS", 11) << Pad("output", 24)
    << Pad("size", 11) << "content_hash\n";
  for (const auto& s : stages) {
    char wall[32] = "-";
    if (s.contains("wall_seconds")) std::snprintf(wall, sizeof wall, "%.2f s", s["wall_seconds"].get<double>());
    std::string rss = s.contains("peak_rss_bytes") ? HumanBytes(s["peak_rss_bytes"].get<uint64_t>()) : "-";
    const json& out = s.value("output", json::object());
    std::string size = out.contains("bytes") ? HumanBytes(out["bytes"].get<uint64_t>()) : "-";
    if (out.value("deleted", false)) size = "(deleted)";
    std::string action = s.value("action", ""), status = s.value("status", "");
    if (status == "interrupted" || status == "failed" || status == "running") action = status;
    if (s.contains("nshards") && action != "skip") action += " " + std::to_string(s["nshards"].get<uint64_t>()) + "sh";
    t << Pad(s.value("node", ""), 22) << Pad(action, 12) << Pad(wall, 10) << Pad(rss, 11)
      << Pad(out.value("file", ""), 24) << Pad(size, 11) << out.value("content_hash", "-") << "\n";
  }
  return t.str();
}

// Steps that run as shards when --shards N > 1: the matrix stages (cpca's clustering is
// global; relight makes an image).
bool Shardable(const Node& n) {
  const StageInfo* s = FindStage(n.stages.front());
  return !n.image && s != nullptr && s->shardable;
}

// Removes a step's output: the file, and for a stage manifest its shard directory.
void RemoveOutput(const std::string& path, std::error_code& ec) {
  fs::remove(path, ec);
  if (ec) return;
  const std::string dir = io::ShardDirectory(path);
  if (fs::exists(dir, ec)) fs::remove_all(dir, ec);
}

class Bake {
 public:
  Bake(const BakeOptions& o, Recipe r) : o_(o), r_(std::move(r)) {}

  Result<BakeOutcome> Run();

 private:
  std::string Path(const std::string& file) const { return (fs::path(workdir_) / file).string(); }
  Result<std::string> ContentHashOf(const Node& n, const std::string& path);
  json InputsOf(const Node& n);
  void DeleteUnneeded(size_t upto);
  Status SaveReport();
  std::vector<std::string> Command(const Node& n, bool overwrite) const;
  // Runs a sharded step's shards that are not done and commits them. Returns 0, or the
  // exit code for finish() with outcome->failure set.
  int RunSharded(const Node& n, const json* record, bool trust_record, bool overwrite, json& entry,
                 std::string* content_hash, std::string* failure);

  const BakeOptions& o_;
  Recipe r_;
  std::string workdir_, scene_file_, scene_hash_;
  Graph g_;
  std::map<std::string, json> previous_;        // node -> its entry in the last run.json
  std::set<std::string> ours_;                  // files earlier runs of this recipe made
  std::map<std::string, std::string> hash_of_;  // work file -> content_hash, known this run
  json entries_ = json::array();
  json report_;
  std::set<std::string> forced_;
};

std::vector<std::string> Bake::Command(const Node& n, bool overwrite) const {
  std::vector<std::string> c = {o_.ltbake};
  c.insert(c.end(), n.args.begin(), n.args.end());
  c.insert(c.end(), {"-o", Path(n.output)});
  if (!n.image) c.insert(c.end(), {"--mem-limit", o_.mem_limit});
  c.insert(c.end(), {"--jobs", std::to_string(o_.jobs), "--progress", o_.progress ? "always" : "never"});
  if (overwrite && !n.image) c.push_back("--overwrite");
  return c;
}

int Bake::RunSharded(const Node& n, const json* record, bool trust_record, bool overwrite, json& e,
                     std::string* content_hash, std::string* failure) {
  const std::string out_path = Path(n.output);
  const uint64_t count = o_.cluster.shards;
  // The stage command of every shard: Command() without --jobs (each engine sets it).
  std::vector<std::string> stage = {o_.ltbake};
  stage.insert(stage.end(), n.args.begin(), n.args.end());
  stage.insert(stage.end(), {"-o", out_path, "--mem-limit", o_.mem_limit, "--progress", "never"});
  if (overwrite) stage.push_back("--overwrite");
  // A transpose shard reads a slice of every row block; its checksum pass would read all
  // of them, in every shard. The commit of its input has just checked every checksum.
  if (n.stages.front() == "transpose") stage.push_back("--no-verify-input");
  e["engine"] = o_.cluster.engine;
  e["nshards"] = count;
  e["command"] = ShellQuote(stage) + " --shard I --nshards " + std::to_string(count) + " --jobs J";

  // Shards this run need not run: done in the recorded attempt (same parameters, inputs
  // and shard count), their file still complete with the fingerprint recorded then.
  std::map<uint64_t, json> done_before;
  if (trust_record && record->contains("shards") && (*record)["shards"].is_array()) {
    for (const json& s : (*record)["shards"]) {
      const std::string st = s.value("status", "");
      if (st != "done" && st != "skipped") continue;
      std::string fp;
      const uint64_t i = s.value("index", count);
      if (i < count && ShardFileComplete(out_path, i, count, &fp) && fp == s.value("fingerprint", "")) {
        done_before[i] = s;
      }
    }
  }
  std::vector<uint64_t> todo;
  for (uint64_t i = 0; i < count; ++i)
    if (!done_before.count(i)) todo.push_back(i);
  if (o_.say && !o_.quiet) {
    o_.say("   " + std::to_string(todo.size()) + " of " + std::to_string(count) + " shards to run (" +
           o_.cluster.engine + " engine)" +
           (done_before.empty() ? "" : ", " + std::to_string(done_before.size()) + " done before"));
  }
  EngineOptions eo = o_.cluster;
  eo.jobs = o_.jobs;
  eo.say = o_.quiet ? nullptr : o_.say;
  eo.pending_signal = o_.pending_signal;
  std::error_code ec;
  fs::create_directories(Path("logs"), ec);
  std::string step = n.name;
  std::replace(step.begin(), step.end(), ':', '-');
  auto t0 = std::chrono::steady_clock::now();
  auto ran = RunShards(eo, stage, out_path, todo, step, Path("logs"));
  e["wall_seconds"] = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  if (!ran.ok()) {
    e["status"] = "failed";
    *failure = "stage " + n.name + ": " + ran.status().message();
    return 1;
  }
  // The shard records: those done before, then this run's.
  json shards = json::array();
  uint64_t peak = 0;
  std::vector<const ShardRun*> failed;
  std::map<uint64_t, json> by_index;
  for (auto& [i, s] : done_before) {
    json r = s;
    r["status"] = "skipped";
    r["attempts"] = 0;
    by_index[i] = r;
  }
  for (const ShardRun& r : ran->shards) {
    json j = {
        {"index", r.index}, {"status", r.status}, {"attempts", r.attempts}, {"log", r.log}, {"exit_code", r.exit_code}};
    if (o_.cluster.engine == "local") {
      j["wall_seconds"] = r.wall_seconds;
      j["peak_rss_bytes"] = r.peak_rss_bytes;
    }
    if (!r.errors.empty()) j["errors"] = r.errors;
    std::string fp;
    if (r.status == "done" && ShardFileComplete(out_path, r.index, count, &fp)) j["fingerprint"] = fp;
    if (r.status == "failed") failed.push_back(&r);
    peak = std::max(peak, r.peak_rss_bytes);
    by_index[r.index] = j;
  }
  for (auto& [i, j] : by_index) shards.push_back(j);
  e["shards"] = shards;
  if (o_.cluster.engine == "local") e["peak_rss_bytes"] = peak;
  if (!ran->submit_commands.empty()) e["submissions"] = ran->submit_commands;
  if (ran->interrupted) {
    e["status"] = "interrupted";
    *failure = "interrupted during " + n.name + "; the shards it finished are kept: rerun `ltbake run " + r_.path +
               "` to run only the others";
    return ran->signal == SIGINT ? 130 : 143;
  }
  if (!failed.empty()) {
    e["status"] = "failed";
    std::string why;
    for (const ShardRun* r : failed) {
      why += "\n  shard " + std::to_string(r->index) + " (" + std::to_string(r->attempts) + " attempt" +
             (r->attempts == 1 ? "" : "s") + ", log " + r->log + ")";
      for (const auto& line : r->errors) why += "\n    " + line;
    }
    std::vector<std::string> one = stage;
    one.insert(one.end(), {"--shard", std::to_string(failed.front()->index), "--nshards", std::to_string(count)});
    *failure = "stage " + n.name + ": " + std::to_string(failed.size()) + " of " + std::to_string(count) +
               " shards failed:" + why + "\n  re-run one shard: " + ShellQuote(one) +
               "\n  or resume the whole bake (runs only the shards not done): ltbake run " + r_.path;
    return 1;
  }
  // Every shard is done: validate them and write the manifest.
  io::CommitOptions co;
  co.overwrite = overwrite;
  co.threads = o_.jobs;
  auto t1 = std::chrono::steady_clock::now();
  auto committed = io::CommitShards(out_path, count, co);
  e["commit_seconds"] = std::chrono::duration<double>(std::chrono::steady_clock::now() - t1).count();
  if (!committed.ok()) {
    e["status"] = "failed";
    *failure = "stage " + n.name + ": its shards ran but cannot be committed: " + committed.status().message();
    return 1;
  }
  if (o_.say && !o_.quiet) {
    o_.say("   committed " + out_path + ": " + std::to_string(count) + " shards, content_hash " +
           committed->content_hash);
  }
  *content_hash = committed->content_hash;
  return 0;
}

Result<std::string> Bake::ContentHashOf(const Node& n, const std::string& path) {
  if (n.image) return HashFileBytes(path);
  LTB_ASSIGN_OR_RETURN(io::ContainerReader reader, io::ContainerReader::Open(path));
  LTB_ASSIGN_OR_RETURN(io::ArraySummary s, io::SummarizeArray(reader, 0, o_.jobs));
  if (s.content_hash.empty()) return FailedPrecondition(path + ": is incomplete");
  return s.content_hash;
}

json Bake::InputsOf(const Node& n) {
  json in = json::object();
  if (n.stages.front() == "sample") in["scene"] = scene_hash_;
  for (const auto& f : n.inputs) {
    auto it = hash_of_.find(f);
    in[f] = it == hash_of_.end() ? std::string() : it->second;
  }
  if (n.image) {
    auto h = HashFileBytes(n.env);
    in["env"] = h.ok() ? *h : std::string("unreadable");
  }
  return in;
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
  return WriteJsonAtomically(Path(kReport), report_);
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

Result<BakeOutcome> Bake::Run() {
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
  const bool existed = fs::exists(workdir_, ec);
  if (existed && !fs::is_directory(workdir_, ec)) return InvalidArgument(workdir_ + ": exists and is not a directory");
  // Locked before run.json is read: a run that waited out another one sees what it did.
  io::FileLock lock;
  if (!o_.dry_run) {
    fs::create_directories(fs::path(workdir_) / "logs", ec);
    if (ec) return IoError(workdir_ + "/logs: cannot create", ec.value());
    LTB_ASSIGN_OR_RETURN(lock, LockWorkdir(workdir_, o_.pending_signal));
  }
  json prev;
  if (existed && fs::exists(Path(kReport), ec)) {
    std::ifstream in(Path(kReport));
    try {
      prev = json::parse(in);
    } catch (const std::exception& e) {
      return DataLoss(Path(kReport) + ": is not valid JSON (" + e.what() + "); move it away to start this bake afresh");
    }
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
  }
  BakeOutcome outcome;
  // The scene: a file, or the recipe's inline table saved in the work directory.
  if (!r_.inline_scene.empty()) {
    scene_file_ = Path("scene.toml");
    if (!o_.dry_run) LTB_RETURN_IF_ERROR(WriteTextIfChanged(scene_file_, r_.inline_scene));
  } else {
    scene_file_ = r_.scene_path;
  }
  LTB_ASSIGN_OR_RETURN(g_, BuildGraph(r_, o_, workdir_, scene_file_));
  // Vertex rows have no image for the column transform: say so now, not three stages in.
  if (g_.targets.size() && fs::exists(scene_file_, ec)) {
    auto scene = sample::ParseScene(scene_file_);
    if (!scene.ok()) return scene.status().WithContext("scene of recipe " + r_.path);
    bool column_stages = false;
    for (const Node& n : g_.nodes) column_stages = column_stages || n.name == "column-transform";
    if (scene->mode == sample::SceneDesc::Mode::kVertex && column_stages) {
      return InvalidArgument(r_.path + ": the scene " + scene_file_ +
                             " has vertex rows (mode = \"vertex\"), which have no image for column-transform and "
                             "quantize to work on; compress vertex bakes with cpca: targets = [\"cpca\"] and a [cpca] "
                             "table");
    }
  }
  for (const Node& n : g_.nodes) {
    if (n.stages.front() == "sample") {
      if (o_.dry_run && !r_.inline_scene.empty() && !fs::exists(scene_file_, ec)) {
        scene_hash_ = "(inline scene, not written yet)";
      } else {
        auto h = stages::SceneHash(scene_file_);
        if (!h.ok()) return h.status().WithContext("scene of recipe " + r_.path);
        scene_hash_ = *h;
      }
    }
  }

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
  // Stages before --from are not run: their outputs must exist and be complete.
  const int from = o_.from.empty() ? -1 : StageIndex(o_.from);
  auto before_from = [&](const Node& n) {
    if (from < 0) return false;
    for (const auto& s : n.stages)
      if (StageIndex(s) >= from) return false;
    return true;
  };
  auto is_forced = [&](const Node& n) {
    for (const auto& s : n.stages)
      if (forced_.count(s)) return true;
    return false;
  };

  // Plan: decide every node, then make sure the files the running nodes read will exist
  // (an intermediate that was not kept is remade when a later stage needs it again).
  std::map<std::string, std::string> needed_by;  // node -> why its output must exist
  std::vector<Decision> plan(g_.nodes.size());
  for (int round = 0; round <= static_cast<int>(g_.nodes.size()); ++round) {
    std::map<std::string, std::string> saved = hash_of_;
    for (size_t i = 0; i < g_.nodes.size(); ++i) {
      const Node& n = g_.nodes[i];
      OutputState out = Inspect(n, Path(n.output));
      if (before_from(n)) {
        plan[i] = {false, "given", "before --from " + o_.from};
        auto rec = previous_.find(n.name);
        if (out.complete && rec != previous_.end() &&
            rec->second["output"].value("fingerprint", "") == out.fingerprint) {
          hash_of_[n.output] = rec->second["output"].value("content_hash", "");
        } else {
          hash_of_[n.output] = out.complete ? "(computed when run)" : "";
        }
        continue;
      }
      json inputs = InputsOf(n);
      const json* rec = previous_.count(n.name) ? &previous_[n.name] : nullptr;
      bool needed = needed_by.count(n.name) > 0 || g_.wanted.count(n.output) > 0;
      plan[i] = Decide(n, rec, inputs, out, is_forced(n), needed_by.count(n.name) ? needed_by[n.name] : "", needed);
      if (plan[i].run) {
        hash_of_[n.output] = "";  // being remade
      } else {
        hash_of_[n.output] = (*rec)["output"].value("content_hash", "");
      }
    }
    bool changed = false;
    for (size_t i = g_.nodes.size(); i-- > 0;) {
      if (!plan[i].run) continue;
      for (const auto& f : g_.nodes[i].inputs) {
        for (size_t u = 0; u < i; ++u) {
          const Node& up = g_.nodes[u];
          if (up.output != f || plan[u].run || before_from(up) || needed_by.count(up.name)) continue;
          if (Inspect(up, Path(f)).complete) continue;
          needed_by[up.name] = g_.nodes[i].name + " needs it";
          changed = true;
        }
      }
    }
    hash_of_ = saved;
    if (!changed) break;
  }
  // A stage asked for before its input exists.
  for (size_t i = 0; i < g_.nodes.size(); ++i) {
    if (!plan[i].run) continue;
    for (const auto& f : g_.nodes[i].inputs) {
      for (size_t u = 0; u < g_.nodes.size(); ++u) {
        if (g_.nodes[u].output == f && before_from(g_.nodes[u]) && !Inspect(g_.nodes[u], Path(f)).complete) {
          return FailedPrecondition("--from " + o_.from + ": " + g_.nodes[i].name + " reads " + Path(f) +
                                    ", which does not exist or is incomplete (" + g_.nodes[u].name +
                                    " makes it); run without --from, or --from " + g_.nodes[u].stages.front());
        }
      }
    }
  }

  if (o_.dry_run) {
    std::ostringstream t;
    t << "plan for " << r_.path << " in " << workdir_ << ":\n";
    for (size_t i = 0; i < g_.nodes.size(); ++i) {
      const Node& n = g_.nodes[i];
      t << "  " << Pad(n.name, 22) << Pad(plan[i].action, 8) << plan[i].reason << "\n";
      if (plan[i].run) t << "      " << ShellQuote(Command(n, ours_.count(n.output) > 0)) << "\n";
    }
    outcome.summary = t.str();
    return outcome;
  }

  report_["status"] = "running";
  auto finish = [&](const std::string& status, int code) -> Result<BakeOutcome> {
    report_["status"] = status;
    report_["exit_code"] = code;
    report_["finished"] = Now();
    Status s = SaveReport();
    outcome.exit_code = code;
    outcome.report_path = Path(kReport);
    outcome.summary = SummaryTable(entries_);
    if (!s.ok() && code == 0) return s.WithContext("writing the run report");
    if (!s.ok()) outcome.failure += "\n(the run report could not be written: " + s.message() + ")";
    return outcome;
  };

  for (size_t i = 0; i < g_.nodes.size(); ++i) {
    const Node& n = g_.nodes[i];
    const std::string out_path = Path(n.output);
    json entry = {{"node", n.name}, {"stages", n.stages}, {"params", n.params}};
    if (int sig = o_.pending_signal ? o_.pending_signal() : 0; sig != 0) {
      outcome.failure = "interrupted before " + n.name + "; rerun `ltbake run " + r_.path + "` to go on";
      return finish("interrupted", sig == SIGTERM ? 143 : 130);
    }
    if (before_from(n)) {  // given: its output is used as it is
      OutputState out = Inspect(n, out_path);
      if (previous_.count(n.name)) entry = previous_[n.name];
      std::string& h = hash_of_[n.output];
      if (h.empty() || h[0] == '(') {
        LTB_ASSIGN_OR_RETURN(h, ContentHashOf(n, out_path));
      }
      entry["action"] = "given";
      entry["reason"] = "before --from " + o_.from;
      entry.erase("wall_seconds");
      entry.erase("peak_rss_bytes");
      entry["output"] = {{"file", n.output},
                         {"path", out_path},
                         {"bytes", out.bytes},
                         {"content_hash", h},
                         {"fingerprint", out.fingerprint}};
      if (!entry.contains("status")) entry["status"] = "given";
      entries_.push_back(entry);
      continue;
    }
    json inputs = InputsOf(n);
    OutputState out = Inspect(n, out_path);
    const json* rec = previous_.count(n.name) ? &previous_[n.name] : nullptr;
    bool needed = needed_by.count(n.name) > 0 || g_.wanted.count(n.output) > 0;
    Decision d = Decide(n, rec, inputs, out, is_forced(n), needed_by.count(n.name) ? needed_by[n.name] : "", needed);
    if (o_.cluster.shards > 1 && Shardable(n) && d.action == "redo" && !out.problem.empty() && !is_forced(n) &&
        rec->value("params", json()) == n.params && rec->value("inputs", json()) == inputs) {
      // A manifest that no longer opens (a shard deleted, truncated, rewritten): rerun only the shards
      // that are not intact, then commit again.
      d.action = "resume";
      d.reason = n.output + " is unreadable (" + out.problem + "); rerunning the shards that are not intact";
    }
    entry["inputs"] = inputs;
    entry["input_paths"] = json::array();
    std::vector<std::string> in_paths;
    for (const auto& f : n.inputs) in_paths.push_back(Path(f));
    if (n.image) in_paths.push_back(n.env);
    if (n.stages.front() == "sample") in_paths.push_back(scene_file_);
    for (const auto& p : in_paths) {
      std::error_code size_ec;
      uint64_t bytes = fs::file_size(p, size_ec);
      entry["input_paths"].push_back({{"path", p}, {"bytes", size_ec ? json(nullptr) : json(bytes)}});
    }
    entry["action"] = d.action;
    entry["reason"] = d.reason;
    if (!d.run) {
      if (o_.say && !o_.quiet) o_.say("== " + n.name + ": skipped, " + d.reason);
      entry = *rec;
      entry["action"] = "skip";
      entry["reason"] = d.reason;
      entry.erase("wall_seconds");
      entry.erase("peak_rss_bytes");
      hash_of_[n.output] = (*rec)["output"].value("content_hash", "");
      entries_.push_back(entry);
      continue;
    }
    const bool overwrite = ours_.count(n.output) > 0 || is_forced(n);
    if (d.action == "redo") {
      // Made otherwise (or forced): start afresh, so that not even a file whose metadata
      // happens to match is resumed.
      std::error_code rm;
      RemoveOutput(out_path, rm);
      if (rm) return IoError(out_path + ": cannot remove it to redo " + n.name, rm.value());
    }
    std::vector<std::string> cmd = Command(n, overwrite);
    std::string log = Path("logs/" + std::string(n.name.begin(), n.name.end()) + ".log");
    std::replace(log.begin() + static_cast<long>(Path("logs/").size()), log.end(), ':', '-');
    entry["command"] = ShellQuote(cmd);
    entry["log"] = log;
    entry["status"] = "running";
    entry["started"] = Now();
    entry["output"] = {{"file", n.output}, {"path", out_path}};
    entries_.push_back(entry);
    ours_.insert(n.output);
    // Record the attempt before it starts: a killed run's next run knows the file is its own.
    if (Status s = SaveReport(); !s.ok()) return s.WithContext("writing the run report");
    if (o_.say && !o_.quiet) o_.say("== " + n.name + ": " + d.action + " (" + d.reason + ")");
    json& e = entries_.back();
    int sig = 0;
    std::string known_hash;  // a sharded step's, from its commit
    if (o_.cluster.shards > 1 && Shardable(n)) {
      const bool trust = rec != nullptr && d.action != "redo" && (*rec).value("params", json()) == n.params &&
                         (*rec).value("inputs", json()) == inputs &&
                         (*rec).value("nshards", uint64_t{0}) == o_.cluster.shards;
      int code = RunSharded(n, rec, trust, overwrite, e, &known_hash, &outcome.failure);
      if (code != 0) return finish(code == 1 ? "failed" : "interrupted", code);
      sig = o_.pending_signal ? o_.pending_signal() : 0;
    } else {
      ChildIo cio;
      cio.log_path = log;
      if (!o_.quiet && !n.image) cio.on_stdout = o_.stage_stdout;  // relight's JSON goes to run.json
      cio.on_stderr = o_.stage_stderr;
      cio.pending_signal = o_.pending_signal;
      auto child = RunChild(cmd, cio);
      if (!child.ok()) {
        e["status"] = "failed";
        outcome.failure = "stage " + n.name + " could not be started: " + child.status().message();
        return finish("failed", 1);
      }
      e["wall_seconds"] = child->wall_seconds;
      e["peak_rss_bytes"] = child->peak_rss_bytes;
      e["exit_code"] = child->exit_code;
      if (n.image) {
        try {
          e["metrics"] = json::parse(child->stdout_text);
        } catch (const std::exception&) {
        }
      }
      sig = o_.pending_signal ? o_.pending_signal() : 0;
      if (child->exit_code == 130 || child->exit_code == 143 || (child->term_signal == SIGINT) ||
          (child->term_signal == SIGTERM)) {
        e["status"] = "interrupted";
        int code = child->exit_code == 143 || child->term_signal == SIGTERM || sig == SIGTERM ? 143 : 130;
        outcome.failure = "interrupted during " + n.name + "; what it committed is kept: rerun `ltbake run " + r_.path +
                          "` to resume";
        return finish("interrupted", code);
      }
      if (child->exit_code != 0) {
        e["status"] = "failed";
        std::string why;
        for (const auto& line : child->errors) why += "\n  " + line;
        if (child->term_signal) {
          why += "\n  killed by signal " + std::to_string(child->term_signal) +
                 (child->term_signal == SIGKILL ? " (out of memory? try a smaller --mem-limit)" : "");
        }
        if (why.empty()) why = "\n  (no error message; see the log)";
        if (why.find("--overwrite") != std::string::npos) {
          why += "\n  (" + n.output +
                 " in the work directory was not made by this recipe's runs; `ltbake run --force " + n.stages.front() +
                 "` replaces it)";
        }
        e["errors"] = child->errors;
        outcome.failure = "stage " + n.name + " failed (exit " + std::to_string(child->exit_code) + "):" + why +
                          "\n  log: " + log + "\n  re-run just this stage: " + ShellQuote(cmd) +
                          "\n  or resume the whole bake: ltbake run " + r_.path;
        return finish("failed", 1);
      }
    }
    // Done: record what it made.
    OutputState made = Inspect(n, out_path);
    auto t0 = std::chrono::steady_clock::now();
    auto h = known_hash.empty() ? ContentHashOf(n, out_path) : Result<std::string>(known_hash);
    if (!h.ok()) {
      e["status"] = "failed";
      outcome.failure = "stage " + n.name + " finished but its output cannot be read back: " + h.status().message();
      return finish("failed", 1);
    }
    hash_of_[n.output] = *h;
    e["status"] = "done";
    e["finished"] = Now();
    e["output"] = {{"file", n.output},
                   {"path", out_path},
                   {"bytes", made.bytes},
                   {"content_hash", *h},
                   {"fingerprint", made.fingerprint},
                   {"hash_seconds", std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count()}};
    if (n.image && o_.say && !o_.quiet) {
      std::string line = "wrote " + out_path;
      const json& m = e.value("metrics", json::object());
      if (m.contains("error")) {
        char b[160];
        std::snprintf(b, sizeof b,
                      ": error against rows.ltm rel. L2 %.4g, PSNR %.1f dB (lighting alone %.4g, matrix alone %.4g)",
                      m["error"].value("rel_l2", 0.0), m["error"].value("psnr_db", 0.0),
                      m.value("error_lighting_only", json::object()).value("rel_l2", 0.0),
                      m.value("error_matrix_only", json::object()).value("rel_l2", 0.0));
        line += b;
      }
      o_.say(line);
    }
    DeleteUnneeded(i);
    if (sig != 0) {  // the stage finished just as the signal came: stop here
      outcome.failure = "interrupted after " + n.name + "; rerun `ltbake run " + r_.path + "` to go on";
      return finish("interrupted", sig == SIGTERM ? 143 : 130);
    }
    Status s = SaveReport();
    if (!s.ok()) return s.WithContext("writing the run report");
  }
  // Intermediates left over by an earlier run that stopped before removing them.
  DeleteUnneeded(g_.nodes.size());
  return finish("ok", 0);
}

}  // namespace

Result<BakeOutcome> RunBake(const BakeOptions& options) {
  LTB_ASSIGN_OR_RETURN(Recipe recipe, ParseRecipe(options.recipe));
  Bake bake(options, std::move(recipe));
  return bake.Run();
}

}  // namespace ltb::pipeline
