// ltbake convert IN OUT
#include <cstdio>
#include <iostream>
#include <nlohmann/json.hpp>

#include "cli/commands.h"
#include "cli/common.h"
#include "format/io/file_lock.h"
#include "format/json_text.h"
#include "stages/convert/convert.h"
#include "stages/images/envmap.h"

namespace ltb::cli {
namespace {

class ConvertCommand : public Command {
 public:
  explicit ConvertCommand(CLI::App* parent) {
    auto* app = parent->add_subcommand(
        "convert", ".npy (2-D float32/float64, C order) -> .ltm, or .ltm -> dense float32 .npy (by extension)");
    app->add_option("IN", options_.input, "input file")->required();
    app->add_option("OUT", options_.output, "output file")->required();
    app->add_option("--chunk-size", chunk_size_, "target bytes per chunk (npy -> ltm)")
        ->default_val("8MiB")
        ->check(SizeCheck());
    app->add_option("--layout", layout_, "chunk layout of the .ltm: rows (row blocks) or cols (column blocks)")
        ->default_val("rows")
        ->check(CLI::IsMember({"rows", "cols"}));
    app->add_flag("--zstd", options_.zstd, "zstd-compress chunks where it saves at least 10%");
    app->add_flag("--overwrite", options_.overwrite, "replace an output that was written with other parameters");
    app->add_option("--cube-res", options_.cube_res,
                    "declare the columns a pixel-basis cubemap with R×R faces (6·R² columns, R a power of two)");
    app->add_option("--image", image_, "declare the rows the pixels of a WxH image (W·H rows, row y·W + x)");
    app->add_option("--basis", basis_,
                    "ltm -> npy: stored (default; column-transform and quantize outputs decode to the row-transformed "
                    "basis) or pixels (also invert the row transform)")
        ->default_val("stored")
        ->check(CLI::IsMember({"stored", "pixels"}));
    app->add_option("--env-layout", env_layout_,
                    "environment map input (.exr/.hdr, or six faces through {face}) -> .npy cubemap: auto, latlong, "
                    "hcross, vcross, faces or angular (light probe)")
        ->default_val("auto")
        ->check(CLI::IsMember({"auto", "latlong", "hcross", "vcross", "faces", "angular"}));
    app->add_flag("--clamp", env_clamp_,
                  "environment map input: set NaN and negative values to 0 and +Inf to the largest float instead of "
                  "refusing them");
    app->add_flag("--json", json_, "print the summary as JSON");
    AddCommonFlags(app, &flags_);
  }

