// ltbake quantize IN -o OUT [--error-ratio 1.1 | --bits 9 [--dither] [--scaling level|none]]
#include <cmath>
#include <filesystem>
#include <iomanip>
#include <iostream>
#include <nlohmann/json.hpp>

#include "cli/commands.h"
#include "cli/common.h"
#include "format/json_text.h"
#include "stages/quantize/quantize.h"

namespace ltb::cli {
namespace {

class QuantizeCommand : public Command {
 public:
  explicit QuantizeCommand(CLI::App* parent) {
    auto* app = parent->add_subcommand("quantize",
                                       "quantize a column-transform output (final.ltm): one step for the whole matrix "
                                       "(default), or per-column maxima with --bits");
    app->add_option("IN", options_.input, "input container (from `ltbake column-transform`)")->required();
    app->add_option("-o,--output", options_.output, "output container (final.ltm, what relight reads)")->required();
    auto* ratio = app->add_option("--error-ratio", options_.error_ratio,
                                  "one quantization step for the whole matrix (the default, 1.1), chosen so the "
                                  "matrix's RMS error grows by at most this factor over column-transform's")
                      ->check(CLI::Range(1.000001, 100.0));
    auto* bits = bits_opt_ =
        app->add_option("--bits", options_.bits,
                        "instead: each column normalised by its largest coefficient and quantized to "
                        "this many bits, sign included (2..24; CP07 §4.3)")
            ->check(CLI::Range(2, 24));
    ratio->excludes(bits);
    app->add_option("--scaling", scaling_,
                    "with --bits: level multiplies level-l coefficients by 2^l first; none: do not")
        ->default_val("level")
        ->check(CLI::IsMember({"level", "none"}))
        ->needs(bits);
    app->add_flag("--dither,!--no-dither", options_.dither,
                  "with --bits: dither instead of rounding to nearest (unbiased, but more RMS error; off by default)")
        ->needs(bits);
    app->add_option("--seed", options_.seed, "with --bits: dither seed")->default_val(1)->needs(bits);
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
    options_.level_scaling = scaling_ == "level";
    if (bits_opt_->count() == 0 && options_.error_ratio == 0) options_.error_ratio = kDefaultErrorRatio;
    const bool step_mode = options_.error_ratio != 0;
    options_.jobs = sf.jobs;
    ProgressBar bar(flags_, "quantize");
    auto r = stages::RunQuantize(options_, bar.hook());
    bar.Done();
    if (!r.ok()) return ReportFailure(r.status());
    const std::string file = options_.shard.sharded()
                                 ? io::ShardPath(options_.output, options_.shard.index, options_.shard.count)
                                 : options_.output;
    std::error_code ec;
    const uint64_t file_bytes = std::filesystem::file_size(file, ec);  // what is on disk
    // --error-ratio: the RMS error after quantization over column-transform's (measured).
    const double e = r->truncation_error, q = r->quantization_error;
    const bool measured = step_mode && std::isfinite(q);
    const double ratio = measured && e > 0 ? std::sqrt((e + q) / e) : NAN;
    const double rel = measured && r->energy > 0 ? std::sqrt((e + q) / r->energy) : NAN;
    if (json_) {
      auto num = [](double v) { return std::isfinite(v) ? nlohmann::json(v) : nlohmann::json(nullptr); };
      nlohmann::json j = {{"output", options_.output},
                          {"file", file},
                          {"file_bytes", ec ? 0 : file_bytes},
                          {"mode", step_mode ? "step" : "bits"},
                          {"bits", step_mode ? 24 : options_.bits},
                          {"scaling", step_mode ? "norm" : scaling_},
                          {"dither", step_mode ? false : options_.dither},
                          {"nonzeros_in", r->nonzeros_in},
                          {"nonzeros_out", r->nonzeros_out},
                          {"matrix_bytes", r->matrix_bytes},
                          {"bytes_per_nonzero", r->BytesPerNonzero()},
                          {"chunks_written", r->chunks_written},
                          {"chunks_already_committed", r->chunks_already_committed}};
      if (step_mode) {
        j["error_ratio"] = options_.error_ratio;
        j["step"] = r->step;
        j["truncation_error"] = e;
        j["quantization_error"] = num(q);
        j["rms_error_ratio"] = num(ratio);
        j["relative_rms_error"] = num(rel);
      }
      std::cout << JsonText(j, 2) << "\n";
    } else if (!flags_.quiet) {
      std::cout << "wrote " << OutputName(options_.output, options_.shard) << ": ";
      if (step_mode) {
        std::cout << "one step " << std::setprecision(4) << r->step;
        if (measured) std::cout << " (RMS error x" << ratio << " over column-transform's, relative " << rel << ")";
        std::cout << ", ";
      } else {
        std::cout << options_.bits << " bits, ";
      }
      std::cout << r->nonzeros_out << " of " << r->nonzeros_in
                << " coefficients nonzero after quantization; matrix payload " << r->matrix_bytes << " bytes ("
                << std::setprecision(3) << r->BytesPerNonzero() << " bytes per nonzero), file "
                << (ec ? std::string("?") : std::to_string(file_bytes)) << " bytes on disk";
      if (r->chunks_already_committed)
        std::cout << " (resumed: " << r->chunks_already_committed << " already committed)";
      std::cout << "\n";
    }
    return kExitOk;
  }

 private:
  static constexpr double kDefaultErrorRatio = 1.1;
  stages::QuantizeOptions options_;
  CLI::Option* bits_opt_ = nullptr;
  std::string scaling_ = "level";
  bool json_ = false;
  CommonFlags flags_;
  ShardFlags shard_flags_;
};

}  // namespace

std::unique_ptr<Command> RegisterQuantize(CLI::App* parent) { return std::make_unique<QuantizeCommand>(parent); }

}  // namespace ltb::cli
