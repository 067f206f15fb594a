// ltbake quantize IN -o OUT [--bits 9] [--no-dither] [--scaling level|none]
#include <filesystem>
#include <iomanip>
#include <iostream>

#include <nlohmann/json.hpp>

#include "cli/commands.h"
#include "cli/common.h"
#include "stages/quantize/quantize.h"

namespace ltb::cli {
namespace {

class QuantizeCommand : public Command {
 public:
  explicit QuantizeCommand(CLI::App* parent) {
    auto* app = parent->add_subcommand(
        "quantize", "scale by 2^level, normalise, dither and quantize a column-transform output (final.ltm)");
    app->add_option("IN", options_.input, "input container (from `ltbake column-transform`)")->required();
    app->add_option("-o,--output", options_.output, "output container (final.ltm, what relight reads)")->required();
    app->add_option("--bits", options_.bits, "bits per coefficient, sign included")->default_val(9)->check(CLI::Range(2, 24));
    app->add_option("--scaling", scaling_, "level: multiply level-l coefficients by 2^l first; none: do not")
        ->default_val("level")
        ->check(CLI::IsMember({"level", "none"}));
    app->add_flag("!--no-dither", options_.dither, "round to nearest instead of dithering");
    app->add_option("--seed", options_.seed, "dither seed")->default_val(1);
    app->add_flag("!--no-zstd", options_.zstd, "do not zstd-compress the sparse chunks");
    app->add_flag("--overwrite", options_.overwrite, "replace an output that was made with other parameters");
    app->add_flag("--json", json_, "print the summary as JSON");
    AddCommonFlags(app, &flags_);
    AddShardFlags(app, &shard_flags_);
  }

  int Run() override {
    auto shard = ResolveShard(shard_flags_);
    if (!shard.ok()) {
      std::cerr << "ltbake: " << shard.status().message() << "\n";
      return kExitUsage;
    }
    options_.shard = *shard;
    options_.level_scaling = scaling_ == "level";
    options_.jobs = flags_.jobs;
    ProgressBar bar(flags_, "quantize");
    auto r = stages::RunQuantize(options_, bar.hook());
    bar.Done();
    if (!r.ok()) return ReportFailure(r.status());
    const std::string file = options_.shard.sharded()
                                 ? io::ShardPath(options_.output, options_.shard.index, options_.shard.count)
                                 : options_.output;
    std::error_code ec;
    const uint64_t file_bytes = std::filesystem::file_size(file, ec);  // what is on disk
    if (json_) {
      nlohmann::json j = {{"output", options_.output},
                          {"file", file},                     {"file_bytes", ec ? 0 : file_bytes},
                          {"bits", options_.bits},
                          {"scaling", scaling_},              {"dither", options_.dither},
                          {"nonzeros_in", r->nonzeros_in},    {"nonzeros_out", r->nonzeros_out},
                          {"matrix_bytes", r->matrix_bytes},  {"bytes_per_nonzero", r->BytesPerNonzero()},
                          {"chunks_written", r->chunks_written},
                          {"chunks_already_committed", r->chunks_already_committed}};
      std::cout << j.dump(2) << "\n";
    } else if (!flags_.quiet) {
      std::cout << "wrote " << OutputName(options_.output, options_.shard) << ": " << options_.bits << " bits, " << r->nonzeros_out << " of "
                << r->nonzeros_in << " coefficients nonzero after quantization; matrix payload " << r->matrix_bytes
                << " bytes (" << std::setprecision(3) << r->BytesPerNonzero() << " bytes per nonzero), file "
                << (ec ? std::string("?") : std::to_string(file_bytes)) << " bytes on disk";
      if (r->chunks_already_committed) std::cout << " (resumed: " << r->chunks_already_committed << " already committed)";
      std::cout << "\n";
    }
    return kExitOk;
  }

 private:
  stages::QuantizeOptions options_;
  std::string scaling_ = "level";
  bool json_ = false;
  CommonFlags flags_;
  ShardFlags shard_flags_;
};

}  // namespace

std::unique_ptr<Command> RegisterQuantize(CLI::App* parent) { return std::make_unique<QuantizeCommand>(parent); }

}  // namespace ltb::cli
