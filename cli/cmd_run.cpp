// ltbake run RECIPE.toml [--workdir DIR] [--from STAGE] [--until STAGE] [--force [STAGE]] [--dry-run]
#include <unistd.h>

#include <algorithm>
#include <climits>
#include <cstdio>
#include <fstream>
#include <iostream>
#include <sstream>

#include "cli/commands.h"
#include "cli/common.h"
#include "format/array_spec.h"
#include "format/json_text.h"
#include "pipeline/bake.h"
#include "pipeline/eta.h"

namespace ltb::cli {
namespace {

// The running executable, so stages run with the same build as the run itself.
std::string SelfExe() {
  char buf[PATH_MAX];
  ssize_t n = ::readlink("/proc/self/exe", buf, sizeof buf - 1);
  if (n <= 0) return "ltbake";
  return std::string(buf, static_cast<size_t>(n));
}

using nlohmann::json;

std::string Pad(std::string s, size_t w) {
  s.resize(std::max(w, s.size() + 1), ' ');  // a column wider than its field still ends in a space
  return s;
}

// The table printed after a run: one line per step, from its run.json record.
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

// --dry-run: every step, what it would do and why, and the command of those that run.
std::string PlanText(const pipeline::BakeOutcome& o) {
  std::ostringstream t;
  t << "plan for " << o.recipe_path << " in " << o.workdir << ":\n";
  for (const auto& s : o.plan) {
    t << "  " << Pad(s.node, 22) << Pad(s.action, 8) << s.reason << "\n";
    if (!s.command.empty() && s.submit.empty()) t << "      " << s.command << "\n";
    if (!s.submit.empty()) {  // the Slurm engine: a job array and its script
      t << "      submits: " << s.submit << "\n      job script " << s.script_path << ":\n";
      std::istringstream lines(s.script);
      for (std::string line; std::getline(lines, line);) t << "        " << line << "\n";
    }
  }
  return t.str();
}

// " [3/6]": where the step is in the bake.
std::string StepOf(const pipeline::StepEvent& e) {
  return e.steps ? " [" + std::to_string(e.step) + "/" + std::to_string(e.steps) + "]" : "";
}

// --dry-run --json: the plan as one JSON object.
std::string PlanJson(const pipeline::BakeOutcome& o) {
  json steps = json::array();
  for (const auto& s : o.plan) {
    json j = {{"node", s.node}, {"action", s.action}, {"reason", s.reason}};
    if (!s.command.empty()) j["command"] = s.command;
    if (!s.submit.empty()) j["slurm"] = {{"submit", s.submit}, {"script_path", s.script_path}, {"script", s.script}};
    steps.push_back(j);
  }
  return JsonText(json{{"recipe", o.recipe_path}, {"workdir", o.workdir}, {"plan", steps}}, 2) + "\n";
}

// The line a step event prints (stdout), or "" for none.
std::string StepLine(const pipeline::StepEvent& e) {
  using Kind = pipeline::StepEvent::Kind;
  switch (e.kind) {
    case Kind::kSkipped:
      return "== " + e.node + ": skipped, " + e.reason + StepOf(e);
    case Kind::kStarting: {
      std::string line = "== " + e.node + ": " + e.action + " (" + e.reason + ")" + StepOf(e);
      // The rest of the bake, this step included (a model: pipeline/eta.h), once the matrix exists.
      if (e.eta_seconds) line += "; " + pipeline::ApproxDuration(*e.eta_seconds) + " left in the bake";
      return line;
    }
    case Kind::kImageWritten: {
      std::string line = "wrote " + e.path;
      const json& m = e.metrics;
      if (m.is_object() && m.contains("error")) {
        char b[160];
        std::snprintf(b, sizeof b,
                      ": error against rows.ltm rel. L2 %.4g, PSNR %.1f dB (lighting alone %.4g, matrix alone %.4g)",
                      m["error"].value("rel_l2", 0.0), m["error"].value("psnr_db", 0.0),
                      m.value("error_lighting_only", json::object()).value("rel_l2", 0.0),
                      m.value("error_matrix_only", json::object()).value("rel_l2", 0.0));
        line += b;
      }
      return line;
    }
  }
  return std::string();
}

Ending EndingOf(pipeline::BakeEnd end) {
  switch (end) {
    case pipeline::BakeEnd::kOk:
      return Ending::kOk;
    case pipeline::BakeEnd::kFailed:
      return Ending::kFailed;
    case pipeline::BakeEnd::kInterrupted:
      return Ending::kInterrupted;
  }
  return Ending::kFailed;
}

class RunCommand : public Command {
 public:
  explicit RunCommand(CLI::App* parent) {
    auto* app = parent->add_subcommand(
        "run",
        "run a bake recipe: every stage its targets need, skipping what is up to date (content and "
        "parameters), resuming what was interrupted (docs/RECIPE.md)");
    app->add_option("RECIPE", options_.recipe, "recipe file (TOML, see samples/tiny-bake.toml)")->required();
    app->add_option("--workdir", options_.workdir, "work directory (overrides the recipe's workdir)");
    app->add_option("--from", options_.from, "start at this stage: earlier stages are not run, their outputs are used");
    app->add_option("--until", options_.until, "stop after this stage (and what it needs)");
    app->add_option("--force", options_.force,
                    "redo this stage even if it is up to date (repeatable); without a stage: redo every stage "
                    "(give it after RECIPE)")
        ->expected(0, 1)
        ->multi_option_policy(CLI::MultiOptionPolicy::TakeAll)
        ->default_str("all");
    app->add_flag("--dry-run", options_.dry_run, "print the plan (what runs and why) and change nothing");
    app->add_option("--engine", options_.cluster.engine,
                    "where shards run: local (a process pool) or slurm (one job array per stage, sbatch --wait)")
        ->default_val("local")
        ->check(CLI::IsMember({"local", "slurm"}));
    app->add_option("--shards", options_.cluster.shards,
                    "split every matrix stage (not cpca, relight) into N shards, committed as a manifest "
                    "(docs/cluster.md)")
        ->default_val(1)
        ->check(CLI::Range(uint64_t{1}, format::kMaxShards));
    app->add_option("--partition", options_.cluster.partition, "slurm: partition to submit to");
    app->add_option("--cpus-per-task", options_.cluster.cpus_per_task, "slurm: CPUs per shard (default: --jobs)")
        ->check(CLI::Range(1, 4096));
    app->add_option("--mem", options_.cluster.mem, "slurm: memory per shard, as sbatch --mem takes it (e.g. 4G)");
    app->add_option("--sbatch-arg", options_.cluster.sbatch_args,
                    "slurm: one more sbatch argument, e.g. --sbatch-arg=--time=2:00:00 (repeatable)")
        ->allow_extra_args(false);
    app->add_option("--retries", options_.cluster.retries, "slurm: resubmit failed shards up to this many times")
        ->default_val(2)
        ->check(CLI::Range(0, 100));
    app->add_flag("--json", json_,
                  "print the run report (what run.json holds; with --dry-run, the plan) as JSON on stdout; the "
                  "step lines and the stages' output go to stderr");
    AddCommonFlags(app, &flags_);
    app_ = app;
  }