  int Run() override {
    auto chunk = stages::ParseByteSize(chunk_size_);
    if (!chunk.ok()) return ReportUsage(chunk.status().WithContext("--chunk-size"));
    StageFlags sf;
    if (int code = ResolveStageFlags(flags_, nullptr, &sf); code != kExitOk) return code;
    options_.chunk_bytes = *chunk;
    options_.mem_limit = sf.mem_limit;
    options_.jobs = sf.jobs;
    options_.pixel_basis = basis_ == "pixels";
    options_.layout = layout_ == "cols" ? format::Layout::kCols : format::Layout::kRows;
    if (!image_.empty()) {
      unsigned long long w = 0, h = 0;
      char x = 0, extra = 0;
      if (std::sscanf(image_.c_str(), "%llu%c%llu%c", &w, &x, &h, &extra) != 3 || (x != 'x' && x != 'X') || w == 0 ||
          h == 0) {
        std::cerr << "ltbake: usage error: --image \"" << image_ << "\" is not WIDTHxHEIGHT (e.g. 256x256)\n";
        return kExitUsage;
      }
      options_.image_width = w;
      options_.image_height = h;
    }
    if (stages::IsEnvMapPath(options_.input)) {  // environment map -> 6R² × 3 cubemap .npy
      if (options_.cube_res == 0) {
        std::cerr << "ltbake: usage error: converting an environment map needs --cube-res R\n";
        return kExitUsage;
      }
      ProgressBar bar(flags_, "convert");
      stages::EnvLoadOptions env;
      env.layout = *stages::ParseEnvLayout(env_layout_);  // checked by IsMember
      env.clamp = env_clamp_;
      env.max_bytes = sf.mem_limit;  // the map's pixels (and an .hdr's bytes) within --mem-limit
      env.progress = bar.hook();     // SIGINT/SIGTERM while loading or resampling: 130/143
      uint64_t clamped = 0;
      auto lock = io::LockOutput(options_.output);  // one writer per output
      if (!lock.ok()) return ReportFailure(lock.status());
      Status s = stages::ConvertEnvToNpy(options_.input, options_.output, options_.cube_res, env, &clamped);
      bar.Done();
      if (!s.ok()) return ReportFailure(s);
      if (json_) {
        std::cout << JsonText({{"output", options_.output},
                               {"kind", "environment cubemap"},
                               {"rows", 6 * options_.cube_res * options_.cube_res},
                               {"cols", 3},
                               {"cube_res", options_.cube_res},
                               {"clamped_values", clamped}},
                              -1)
                  << "\n";
      } else if (!flags_.quiet) {
        std::cout << "wrote " << options_.output << ": " << 6 * options_.cube_res * options_.cube_res
                  << " x 3 cubemap (R = " << options_.cube_res << ")";
        if (clamped) std::cout << ", " << clamped << " values clamped";
        std::cout << "\n";
      }
      return kExitOk;
    }
    ProgressBar bar(flags_, "convert");
    auto r = stages::RunConvert(options_, bar.hook());
    bar.Done();
    if (!r.ok()) return ReportFailure(r.status());
    if (!r->restarted_because.empty()) {
      std::cerr << "ltbake convert: started over (--overwrite): " << r->restarted_because << "\n";
    }
    if (json_) {
      nlohmann::json j = {{"output", options_.output},
                          {"rows", r->rows},
                          {"cols", r->cols},
                          {"chunks_total", r->chunks_total},
                          {"chunks_written", r->chunks_written},
                          {"chunks_already_committed", r->chunks_already_committed},
                          {"zero_chunks", r->zero_chunks},
                          {"zstd_chunks", r->zstd_chunks},
                          {"bytes_out", r->bytes_out}};
      if (r->channels) j["channels"] = r->channels;
      if (!r->restarted_because.empty()) j["restarted_because"] = r->restarted_because;
      std::cout << JsonText(j, -1) << "\n";
    } else if (!flags_.quiet) {
      std::cout << "wrote " << options_.output << ": ";
      if (r->channels) std::cout << r->channels << " channels x ";
      std::cout << r->rows << " x " << r->cols << ", " << r->chunks_total << " chunks";
      if (r->chunks_already_committed > 0) {
        std::cout << " (resumed: " << r->chunks_already_committed << " already committed, " << r->chunks_written
                  << " written";
        if (r->discarded_tail_bytes) std::cout << ", " << r->discarded_tail_bytes << " uncommitted bytes discarded";
        std::cout << ")";
      }
      if (r->zero_chunks) std::cout << ", " << r->zero_chunks << " all-zero";
      if (r->zstd_chunks) std::cout << ", " << r->zstd_chunks << " zstd";
      std::cout << ", " << r->bytes_out << " bytes\n";
    }
    return kExitOk;
  }

 private:
  stages::ConvertOptions options_;
  bool json_ = false;
  std::string chunk_size_ = "8MiB", layout_ = "rows", image_, basis_ = "stored", env_layout_ = "auto";
  bool env_clamp_ = false;
  CommonFlags flags_;
};

}  // namespace

std::unique_ptr<Command> RegisterConvert(CLI::App* parent) { return std::make_unique<ConvertCommand>(parent); }

}  // namespace ltb::cli
