// ltbake transpose IN -o OUT [--mem-limit 1GiB]
#include <iostream>

#include "cli/commands.h"
#include "cli/common.h"
#include "stages/transpose/transpose.h"

namespace ltb::cli {
namespace {

class TransposeCommand : public Command {
 public:
  explicit TransposeCommand(CLI::App* parent) {
    auto* app = parent->add_subcommand(
        "transpose", "row blocks -> column blocks (each column a W×H image), out of core within --mem-limit");
    app->add_option("IN", options_.input, "input container (row blocks)")->required();
    app->add_option("-o,--output", options_.output, "output container (column blocks)")->required();
    app->add_flag("--zstd", options_.zstd, "zstd-compress chunks where it saves at least 10%");
    app->add_flag("--overwrite", options_.overwrite, "replace an output that was made with other parameters");
    app->add_flag("!--no-verify-input", options_.verify_input,
                  "skip the checksum pass over the input (saves one sequential read of it)");
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
    options_.mem_limit = sf.mem_limit;
    options_.jobs = sf.jobs;
    ProgressBar bar(flags_, "transpose");
    auto r = stages::RunTranspose(options_, bar.hook());
    bar.Done();
    if (!r.ok()) return ReportFailure(r.status());
    if (!r->direct_fallback.empty() && !flags_.quiet) {
      std::cerr << "ltbake: note: " << r->direct_fallback << "; the output was written through the page cache\n";
    }
    if (!flags_.quiet) {
      std::cout << "wrote " << OutputName(options_.output, options_.shard) << ": " << r->rows << " x " << r->cols
                << " in chunks of " << r->block_cols << " column(s); " << r->panels << " panel(s) of up to "
                << r->panel_cols << " columns";
      if (r->chunks_already_committed)
        std::cout << " (resumed: " << r->chunks_already_committed << " already committed)";
      std::cout << "; " << r->zero_chunks_out << " all-zero chunks stored free; read " << r->bytes_read
                << " + verified " << r->bytes_verified << " bytes, wrote " << r->bytes_written;
      if (r->bytes_direct > 0) std::cout << " (" << r->bytes_direct << " with O_DIRECT)";
      std::cout << "\n";
    }
    return kExitOk;
  }

 private:
  stages::TransposeOptions options_;
  CommonFlags flags_;
  ShardFlags shard_flags_;
};

}  // namespace

std::unique_ptr<Command> RegisterTranspose(CLI::App* parent) { return std::make_unique<TransposeCommand>(parent); }

}  // namespace ltb::cli
