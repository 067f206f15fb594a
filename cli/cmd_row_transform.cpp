// ltbake row-transform IN -o OUT [--filter haar|db2|db3|db4]
#include <iostream>

#include "cli/commands.h"
#include "cli/common.h"
#include "stages/row_transform/row_transform.h"

namespace ltb::cli {
namespace {

class RowTransformCommand : public Command {
 public:
  explicit RowTransformCommand(CLI::App* parent) {
    auto* app = parent->add_subcommand(
        "row-transform", "2D wavelet transform of every row's six cube faces (input: pixel-basis row blocks)");
    app->add_option("IN", options_.input, "input container (row blocks, pixel-basis cubemap columns)")->required();
    app->add_option("-o,--output", options_.output, "output container")->required();
    app->add_option("--filter", filter_, "orthonormal row filter")
        ->default_val("haar")
        ->check(CLI::IsMember({"haar", "db1", "db2", "db3", "db4"}));
    app->add_flag("--zstd", options_.zstd, "zstd-compress chunks where it saves at least 10%");
    app->add_flag("--overwrite", options_.overwrite, "replace an output that was made with other parameters");
    app->add_flag("!--no-direct-io", options_.direct_io,
                  "write the output through the page cache instead of with O_DIRECT");
    AddCommonFlags(app, &flags_);
    AddShardFlags(app, &shard_flags_);
  }

  std::vector<std::string*> ChannelSetPaths() override { return {&options_.input, &options_.output}; }

  int Run() override {
    StageFlags sf;
    if (int code = ResolveStageFlags(flags_, &shard_flags_, &sf); code != kExitOk) return code;
    options_.shard = sf.shard;
    options_.filter = *wavelet::ParseFilter(filter_);  // checked by IsMember
    options_.jobs = sf.jobs;
    ProgressBar bar(flags_, "row-transform");
    auto r = stages::RunRowTransform(options_, bar.hook());
    bar.Done();
    if (!r.ok()) return ReportFailure(r.status());
    if (!r->direct_fallback.empty() && !flags_.quiet) {
      std::cerr << "ltbake: note: " << r->direct_fallback << "; the output was written through the page cache\n";
    }
    if (!flags_.quiet) {
      std::cout << "wrote " << OutputName(options_.output, options_.shard) << ": " << r->rows
                << " rows, R = " << r->cube_res << ", filter " << filter_ << ", " << r->chunks_total << " chunks";
      if (r->chunks_already_committed)
        std::cout << " (resumed: " << r->chunks_already_committed << " already committed)";
      std::cout << "; skipped " << r->zero_chunks << " all-zero chunks and " << r->zero_rows << " all-zero rows";
      if (r->bytes_direct > 0) std::cout << "; wrote " << r->bytes_direct << " bytes with O_DIRECT";
      std::cout << "\n";
    }
    return kExitOk;
  }

 private:
  stages::RowTransformOptions options_;
  std::string filter_ = "haar";
  CommonFlags flags_;
  ShardFlags shard_flags_;
};

}  // namespace

std::unique_ptr<Command> RegisterRowTransform(CLI::App* parent) {
  return std::make_unique<RowTransformCommand>(parent);
}

}  // namespace ltb::cli