  int Run() override {
    // The stages it starts inherit this: an interrupted stage leaves the message (with the
    // command that resumes the whole bake) to this process (ReportFailure).
    ::setenv(kRunPidVariable, std::to_string(::getpid()).c_str(), 1);
    if (app_->count("--force") > 0 && options_.force.empty()) options_.force = {"all"};
    for (auto& f : options_.force) {
      if (f.empty()) f = "all";
    }
    options_.jobs = flags_.jobs;
    options_.mem_limit = flags_.mem_limit;
    auto mem = stages::ParseByteSize(flags_.mem_limit);
    if (!mem.ok()) return ReportUsage(mem.status().WithContext("--mem-limit"));
    options_.quiet = flags_.quiet;
    options_.progress = !flags_.quiet && (flags_.progress == "always" || (flags_.progress == "auto" && ::isatty(2)));
    options_.ltbake = SelfExe();
    // With --json, stdout holds the JSON alone: what the bake says goes to stderr.
    std::ostream& say = json_ ? std::cerr : std::cout;
    options_.say = [&say](const std::string& line) { say << line << std::endl; };
    if (!flags_.quiet) {
      options_.on_step = [&say](const pipeline::StepEvent& e) {
        std::string line = StepLine(e);
        if (!line.empty()) say << line << std::endl;
      };
    }
    options_.exit_code_for = [](pipeline::BakeEnd end, int signal) { return ExitCodeFor(EndingOf(end), signal); };
    options_.stage_stdout = [&say](std::string_view text) {
      say << text;
      say.flush();
    };
    options_.stage_stderr = [](std::string_view text) {
      std::cerr << text;
      std::cerr.flush();
    };
    options_.pending_signal = [] { return ReceivedSignal(); };
    auto outcome = pipeline::RunBake(options_);
    if (!outcome.ok()) {
      Status s = outcome.status();
      std::cerr << "ltbake: error: " << s.message() << "\n";
      if (ReceivedSignal() != 0) return ExitCodeFor(Ending::kInterrupted, ReceivedSignal());
      // A recipe that cannot be used as it is (a bad key or value, a scene that does not
      // fit its targets) is a usage error, as a bad flag is.
      return ExitCodeFor(s.code() == StatusCode::kInvalidArgument ? Ending::kUsage : Ending::kFailed);
    }
    if (options_.dry_run) {
      std::cout << (json_ ? PlanJson(*outcome) : PlanText(*outcome));
      return kExitOk;
    }
    const int code = ExitCodeFor(EndingOf(outcome->end), outcome->signal);
    if (json_) {
      std::ifstream report(outcome->report_path);
      std::cout << report.rdbuf();
    } else if (!flags_.quiet || code != kExitOk) {
      std::cout << "\n" << SummaryTable(outcome->stages);
      std::cout << "run report: " << outcome->report_path << "\n";
    }
    if (!outcome->failure.empty()) std::cerr << "ltbake: error: " << outcome->failure << "\n";
    return code;
  }

 private:
  pipeline::BakeOptions options_;
  bool json_ = false;
  CommonFlags flags_;
  CLI::App* app_ = nullptr;
};

}  // namespace

std::unique_ptr<Command> RegisterRun(CLI::App* parent) { return std::make_unique<RunCommand>(parent); }

}  // namespace ltb::cli
