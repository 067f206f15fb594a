// ltbake commit OUT --nshards N   and   ltbake merge MANIFEST -o OUT
#include <iostream>
#include <nlohmann/json.hpp>

#include "cli/commands.h"
#include "cli/common.h"
#include "format/io/manifest.h"
#include "format/json_text.h"

namespace ltb::cli {
namespace {

class CommitCommand : public Command {
 public:
  explicit CommitCommand(CLI::App* parent) {
    auto* app = parent->add_subcommand(
        "commit", "validate the shards of a stage's output and write its manifest (reads as one matrix everywhere)");
    app->add_option("OUT", output_, "the stage's -o output; its shards are OUT-stem.shards/IIIII-of-NNNNN.ltm")
        ->required();
    app->add_option("--nshards", nshards_, "number of shards the stage was split into")
        ->required()
        ->check(CLI::Range(uint64_t{1}, format::kMaxShards));
    app->add_flag("--overwrite", overwrite_, "replace an OUT that is a container, not a manifest");
    app->add_flag("--json", json_, "print the result as JSON");
    AddCommonFlags(app, &flags_);
  }

  int Run() override {
    io::CommitOptions options;
    options.overwrite = overwrite_;
    options.threads = flags_.jobs;
    ProgressBar bar(flags_, "commit");
    options.progress = bar.hook();
    auto r = io::CommitShards(output_, nshards_, options);
    bar.Done();
    if (!r.ok()) return ReportFailure(r.status());
    if (json_) {
      nlohmann::json shards = nlohmann::json::array();
      for (const auto& s : r->shards) {
        shards.push_back({{"index", s.index}, {"path", s.path}, {"bytes", s.bytes}, {"content_hash", s.content_hash}});
      }
      std::cout << JsonText(nlohmann::json{{"manifest", output_},
                                           {"nshards", nshards_},
                                           {"content_hash", r->content_hash},
                                           {"bytes", r->bytes},
                                           {"shards", shards}},
                            2)
                << "\n";
    } else if (!flags_.quiet) {
      std::cout << "committed " << output_ << ": " << nshards_ << " shards, " << r->bytes << " bytes, content_hash "
                << r->content_hash << "\n";
    }
    return kExitOk;
  }

 private:
  std::string output_;
  uint64_t nshards_ = 1;
  bool overwrite_ = false, json_ = false;
  CommonFlags flags_;
};

class MergeCommand : public Command {
 public:
  explicit MergeCommand(CLI::App* parent) {
    auto* app = parent->add_subcommand("merge", "concatenate a stage manifest's shards into one container");
    app->add_option("MANIFEST", input_, "a manifest written by `ltbake commit` (or `ltbake run --shards N`)")
        ->required()
        ->check(CLI::ExistingFile);
    app->add_option("-o,--output", output_, "the single container to write")->required();
    app->add_flag("--overwrite", overwrite_, "replace an output that holds another matrix");
    AddCommonFlags(app, &flags_);
  }

  int Run() override {
    ProgressBar bar(flags_, "merge");
    auto r = io::MergeManifest(input_, output_, overwrite_, bar.hook());
    bar.Done();
    if (!r.ok()) return ReportFailure(r.status());
    if (!flags_.quiet) {
      std::cout << "wrote " << output_ << ": " << r->chunks << " chunks copied (" << r->bytes
                << " payload bytes) from the shards of " << input_ << "\n";
    }
    return kExitOk;
  }

 private:
  std::string input_, output_;
  bool overwrite_ = false;
  CommonFlags flags_;
};

}  // namespace

std::unique_ptr<Command> RegisterCommit(CLI::App* parent) { return std::make_unique<CommitCommand>(parent); }
std::unique_ptr<Command> RegisterMerge(CLI::App* parent) { return std::make_unique<MergeCommand>(parent); }

}  // namespace ltb::cli
