// ltbake column-transform IN -o OUT [--filter F] [--depth adaptive|none|full|K]
//                                   [--terms N | --keep F | --budget B]
#include <cmath>
#include <iomanip>
#include <iostream>
#include <nlohmann/json.hpp>

#include "cli/commands.h"
#include "cli/common.h"
#include "format/json_text.h"
#include "stages/column_transform/column_transform.h"

namespace ltb::cli {
namespace {

class ColumnTransformCommand : public Command {
 public:
  explicit ColumnTransformCommand(CLI::App* parent) {
    auto* app = parent->add_subcommand(
        "column-transform",
        "adaptive 4D: transform each column image to its optimal depth and keep its N largest terms "
        "(input: column blocks from transpose)");
    app->add_option("IN", options_.input, "input container (column blocks, from `ltbake transpose`)")->required();
    app->add_option("-o,--output", options_.output, "output container (sparse columns + depth table)")->required();
    app->add_option("--filter", filter_, "column filter")
        ->default_val("legall53")
        ->check(CLI::IsMember({"legall53", "cdf97", "haar", "db1", "db2", "db3", "db4"}));
    app->add_option("--depth", depth_, "adaptive (optimal depth per column), none (2D), full (naive 4D) or a depth K")
        ->default_val("adaptive");
    auto* terms = app->add_option("--terms", terms_, "keep the N largest terms of each column")
                      ->check(CLI::Range(uint64_t{1}, uint64_t{1} << 62));
    auto* keep = app->add_option("--keep", keep_, "keep this fraction of each column's terms: 0.05 or 5%")
                     ->check(FractionCheck());
    auto* budget =
        app->add_option("--budget", budget_,
                        "one budget of nonzeros for the whole matrix, allocated by rate-distortion "
                        "optimisation: a fraction (0.02 or 2%), a count, or a size (64MiB at 8 bytes/nonzero); "
                        "the default is 5%")
            ->check(BudgetCheck());
    auto* target = app->add_option("--target-error", target_,
                                   "instead of a count: the fewest nonzeros (one rate-distortion threshold, as "
                                   "--budget) whose relative RMS error is at most this, e.g. 0.02 or 2%")
                       ->check(FractionCheck());
    terms->excludes(keep)->excludes(budget)->excludes(target);
    keep->excludes(budget)->excludes(target);
    budget->excludes(target);
    app->add_option("--block-cols", options_.block_cols,
                    "columns per output chunk (default: as many as fill 32 MiB dense, so the file carries few "
                    "frames; 1 = one chunk per column)")
        ->check(CLI::Range(uint64_t{1}, uint64_t{1} << 40));
    app->add_flag("!--no-zstd", options_.zstd, "do not zstd-compress the sparse chunks");
    app->add_flag("--overwrite", options_.overwrite, "replace an output that was made with other parameters");
    app->add_flag("--json", json_, "print the summary as JSON");
    AddCommonFlags(app, &flags_);
    AddShardFlags(app, &shard_flags_);
  }

  std::vector<std::string*> ChannelSetPaths() override { return {&options_.input, &options_.output}; }

