// ltbake sample SCENE.toml -o raw.ltm [--cube-res R] [--spp N] [--bounces N] [--seed S]
#include <cstdio>
#include <iostream>

#include "cli/commands.h"
#include "cli/common.h"
#include "stages/sample/sample.h"
#include "stages/sample/scene.h"

namespace ltb::cli {
namespace {

class SampleCommand : public Command {
 public:
  explicit SampleCommand(CLI::App* parent) {
    auto* app = parent->add_subcommand("sample", "ray-cast the light transport matrix of a scene (Embree)");
    // The scene's existence is checked when it is read, so a directory or a FIFO is named as such.
    app->add_option("SCENE", options_.scene, "scene file (TOML, see docs/SCENE.md)")->required();
    app->add_option("-o,--output", options_.output, "output container (row blocks)")->required();
    app->add_option("--cube-res", cube_res_,
                    "cube face resolution R, a power of two up to " + std::to_string(sample::kMaxCubeRes) +
                        " (default: the scene's, else 32)")
        ->check(PowerOfTwoCheck(sample::kMaxCubeRes));
    app->add_option("--spp", spp_, "stratified jittered rays per texel (default: the scene's, else 4)")
        ->check(CLI::Range(int64_t{1}, int64_t{1} << 16));
    app->add_option("--bounces", bounces_, "diffuse interreflection bounces (default: the scene's, else 0)")
        ->check(CLI::Range(int64_t{0}, int64_t{16}));
    app->add_option("--seed", seed_, "random seed (default: the scene's, else 1)")
        ->check(CLI::Range(int64_t{0}, int64_t{1} << 62));
    app->add_option("--chunk-rows", options_.chunk_rows, "rows per chunk (default: ~2 MiB chunks)");
    app->add_option("--row-transform", row_filter_,
                    "fused sample + row-transform: wavelet-transform each row block with this filter before it is "
                    "written (the output equals `ltbake row-transform` of the raw matrix; no raw file)")
        ->check(CLI::IsMember({"haar", "db1", "db2", "db3", "db4"}));
    app->add_flag("--row-zstd", options_.row_zstd, "with --row-transform: zstd-compress the matrix chunks");
    app->add_flag("--visibility", options_.visibility,
                  "vertex mode: bake the visibility field V(x, w) of the triple-product path (docs/TRIPLE.md), "
                  "Haar per face, sparse, instead of T");
    app->add_flag("--overwrite", options_.overwrite, "replace an output that was made with other parameters");
    app->add_flag("!--no-direct-io", options_.direct_io,
                  "write the output through the page cache instead of with O_DIRECT");
    AddCommonFlags(app, &flags_);
    AddShardFlags(app, &shard_flags_);
  }

  int Run() override {
    StageFlags sf;
    if (int code = ResolveStageFlags(flags_, &shard_flags_, &sf); code != kExitOk) return code;
    options_.shard = sf.shard;
    if (cube_res_ >= 0) options_.cube_res = static_cast<uint32_t>(cube_res_);
    if (spp_ >= 0) options_.spp = static_cast<uint32_t>(spp_);
    if (bounces_ >= 0) options_.bounces = static_cast<uint32_t>(bounces_);
    if (seed_ >= 0) options_.seed = static_cast<uint64_t>(seed_);
    options_.jobs = sf.jobs;
    options_.mem_limit = sf.mem_limit;  // bounds the queue of chunks waiting to be written
    if (!row_filter_.empty()) options_.row_filter = *wavelet::ParseFilter(row_filter_);  // checked by IsMember
    ProgressBar bar(flags_, "sample");
    auto r = stages::RunSample(options_, bar.hook());
    bar.Done();
    if (!r.ok()) return ReportFailure(r.status());
    if (!r->direct_fallback.empty() && !flags_.quiet) {
      std::cerr << "ltbake: note: " << r->direct_fallback << "; the output was written through the page cache\n";
    }
    if (!flags_.quiet) {
      char rate[64];
      std::snprintf(rate, sizeof rate, "%.3g", r->seconds > 0 ? r->rays / r->seconds : 0.0);
      std::cout << "wrote " << OutputName(options_.output, options_.shard) << ": " << r->rows << " rows x "
                << 6ull * r->cube_res * r->cube_res << " texels (R = " << r->cube_res << ", spp " << r->spp
                << ", bounces " << r->bounces << ")";
      if (!row_filter_.empty()) std::cout << ", row-transformed (" << row_filter_ << ")";
      if (options_.visibility) std::cout << ", visibility field (Haar, sparse)";
      if (r->chunks_already_committed)
        std::cout << ", resumed (" << r->chunks_already_committed << " chunks were committed)";
      std::cout << "\n  rows that see geometry: " << r->valid_rows << " (the rest are all-zero rows, mask 0)"
                << "\n  rays traced: " << r->rays << " in " << r->seconds << " s (" << rate << " rays/s)"
                << "\n  skipped: " << r->texels_below_horizon << " (row, texel) pairs wholly below the horizon, "
                << r->samples_below_horizon << " samples below it"
                << "\n  degenerate triangles dropped: " << r->degenerate_triangles << "\n";
    }
    return kExitOk;
  }

 private:
  stages::SampleOptions options_;
  std::string row_filter_;
  long long cube_res_ = -1, spp_ = -1, bounces_ = -1, seed_ = -1;
  CommonFlags flags_;
  ShardFlags shard_flags_;
};

}  // namespace

std::unique_ptr<Command> RegisterSample(CLI::App* parent) { return std::make_unique<SampleCommand>(parent); }

}  // namespace ltb::cli
