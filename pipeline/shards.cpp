#include "pipeline/shards.h"

#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <csignal>
#include <cstdlib>
#include <fstream>
#include <map>
#include <mutex>
#include <sstream>
#include <thread>

#include "format/io/container_reader.h"
#include "format/io/manifest.h"
#include "pipeline/process.h"

namespace ltb::pipeline {

namespace {

std::string ShardLog(const std::string& log_dir, const std::string& step, uint64_t i) {
  return log_dir + "/" + step + ".shard-" + std::to_string(i) + ".log";
}

bool IsInterruption(const ChildResult& c) {
  return c.exit_code == 130 || c.exit_code == 143 || c.term_signal == SIGINT || c.term_signal == SIGTERM;
}

// The "error" lines at the end of a shard's log (Slurm writes the log; we only read it).
std::vector<std::string> ErrorLines(const std::string& log) {
  std::ifstream in(log);
  std::vector<std::string> lines;
  std::string line;
  while (std::getline(in, line)) {
    if (line.find("error") != std::string::npos || line.find("CANCELLED") != std::string::npos ||
        line.find("Killed") != std::string::npos) {
      lines.push_back(line);
    }
  }
  if (lines.size() > 5) lines.erase(lines.begin(), lines.end() - 5);
  return lines;
}

// "0-3" or "1,4,7": the --array list of the shards in `todo` (ascending).
std::string ArrayList(const std::vector<uint64_t>& todo) {
  std::string out;
  for (size_t k = 0; k < todo.size();) {
    size_t j = k;
    while (j + 1 < todo.size() && todo[j + 1] == todo[j] + 1) ++j;
    if (!out.empty()) out += ",";
    out += std::to_string(todo[k]);
    if (j > k) {
      out += '-';
      out += std::to_string(todo[j]);
    }
    k = j + 1;
  }
  return out;
}

std::vector<std::string> ShardArgs(const std::vector<std::string>& stage, uint64_t index, uint64_t count, int jobs) {
  std::vector<std::string> argv = stage;
  argv.insert(argv.end(),
              {"--shard", std::to_string(index), "--nshards", std::to_string(count), "--jobs", std::to_string(jobs)});
  return argv;
}

Result<ShardedStep> RunLocal(const EngineOptions& o, const std::vector<std::string>& stage, const std::string& output,
                             const std::vector<uint64_t>& todo, const std::string& step, const std::string& log_dir) {
  ShardedStep result;
  result.shards.resize(todo.size());
  for (size_t k = 0; k < todo.size(); ++k) {
    result.shards[k].index = todo[k];
    result.shards[k].log = ShardLog(log_dir, step, todo[k]);
  }
  const size_t procs = std::min<size_t>(todo.size(), static_cast<size_t>(std::max(1, o.jobs)));
  const int per = std::max(1, o.jobs / static_cast<int>(std::max<size_t>(1, procs)));
  std::atomic<size_t> next{0};
  std::atomic<bool> stop{false};
  std::mutex mu;
  Status first_error;
  auto worker = [&] {
    for (;;) {
      size_t k = next.fetch_add(1);
      if (k >= todo.size() || stop) return;
      ShardRun& run = result.shards[k];
      if (o.pending_signal && o.pending_signal() != 0) {
        run.status = "interrupted";
        stop = true;
        return;
      }
      ChildIo io;
      io.log_path = run.log;
      io.pending_signal = o.pending_signal;
      run.attempts = 1;
      auto child = RunChild(ShardArgs(stage, run.index, o.shards, per), io);
      std::lock_guard<std::mutex> lock(mu);
      if (!child.ok()) {
        run.status = "failed";
        run.errors = {child.status().message()};
        if (first_error.ok()) first_error = child.status();
        stop = true;
        return;
      }
      run.exit_code = child->exit_code;
      run.wall_seconds = child->wall_seconds;
      run.peak_rss_bytes = child->peak_rss_bytes;
      run.errors = child->errors;
      if (IsInterruption(*child)) {
        // A shard that had just committed its last chunk when the signal came is done.
        run.status = ShardFileComplete(output, run.index, o.shards) ? "done" : "interrupted";
        stop = true;
      } else if (child->exit_code != 0) {
        run.status = "failed";
        if (child->term_signal) run.errors.push_back("killed by signal " + std::to_string(child->term_signal));
      } else {
        run.status = "done";
      }
      if (o.say) {
        char line[256];
        std::snprintf(line, sizeof line, "   shard %llu/%llu %s in %.2f s", static_cast<unsigned long long>(run.index),
                      static_cast<unsigned long long>(o.shards), run.status.c_str(), run.wall_seconds);
        o.say(line);
      }
    }
  };
  std::vector<std::thread> pool;
  for (size_t p = 1; p < procs; ++p) pool.emplace_back(worker);
  worker();
  for (auto& t : pool) t.join();
  if (!first_error.ok()) return first_error.WithContext("starting a shard of " + step);
  for (ShardRun& r : result.shards) {
    if (r.status.empty()) r.status = "interrupted";  // never started: the run stopped first
    if (r.status == "interrupted") result.interrupted = true;
  }
  if (result.interrupted && o.pending_signal) result.signal = o.pending_signal();
  return result;
}

// The program's path: as given when it has a '/', else the first match on $PATH.
Result<std::string> FindProgram(const std::string& name) {
  if (name.find('/') != std::string::npos) return name;
  const char* path = std::getenv("PATH");
  std::stringstream dirs(path != nullptr ? path : "/usr/bin:/bin");
  std::string dir;
  while (std::getline(dirs, dir, ':')) {
    std::string full = (dir.empty() ? "." : dir) + "/" + name;
    if (::access(full.c_str(), X_OK) == 0) return full;
  }
  return FailedPrecondition(name +
                            " is not on $PATH: install slurm-client (Debian) on the submitting machine, or run "
                            "with --engine local");
}

Status WriteScript(const std::string& path, const std::string& text) {
  std::ofstream out(path, std::ios::trunc);
  out << text;
  out.close();
  if (!out) return IoError(path + ": cannot write the job script", errno);
  return Status::Ok();
}

}  // namespace

SlurmSubmission PlanSlurm(const EngineOptions& o, const std::vector<std::string>& stage,
                          const std::vector<uint64_t>& todo, const std::string& step, const std::string& log_dir,
                          const std::string& sbatch, const std::string& job_name) {
  SlurmSubmission s;
  const int cpus = o.cpus_per_task > 0 ? o.cpus_per_task : std::max(1, o.jobs);
  // One script per step; the shard index comes from the array task, the count is explicit
  // (an array that reruns only some shards has another SLURM_ARRAY_TASK_COUNT).
  std::vector<std::string> argv = stage;
  argv.insert(argv.end(), {"--nshards", std::to_string(o.shards)});
  s.script_path = log_dir + "/" + step + ".sbatch";
  s.script = "#!/bin/bash\n# Written by `ltbake run`: one shard of step " + step + " per array task.\nexec " +
             ShellQuote(argv) + " --shard \"$SLURM_ARRAY_TASK_ID\" --jobs \"${SLURM_CPUS_PER_TASK:-" +
             std::to_string(cpus) + "}\"\n";
  s.command = {sbatch,
               "--wait",
               "--parsable",
               "--job-name=" + job_name,
               "--array=" + ArrayList(todo),
               "--output=" + log_dir + "/" + step + ".shard-%a.log",
               "--open-mode=append",
               "--cpus-per-task=" + std::to_string(cpus)};
  if (!o.partition.empty()) s.command.push_back("--partition=" + o.partition);
  if (!o.mem.empty()) s.command.push_back("--mem=" + o.mem);
  s.command.insert(s.command.end(), o.sbatch_args.begin(), o.sbatch_args.end());
  s.command.push_back(s.script_path);
  return s;
}

namespace {

Result<ShardedStep> RunSlurm(const EngineOptions& o, const std::vector<std::string>& stage, const std::string& output,
                             const std::vector<uint64_t>& todo, const std::string& step, const std::string& log_dir) {
  ShardedStep result;
  LTB_ASSIGN_OR_RETURN(const std::string sbatch, FindProgram(o.sbatch));
  LTB_ASSIGN_OR_RETURN(const std::string scancel, FindProgram(o.scancel));
  // Unique per submission, so a cancel reaches only this run's jobs.
  const std::string job_name = "ltbake-" + step + "-" + std::to_string(::getpid()) + "-" +
                               std::to_string(std::chrono::steady_clock::now().time_since_epoch().count() % 1000000);
  const SlurmSubmission first = PlanSlurm(o, stage, todo, step, log_dir, sbatch, job_name);
  LTB_RETURN_IF_ERROR(WriteScript(first.script_path, first.script));
  std::map<uint64_t, ShardRun> runs;
  for (uint64_t i : todo) runs[i] = ShardRun{.index = i, .status = "failed", .log = ShardLog(log_dir, step, i)};
  std::vector<uint64_t> left = todo;
  for (int round = 0; round <= o.retries && !left.empty(); ++round) {
    const std::vector<std::string> cmd = PlanSlurm(o, stage, left, step, log_dir, sbatch, job_name).command;
    result.submit_commands.push_back(ShellQuote(cmd));
    if (o.say) {
      o.say(std::string("   ") + (round == 0 ? "submitting" : "resubmitting") + " shards " + ArrayList(left) + " of " +
            std::to_string(o.shards) + ": " + ShellQuote(cmd));
    }
    std::string sbatch_err;
    ChildIo io;
    io.log_path = log_dir + "/" + step + ".log";
    io.on_stderr = [&](std::string_view t) { sbatch_err.append(t); };
    io.pending_signal = o.pending_signal;
    auto child = RunChild(cmd, io);
    if (!child.ok()) {
      return FailedPrecondition("cannot run " + o.sbatch + " (" + child.status().message() +
                                "): install slurm-client, or use --engine local");
    }
    for (uint64_t i : left) runs[i].attempts++;
    const int sig = o.pending_signal ? o.pending_signal() : 0;
    // Only a signal to this run, or to sbatch itself, interrupts: sbatch --wait exits with
    // the largest exit code of the tasks, 143 when a task was cancelled (scancel, time limit).
    if (sig != 0 || child->term_signal == SIGINT || child->term_signal == SIGTERM) {
      // sbatch --wait does not take its job with it: cancel what this run submitted.
      ChildIo quiet;
      quiet.log_path = io.log_path;
      quiet.deadline_seconds = 60;  // a controller that is gone must not keep the run from stopping
      (void)RunChild({scancel, "--name=" + job_name}, quiet);
      for (uint64_t i : left) runs[i].status = ShardFileComplete(output, i, o.shards) ? "done" : "interrupted";
      result.interrupted = true;
      result.signal = sig != 0 ? sig : SIGTERM;
      break;
    }
    std::vector<uint64_t> failed;
    for (uint64_t i : left) {
      if (ShardFileComplete(output, i, o.shards)) {
        runs[i].status = "done";
        runs[i].errors.clear();
      } else {
        runs[i].status = "failed";
        runs[i].errors = ErrorLines(runs[i].log);
        failed.push_back(i);
      }
    }
    const bool refused = sbatch_err.find("sbatch: error") != std::string::npos;
    if (failed.size() == left.size() && child->exit_code != 0 && refused) {
      // Nothing ran: the submission itself was refused (a bad partition, --mem, ...).
      for (uint64_t i : failed) runs[i].errors = {sbatch_err.substr(0, sbatch_err.find_last_not_of('\n') + 1)};
      break;
    }
    left = failed;
  }
  for (auto& [i, r] : runs) result.shards.push_back(r);
  return result;
}

}  // namespace

bool ShardFileComplete(const std::string& output, uint64_t index, uint64_t count, std::string* fingerprint) {
  auto r = io::ContainerReader::Open(io::ShardPath(output, index, count));
  if (!r.ok() || r->is_manifest()) return false;
  const auto& s = r->metadata().shard;
  if (!s || s->index != index || s->count != count) return false;
  if (!r->sealed() || !r->complete() || !r->problems().empty()) return false;
  if (fingerprint != nullptr) *fingerprint = io::IndexFingerprint(*r);
  return true;
}

Result<ShardedStep> RunShards(const EngineOptions& o, const std::vector<std::string>& stage, const std::string& output,
                              const std::vector<uint64_t>& todo, const std::string& step, const std::string& log_dir) {
  if (todo.empty()) return ShardedStep{};
  if (o.engine == "slurm") return RunSlurm(o, stage, output, todo, step, log_dir);
  if (o.engine == "local") return RunLocal(o, stage, output, todo, step, log_dir);
  return InvalidArgument("--engine " + o.engine + ": expected local or slurm");
}

}  // namespace ltb::pipeline