  int Run() override {
    StageFlags sf;
    if (int code = ResolveStageFlags(flags_, &shard_flags_, &sf); code != kExitOk) return code;
    options_.shard = sf.shard;
    options_.filter = *wavelet::ParseFilter(filter_);
    auto depth = stages::ParseDepthMode(depth_);
    if (!depth.ok()) return ReportUsage(depth.status());
    options_.depth = *depth;
    if (!target_.empty()) {
      options_.terms.kind = stages::TermsMode::Kind::kTargetError;
      options_.terms.target_error = *stages::ParseFraction(target_);  // checked by FractionCheck
    } else if (!budget_.empty()) {
      options_.terms.kind = stages::TermsMode::Kind::kBudget;
      options_.terms.budget = budget_;
    } else if (terms_ > 0) {
      options_.terms.kind = stages::TermsMode::Kind::kTerms;
      options_.terms.terms = terms_;
    } else if (!keep_.empty()) {
      options_.terms.kind = stages::TermsMode::Kind::kKeep;
      options_.terms.keep = *stages::ParseFraction(keep_);  // checked by FractionCheck
    }                                                       // else the default: --budget 5%
    options_.mem_limit = sf.mem_limit;
    options_.jobs = sf.jobs;
    ProgressBar bar(flags_, "column-transform");
    auto r = stages::RunColumnTransform(options_, bar.hook());
    bar.Done();
    if (!r.ok()) return ReportFailure(r.status());
    double rel = r->energy > 0 ? std::sqrt(r->error / r->energy) : 0.0;
    double fraction = static_cast<double>(r->nonzeros) / (static_cast<double>(r->rows) * static_cast<double>(r->cols));
    if (json_) {
      nlohmann::json j = {
          {"output", options_.output},
          {"file", options_.shard.sharded() ? io::ShardPath(options_.output, options_.shard.index, options_.shard.count)
                                            : options_.output},
          {"rows", r->rows},
          {"cols", r->cols},
          {"image", {{"width", r->width}, {"height", r->height}}},
          {"depths", {r->min_depth, r->max_depth}},
          {"depth_histogram", r->depth_histogram},
          {"empty_columns", r->empty_columns},
          {"nonzeros", r->nonzeros},
          {"nonzero_fraction", fraction},
          {"energy", r->energy},
          {"error", r->error},
          {"relative_rms_error", rel},
          {"chunks_written", r->chunks_written},
          {"chunks_already_committed", r->chunks_already_committed},
          {"jobs", r->jobs_used}};
      if (options_.terms.kind == stages::TermsMode::Kind::kTargetError) {
        j["target_error"] = options_.terms.target_error;
        j["estimated_error"] = r->estimated_error;
      }
      if (options_.terms.kind == stages::TermsMode::Kind::kBudget ||
          options_.terms.kind == stages::TermsMode::Kind::kTargetError) {
        j["budget"] = r->budget;
        j["lambda"] = r->lambda;
        j["histogram_bytes"] = r->histogram_bytes;
      }
      std::cout << JsonText(j, 2) << "\n";
    } else if (!flags_.quiet) {
      std::cout << "wrote " << OutputName(options_.output, options_.shard) << ": " << r->cols << " columns of "
                << r->width << "x" << r->height << ", depths " << r->min_depth << ".." << r->max_depth;
      if (r->chunks_already_committed)
        std::cout << " (resumed: " << r->chunks_already_committed << " already committed)";
      std::cout << "\n  kept " << r->nonzeros << " nonzeros (" << std::setprecision(4) << 100 * fraction
                << "% of the matrix), relative RMS error " << rel << "; " << r->empty_columns << " empty columns\n";
      std::cout << "  columns per depth:";
      for (size_t d = 0; d < r->depth_histogram.size(); ++d) std::cout << " " << d << ":" << r->depth_histogram[d];
      std::cout << "\n";
      if (options_.terms.kind == stages::TermsMode::Kind::kBudget) {
        std::cout << "  budget " << r->budget << " nonzeros, lambda " << r->lambda << "\n";
      } else if (options_.terms.kind == stages::TermsMode::Kind::kTargetError) {
        std::cout << "  target error " << options_.terms.target_error << ": " << r->budget
                  << " nonzeros (estimated error " << r->estimated_error << "), lambda " << r->lambda << "\n";
      }
    }
    return kExitOk;
  }

 private:
  stages::ColumnTransformOptions options_;
  std::string filter_ = "legall53", depth_ = "adaptive", budget_;
  uint64_t terms_ = 0;
  std::string keep_, target_;
  bool json_ = false;
  CommonFlags flags_;
  ShardFlags shard_flags_;
};

}  // namespace

std::unique_ptr<Command> RegisterColumnTransform(CLI::App* parent) {
  return std::make_unique<ColumnTransformCommand>(parent);
}

}  // namespace ltb::cli
