#include "pipeline/sharded_step.h"

#include <algorithm>
#include <chrono>
#include <csignal>
#include <filesystem>
#include <map>
#include <vector>

#include "format/io/manifest.h"
#include "pipeline/process.h"
#include "pipeline/shards.h"
#include "pipeline/stage_table.h"

namespace ltb::pipeline {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

double SecondsSince(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

// Shards this run need not run: done in the recorded attempt (same parameters, inputs and
// shard count), their file still complete with the fingerprint recorded then.
std::map<uint64_t, json> ShardsDoneBefore(const ShardedStepInput& in, uint64_t count) {
  std::map<uint64_t, json> done;
  if (!in.trust_record || !in.record->contains("shards") || !(*in.record)["shards"].is_array()) return done;
  for (const json& s : (*in.record)["shards"]) {
    const std::string st = s.value("status", "");
    if (st != "done" && st != "skipped") continue;
    std::string fp;
    const uint64_t i = s.value("index", count);
    if (i < count && ShardFileComplete(in.output, i, count, &fp) && fp == s.value("fingerprint", "")) done[i] = s;
  }
  return done;
}

// The shard records for run.json: those done before, then this run's, by index.
json ShardRecords(const BakeOptions& o, const std::string& output, uint64_t count,
                  const std::map<uint64_t, json>& done_before, const ShardedStep& ran) {
  std::map<uint64_t, json> by_index;
  for (auto& [i, s] : done_before) {
    json r = s;
    r["status"] = "skipped";
    r["attempts"] = 0;
    by_index[i] = r;
  }
  for (const ShardRun& r : ran.shards) {
    json j = {
        {"index", r.index}, {"status", r.status}, {"attempts", r.attempts}, {"log", r.log}, {"exit_code", r.exit_code}};
    if (o.cluster.engine == "local") {
      j["wall_seconds"] = r.wall_seconds;
      j["peak_rss_bytes"] = r.peak_rss_bytes;
    }
    if (!r.errors.empty()) j["errors"] = r.errors;
    std::string fp;
    if (r.status == "done" && ShardFileComplete(output, r.index, count, &fp)) j["fingerprint"] = fp;
    by_index[r.index] = j;
  }
  json shards = json::array();
  for (auto& [i, j] : by_index) shards.push_back(j);
  return shards;
}

// The failure of some shards: which, their logs and errors, and the commands that re-run them.
std::string ShardFailure(const Node& n, const std::vector<std::string>& stage, uint64_t count,
                         const std::vector<const ShardRun*>& failed, const std::string& resume_command) {
  std::string why;
  for (const ShardRun* r : failed) {
    why += "\n  shard " + std::to_string(r->index) + " (" + std::to_string(r->attempts) + " attempt" +
           (r->attempts == 1 ? "" : "s") + ", log " + r->log + ")";
    for (const auto& line : r->errors) why += "\n    " + line;
  }
  std::vector<std::string> one = stage;
  one.insert(one.end(), {"--shard", std::to_string(failed.front()->index), "--nshards", std::to_string(count)});
  return "stage " + n.name + ": " + std::to_string(failed.size()) + " of " + std::to_string(count) +
         " shards failed:" + why + "\n  re-run one shard: " + ShellQuote(one) +
         "\n  or resume the whole bake (runs only the shards not done): " + resume_command;
}

StepEnd Failed(json& e, std::string failure) {
  e["status"] = "failed";
  return {BakeEnd::kFailed, 0, std::move(failure), {}};
}

}  // namespace

StepEnd RunShardedStep(const BakeOptions& o, const ShardedStepInput& in, json& e) {
  const Node& n = *in.node;
  const uint64_t count = o.cluster.shards;
  // The stage command of every shard: the step's command without --jobs (each engine sets it).
  std::vector<std::string> stage = {o.ltbake};
  for (std::string& a : StepArgs(n, in.output, o, in.overwrite, /*shard=*/true)) stage.push_back(std::move(a));
  e["engine"] = o.cluster.engine;
  e["nshards"] = count;
  e["command"] = ShellQuote(stage) + " --shard I --nshards " + std::to_string(count) + " --jobs J";

  const std::map<uint64_t, json> done_before = ShardsDoneBefore(in, count);
  std::vector<uint64_t> todo;
  for (uint64_t i = 0; i < count; ++i)
    if (!done_before.count(i)) todo.push_back(i);
  if (o.say && !o.quiet) {
    o.say("   " + std::to_string(todo.size()) + " of " + std::to_string(count) + " shards to run (" + o.cluster.engine +
          " engine)" + (done_before.empty() ? "" : ", " + std::to_string(done_before.size()) + " done before"));
  }
  EngineOptions eo = o.cluster;
  eo.jobs = o.jobs;
  eo.say = o.quiet ? nullptr : o.say;
  eo.pending_signal = o.pending_signal;
  std::error_code ec;
  fs::create_directories(in.logs, ec);
  std::string step = n.name;
  std::replace(step.begin(), step.end(), ':', '-');
  auto t0 = std::chrono::steady_clock::now();
  auto ran = RunShards(eo, stage, in.output, todo, step, in.logs);
  e["wall_seconds"] = SecondsSince(t0);
  if (!ran.ok()) return Failed(e, "stage " + n.name + ": " + ran.status().message());
  e["shards"] = ShardRecords(o, in.output, count, done_before, *ran);
  uint64_t peak = 0;
  std::vector<const ShardRun*> failed;
  for (const ShardRun& r : ran->shards) {
    if (r.status == "failed") failed.push_back(&r);
    peak = std::max(peak, r.peak_rss_bytes);
  }
  if (o.cluster.engine == "local") e["peak_rss_bytes"] = peak;
  if (!ran->submit_commands.empty()) e["submissions"] = ran->submit_commands;
  if (ran->interrupted) {
    e["status"] = "interrupted";
    return {BakeEnd::kInterrupted,
            ran->signal == SIGINT ? SIGINT : SIGTERM,
            "interrupted during " + n.name + "; the shards it finished are kept: rerun `" + in.resume_command +
                "` to run only the others",
            {}};
  }
  if (!failed.empty()) return Failed(e, ShardFailure(n, stage, count, failed, in.resume_command));
  // Every shard is done: validate them and write the manifest.
  io::CommitOptions co;
  co.overwrite = in.overwrite;
  co.threads = o.jobs;
  auto t1 = std::chrono::steady_clock::now();
  auto committed = io::CommitShards(in.output, count, co);
  e["commit_seconds"] = SecondsSince(t1);
  if (!committed.ok()) {
    return Failed(e, "stage " + n.name + ": its shards ran but cannot be committed: " + committed.status().message());
  }
  if (o.say && !o.quiet) {
    o.say("   committed " + in.output + ": " + std::to_string(count) + " shards, content_hash " +
          committed->content_hash);
  }
  return {BakeEnd::kOk, 0, {}, committed->content_hash};
}

}  // namespace ltb::pipeline
