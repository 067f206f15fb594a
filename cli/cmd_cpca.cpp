// ltbake cpca IN -o OUT --clusters K --basis S
#include <iomanip>
#include <iostream>
#include <nlohmann/json.hpp>

#include "cli/commands.h"
#include "cli/common.h"
#include "format/json_text.h"
#include "stages/cpca/cpca.h"

namespace ltb::cli {
namespace {

class CpcaCommand : public Command {
 public:
  explicit CpcaCommand(CLI::App* parent) {
    auto* app = parent->add_subcommand(
        "cpca", "clustered PCA (Sloan et al. 2003) of a row-block matrix: K clusters, each a mean + S directions");
    app->add_option("IN", options_.input, "row-block matrix (rows.ltm from row-transform, or raw.ltm)")->required();
    app->add_option("-o,--output", options_.output, "output container (cpca.ltm)")->required();
    app->add_option("--clusters,-k", options_.clusters, "number of clusters K")
        ->default_val(16)
        ->check(CLI::Range(1, 1 << 20));
    app->add_option("--basis,-s", options_.basis, "principal directions per cluster S")
        ->default_val(8)
        ->check(CLI::Range(0, 1 << 16));
    app->add_option("--growth-step", options_.growth_step,
                    "basis vectors added per growth level (0, step, 2·step, …, S)")
        ->default_val(1)
        ->check(CLI::Range(1, 1 << 16));
    app->add_option("--level-iterations", options_.level_iterations, "passes per intermediate growth level")
        ->default_val(2)
        ->check(CLI::Range(1, 1000));
    app->add_option("--max-iterations", options_.max_iterations, "cap on assignment/refit passes over the data")
        ->default_val(30)
        ->check(CLI::Range(1, 100000));
    app->add_option("--tolerance", options_.tolerance,
                    "a level ends when a pass improves the error by less than this fraction")
        ->default_val(1e-3);
    app->add_option("--oversample", options_.oversample, "extra directions tracked per cluster (subspace iteration)")
        ->default_val(8)
        ->check(CLI::Range(0, 1024));
    app->add_option("--sample-rows", options_.sample_rows, "rows held in memory for the seeded k-means++ start")
        ->default_val(32768)
        ->check(CLI::Range(1, 1 << 30));
    app->add_option("--seed", options_.seed, "seed of the initialisation")->default_val(1);
    auto* dense = app->add_flag("--dense-first", dense_first_,
                                "run the seeded start and the growth levels on the dense rows of a sparse bake "
                                "only (its \"sparse_kind\" array), then --final-iterations passes on all rows "
                                "(default: on when the input marks dense rows)");
    auto* no_dense =
        app->add_flag("--no-dense-first", no_dense_first_, "every pass on all rows, even on a sparse bake");
    dense->excludes(no_dense);
    app->add_option("--final-iterations", options_.final_iterations,
                    "dense-first: passes on all rows at the full basis after the dense growth levels (fewer when "
                    "a pass improves the error by less than --tolerance)")
        ->default_val(2)
        ->check(CLI::Range(0, 100000));
    app->add_flag("--overwrite", options_.overwrite, "replace an output that was made with other parameters");
    app->add_flag("--json", json_, "print the summary as JSON");
    AddCommonFlags(app, &flags_);
    AddShardFlags(app, &shard_flags_);
  }

  std::vector<std::string*> ChannelSetPaths() override { return {&options_.input, &options_.output}; }

  int Run() override {
    auto shard = ResolveShard(shard_flags_);
    if (!shard.ok() || shard->sharded()) {
      std::cerr << "ltbake: cpca: "
                << (shard.ok() ? "does not split into shards yet: its clustering passes are global (every pass "
                                 "reassigns every row); run it once, with --nshards 1 (it reads a sharded input's "
                                 "manifest like any container)"
                               : shard.status().message())
                << "\n";
      return kExitUsage;
    }
    StageFlags sf;
    if (int code = ResolveStageFlags(flags_, nullptr, &sf); code != kExitOk) return code;
    options_.dense_first = dense_first_      ? stages::DenseFirst::kOn
                           : no_dense_first_ ? stages::DenseFirst::kOff
                                             : stages::DenseFirst::kAuto;
    options_.mem_limit = sf.mem_limit;
    options_.jobs = sf.jobs;
    ProgressBar bar(flags_, "cpca");
    auto r = stages::RunCpca(options_, bar.hook());
    bar.Done();
    if (!r.ok()) return ReportFailure(r.status());
    if (json_) {
      nlohmann::json j = {{"output", options_.output},
                          {"rows", r->rows},
                          {"dims", r->dims},
                          {"clusters", r->clusters},
                          {"basis", r->basis},
                          {"iterations", r->iterations},
                          {"relative_rms_error", r->relative_rms_error},
                          {"squared_error", r->squared_error},
                          {"squared_norm", r->squared_norm},
                          {"empty_clusters", r->empty_clusters},
                          {"model_bytes", r->model_bytes},
                          {"row_bytes", r->row_bytes},
                          {"memory_bytes_estimate", r->memory_bytes},
                          {"resumed", r->resumed},
                          {"already_complete", r->already_complete},
                          {"dense_first", r->dense_first},
                          {"dense_rows", r->dense_rows},
                          {"rows_streamed", r->rows_streamed},
                          {"seconds_dense", r->seconds_dense},
                          {"seconds_final", r->seconds_final}};
      std::cout << JsonText(j, 2) << "\n";
    } else if (!flags_.quiet) {
      std::cout << "wrote " << options_.output << ": " << r->rows << " rows of " << r->dims << " in " << r->clusters
                << " clusters x " << r->basis << " directions, " << r->iterations << " passes, relative RMS error "
                << std::setprecision(4) << r->relative_rms_error << ", " << r->model_bytes + r->row_bytes
                << " bytes stored";
      if (r->empty_clusters) std::cout << " (" << r->empty_clusters << " clusters empty)";
      if (r->dense_first) {
        std::cout << "; dense-first: growth levels on " << r->dense_rows << " dense rows of " << r->rows << ", "
                  << r->rows_streamed << " rows streamed";
      } else {
        std::cout << "; " << r->rows_streamed << " rows streamed";
      }
      if (!r->already_complete) {
        std::cout << std::setprecision(3) << " (" << r->seconds_dense << " s start and growth, " << r->seconds_final
                  << " s final passes and output)";
      }
      if (r->already_complete)
        std::cout << " (already complete)";
      else if (r->resumed)
        std::cout << " (resumed)";
      std::cout << "\n";
    }
    return kExitOk;
  }

 private:
  stages::CpcaOptions options_;
  bool json_ = false;
  bool dense_first_ = false, no_dense_first_ = false;
  CommonFlags flags_;
  ShardFlags shard_flags_;
};

}  // namespace

std::unique_ptr<Command> RegisterCpca(CLI::App* parent) { return std::make_unique<CpcaCommand>(parent); }

}  // namespace ltb::cli
