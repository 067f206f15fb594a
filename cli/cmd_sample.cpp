// ltbake sample SCENE.toml -o raw.ltm [--cube-res R] [--spp N] [--bounces N] [--seed S]
#include <algorithm>
#include <cstdio>
#include <iostream>
#include <nlohmann/json.hpp>
#include <optional>

#include "cli/commands.h"
#include "cli/common.h"
#include "format/json_text.h"
#include "stages/common/channels.h"
#include "stages/common/quantity.h"
#include "stages/sample/factor_choice.h"
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
    sparse_opt_ =
        app->add_option(
               "--sparse", sparse_mode_,
               "sparse precomputation (docs/SPARSE.md): trace about a quarter of the rows densely and the rest "
               "on a few feature texels, reconstructed from dense neighbours. --sparse auto: a short pilot "
               "measures both ways on this scene and bakes in full when sparse would not be faster; "
               "--sparse or --sparse force: sparse regardless")
            ->expected(0, 1)
            ->default_str("force");
    app->add_option("--sparse-margin", sparse_margin_, "")->group("")->check(CLI::Range(0.0, 1e9));
    app->add_option("--dense-fraction", options_.sparse.dense_fraction,
                    "with --sparse: dense rows / rows that see geometry, in (0, 1]")
        ->default_val(0.25);
    app->add_option("--radius", radius_,
                    "with --sparse: neighbour radius in scene units (default: 0.04 x the rows' bounding-box diagonal)");
    app->add_option("--features", features_,
                    "with --sparse: texels traced per sparse row (default: 350 x 6R^2 / 6144, i.e. 350 at R = 32, but "
                    "at least 4 x --neighbours)");
    app->add_option("--neighbours", options_.sparse.neighbours,
                    "with --sparse: dense neighbours a sparse row combines, at most (1..64)")
        ->default_val(16);
    app->add_option("--l1-lambda", options_.sparse.lambda,
                    "with --sparse: L1 weight of the fit, relative to the smallest that gives all-zero weights")
        ->default_val(1e-3);
    app->add_option("--max-residual", options_.sparse.max_residual,
                    "with --sparse: a sparse row whose fit misses its own traced texels by more than this (relative "
                    "L2, beyond their Monte Carlo noise) is traced in full instead")
        ->default_val(0.15);
    app->add_option("--tolerance", tolerance_,
                    "converged sampling (docs/SAMPLE.md): sample the matrix to this estimated relative RMS error "
                    "(\"1%\" or 0.01), each texel at --spp and, where its error needs it, again at 2, 4, ... times; "
                    "with --bounces, each row's indirect paths doubled where theirs does (--spp 2 --max-levels 6 is "
                    "the measured choice)");
    app->add_option("--max-levels", options_.max_levels,
                    "with --tolerance: levels of sampling, at most (1..12; 5: up to 16 x --spp)")
        ->default_val(5);
    app->add_option("--channels", channels_,
                    "mono: one matrix (a scene with colour gets a per-row reflectance table); rgb: one matrix per "
                    "colour channel, OUT.r.ltm, OUT.g.ltm, OUT.b.ltm (docs/COLOUR.md)")
        ->default_val("mono")
        ->check(CLI::IsMember({"mono", "rgb"}));
    app->add_option("--channel", channel_, "bake only this channel of --channels rgb, into OUT as given")
        ->check(CLI::IsMember({"r", "g", "b"}));
    app->add_option("--factor", factor_text_,
                    "vertex mode: bake the BRDF in-out factorisation's K terms, OUT.k0.ltm .. OUT.k{K-1}.ltm, so "
                    "glossy vertices relight from any view (relight --eye; docs/GLOSSY.md); K in 1..64, or "
                    "auto:T, the fewest terms whose factorisation of every glossy material is within T (e.g. "
                    "auto:5%)");
    app->add_option("--factor-grid", factor_grid_,
                    "with --factor: cells a side of the parabolic maps of incident and view directions, I,V")
        ->default_val("96,32");
    app->add_option("--factor-term", factor_term_,
                    "with --factor K: write only term T (0..K-1) into OUT as given; ltbake run bakes a term a step")
        ->check(CLI::Range(0, 63));
    app->add_flag("--overwrite", options_.overwrite, "replace an output that was made with other parameters");
    app->add_flag("--json", json_, "print the summary as JSON (one object; a channel set's passes, one a line)");
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
    if (radius_) options_.sparse.radius = *radius_;
    if (sparse_opt_->count() > 0) {
      if (sparse_mode_ != "auto" && sparse_mode_ != "force" && !sparse_mode_.empty()) {
        return ReportUsage(
            InvalidArgument("--sparse " + sparse_mode_ + ": expected auto or force (or no value: force)"));
      }
      options_.sparse.enabled = true;
      options_.sparse.automatic = sparse_mode_ == "auto";
    }
    if (sparse_margin_) {
      if (!options_.sparse.automatic) return ReportUsage(InvalidArgument("--sparse-margin goes with --sparse auto"));
      options_.sparse.auto_margin = *sparse_margin_;
    }
    if (!tolerance_.empty()) {
      auto t = stages::ParseFraction(tolerance_);
      if (!t.ok()) return ReportUsage(t.status().WithContext("--tolerance"));
      options_.tolerance = *t;
    } else if (options_.max_levels != 5) {
      return ReportUsage(InvalidArgument("--max-levels goes with --tolerance"));
    }
    if (features_)
      options_.sparse.features = static_cast<uint32_t>(std::clamp<long long>(*features_, 0, (1ll << 32) - 1));
    options_.jobs = sf.jobs;
    options_.mem_limit = sf.mem_limit;  // bounds the queue of chunks waiting to be written
    if (!row_filter_.empty()) options_.row_filter = *wavelet::ParseFilter(row_filter_);  // checked by IsMember
    if (!channel_.empty() && channels_ == "rgb") {
      return ReportUsage(
          InvalidArgument("--channel " + channel_ + " bakes one channel into OUT; leave out --channels rgb"));
    }
    if (!channel_.empty()) options_.channel = static_cast<int>(std::string("rgb").find(channel_));
    if (factor_term_ >= 0) options_.factor_term = static_cast<uint32_t>(factor_term_);
    std::optional<double> factor_target;  // --factor auto:T
    if (factor_text_.starts_with("auto:")) {
      auto t = stages::ParseFraction(factor_text_.substr(5));
      if (!t.ok()) return ReportUsage(t.status().WithContext("--factor " + factor_text_));
      if (factor_term_ >= 0) {
        return ReportUsage(
            InvalidArgument("--factor-term names a term of a fixed K; give --factor K (sample --factor " +
                            factor_text_ + " prints the K it chose)"));
      }
      factor_target = *t;
    } else if (!factor_text_.empty()) {
      const std::optional<uint64_t> k =
          factor_text_.find_first_not_of("0123456789") == std::string::npos && factor_text_.size() <= 2
              ? std::optional<uint64_t>(std::stoull(factor_text_))
              : std::nullopt;
      if (!k || *k < 1 || *k > sample::kMaxFactorTerms) {
        return ReportUsage(
            InvalidArgument("--factor " + factor_text_ + ": expected K in 1..64 or auto:T (e.g. auto:5%)"));
      }
      options_.factor = static_cast<uint32_t>(*k);
    }
    {
      unsigned gi = 0, gv = 0;
      char tail = 0;
      if (std::sscanf(factor_grid_.c_str(), "%u,%u%c", &gi, &gv, &tail) != 2 || gi < 4 || gi > 512 || gv < 4 ||
          gv > 256) {
        return ReportUsage(
            InvalidArgument("--factor-grid " + factor_grid_ + ": expected I,V with I in 4..512 and V in 4..256"));
      }
      options_.factor_incident_res = gi;
      options_.factor_view_res = gv;
    }
    if (factor_target) {  // the fewest terms for the target, from the factorisation's own errors
      auto scene = sample::ParseScene(options_.scene);
      if (!scene.ok()) return ReportFailure(scene.status());
      auto c =
          sample::ChooseFactorTerms(*scene, *factor_target, options_.factor_incident_res, options_.factor_view_res);
      if (!c.ok()) return ReportFailure(c.status());
      options_.factor = c->terms;
      factor_choice_ = *c;
      if (!flags_.quiet && !json_) {
        char b[200];
        if (c->worst_material.empty()) {
          std::snprintf(b, sizeof b, "--factor %s: K = 1 (no material the vertices use is glossy)",
                        factor_text_.c_str());
        } else {
          std::snprintf(b, sizeof b,
                        "--factor %s: K = %u (material \"%s\", the farthest, is %.3g off at K = %u; a view "
                        "costs about K products a vertex)",
                        factor_text_.c_str(), c->terms, c->worst_material.c_str(), c->worst_error, c->terms);
        }
        std::cout << b << "\n";
      }
    }
    if (channels_ != "rgb") return RunOne();
    if (!options_.sparse.enabled) {  // the three channels from one pass
      options_.rgb = true;
      return RunOne();
    }
    const std::string set = options_.output;  // sparse: a pass per channel
    for (int c = 0; c < 3; ++c) {             // one container per channel: every later stage runs on each
      options_.channel = c;
      options_.output = stages::ChannelPath(set, c);
      if (int code = RunOne(); code != kExitOk) return code;
    }
    return kExitOk;
  }

 private:
  int RunOne() {
    ProgressBar bar(flags_, options_.channel >= 0 ? std::string("sample ") + stages::ChannelName(options_.channel)
                                                  : std::string("sample"));
    auto r = stages::RunSample(options_, bar.hook());
    bar.Done();
    if (!r.ok()) return ReportFailure(r.status());
    if (json_) {
      std::cout << JsonText(SummaryJson(*r), -1) << "\n";
      return kExitOk;
    }
    if (!r->direct_fallback.empty() && !flags_.quiet) {
      std::cerr << "ltbake: note: " << r->direct_fallback << "; the output was written through the page cache\n";
    }
    if (!flags_.quiet) {
      char rate[64];
      std::snprintf(rate, sizeof rate, "%.3g", r->seconds > 0 ? r->rays / r->seconds : 0.0);
      std::string what = OutputName(options_.output, options_.shard);
      if (options_.factor > 0 && !options_.factor_term) {
        what =
            stages::FactorPath(options_.output, 0) + " .. " + stages::FactorPath(options_.output, options_.factor - 1);
      } else if (options_.rgb) {
        what = stages::ChannelPath(options_.output, 0) + ", " + stages::ChannelPath(options_.output, 1) + ", " +
               stages::ChannelPath(options_.output, 2);
      }
      std::cout << "wrote " << what << ": " << r->rows << " rows x " << 6ull * r->cube_res * r->cube_res
                << " texels (R = " << r->cube_res << ", spp " << r->spp << ", bounces " << r->bounces << ")";
      if (!row_filter_.empty()) std::cout << ", row-transformed (" << row_filter_ << ")";
      if (options_.visibility) std::cout << ", visibility field (Haar, sparse)";
      if (r->chunks_already_committed)
        std::cout << ", resumed (" << r->chunks_already_committed << " chunks were committed)";
      std::cout << "\n  rows that see geometry: " << r->valid_rows << " (the rest are all-zero rows, mask 0)"
                << "\n  rays traced: " << r->rays << " in " << r->seconds << " s (" << rate << " rays/s)"
                << "\n  skipped: " << r->texels_below_horizon << " (row, texel) pairs wholly below the horizon, "
                << r->samples_below_horizon << " samples below it"
                << "\n  degenerate triangles dropped: " << r->degenerate_triangles << "\n";
      if (r->sparse_auto) PrintSparseAuto(*r->sparse_auto);
      if (r->sparse) PrintSparse(*r->sparse);
      if (options_.tolerance) PrintConverged(*r);
      for (const auto& [name, errors] : r->factor_errors) {
        std::cout << "  factorisation of material \"" << name << "\": relative L2 error of rho*cos for K = 1..";
        std::cout << errors.size() << ":";
        char e[32];
        for (double x : errors) {
          std::snprintf(e, sizeof e, " %.4f", x);
          std::cout << e;
        }
        std::cout << "\n";
      }
    }
    return kExitOk;
  }

  nlohmann::json SummaryJson(const stages::SampleResult& r) const {
    nlohmann::json j = {{"output", options_.output},
                        {"rows", r.rows},
                        {"rows_with_geometry", r.valid_rows},
                        {"cols", 6ull * r.cube_res * r.cube_res},
                        {"cube_res", r.cube_res},
                        {"spp", r.spp},
                        {"bounces", r.bounces},
                        {"rays", r.rays},
                        {"seconds", r.seconds},
                        {"texels_below_horizon", r.texels_below_horizon},
                        {"samples_below_horizon", r.samples_below_horizon},
                        {"degenerate_triangles", r.degenerate_triangles},
                        {"chunks_written", r.chunks_written},
                        {"chunks_already_committed", r.chunks_already_committed}};
    if (options_.channel >= 0) j["channel"] = stages::ChannelName(options_.channel);
    if (!r.direct_fallback.empty()) j["direct_io_note"] = r.direct_fallback;
    if (r.sparse) {
      const stages::SparseStats& sp = *r.sparse;
      j["sparse"] = {{"dense_rows", sp.dense_rows},
                     {"sparse_rows", sp.sparse_rows},
                     {"rows_traced_in_full", sp.fallback_rows},
                     {"traced_fraction", sp.traced_fraction()},
                     {"rays", {sp.total_rays[0], sp.total_rays[1]}},
                     {"seconds", {sp.seconds[0], sp.seconds[1]}}};
    }
    if (r.sparse_auto) {
      const stages::SparseAuto& a = *r.sparse_auto;
      j["sparse_auto"] = {
          {"decision", a.sparse ? "sparse" : "full"},
          {"resumed", a.resumed},
          {"reason", a.reason},
          {"pilot_rows", a.pilot_rows},
          {"pilot_dense_rows", a.pilot_dense_rows},
          {"pilot_seconds", a.pilot_seconds},
          {"cpu_seconds_per_row", {{"full", a.full_row}, {"dense", a.dense_row}, {"sparse", a.sparse_row}}},
          {"fallback_fraction", a.fallback_fraction},
          {"predicted_cpu_seconds", {{"full", a.predicted_full}, {"sparse", a.predicted_sparse}}},
          {"margin", a.margin}};
    }
    if (options_.tolerance) {
      j["converged"] = {{"tolerance", *options_.tolerance},
                        {"max_levels", options_.max_levels},
                        {"rows_by_highest_level", r.level_histogram},
                        {"pilot_rows", r.pilot_rows},
                        {"largest_row_error", r.max_rel_error},
                        {"reachable", r.tolerance_reachable},
                        {"least_error", r.least_error}};
    }
    for (const auto& [name, errors] : r.factor_errors) j["factor_errors"][name] = errors;
    if (factor_choice_) {
      j["factor_auto"] = {{"target", factor_text_.substr(5)},
                          {"terms", factor_choice_->terms},
                          {"material", factor_choice_->worst_material},
                          {"error", factor_choice_->worst_error}};
    }
    return j;
  }

  void PrintConverged(const stages::SampleResult& r) const {
    std::string hist;
    for (size_t k = 0; k < r.level_histogram.size(); ++k) {
      if (r.level_histogram[k] != 0) hist += " " + std::to_string(k) + ":" + std::to_string(r.level_histogram[k]);
    }
    char line[256];
    std::snprintf(line, sizeof line,
                  "  converged: tolerance %.4g, up to spp %u; pilot of %llu rows, RMS row norm %.4g; largest row "
                  "error %.4g of it\n",
                  *options_.tolerance, r.spp << (options_.max_levels - 1),
                  static_cast<unsigned long long>(r.pilot_rows), r.pilot_rms_norm, r.max_rel_error);
    std::cout << line << "  rows by the highest level a texel of theirs took (level:rows, this run):" << hist << "\n";
    if (!r.tolerance_reachable) {
      std::snprintf(line, sizeof line,
                    "  the tolerance is out of reach: at --max-levels %u the pilot predicts %.3g%% at best, so the "
                    "levels went as far as brings it within 5%% of that; for %.3g%%, raise --max-levels or --spp\n",
                    options_.max_levels, 100 * r.least_error, 100 * *options_.tolerance);
      std::cout << line;
    }
  }

  static void PrintSparseAuto(const stages::SparseAuto& a) {
    char line[160];
    std::snprintf(line, sizeof line, "  --sparse auto: %s bake%s; pilot of %llu rows (+%llu dense) in %.2f s\n",
                  a.sparse ? "a sparse" : "the full",
                  a.resumed ? " (the decision of the run that started this output)" : "",
                  static_cast<unsigned long long>(a.pilot_rows), static_cast<unsigned long long>(a.pilot_dense_rows),
                  a.pilot_seconds);
    std::cout << line << "    why: " << a.reason << "\n";
  }

  static void PrintSparse(const stages::SparseStats& s) {
    char line[512];
    std::snprintf(
        line, sizeof line,
        "  sparse: %llu dense rows in %llu rounds, %llu sparse rows (%llu traced like dense rows); radius "
        "%.4g, %u features\n  traced %.2f%% of the entries (phase 1 %.2f%%, phase 2 %.2f%%); rays %llu + %llu\n"
        "  this run: phase 1 %llu rays in %.2f s, phase 2 %llu rays in %.2f s\n",
        static_cast<unsigned long long>(s.dense_rows), static_cast<unsigned long long>(s.iterations),
        static_cast<unsigned long long>(s.sparse_rows), static_cast<unsigned long long>(s.fallback_rows), s.radius,
        s.features, 100 * s.traced_fraction(), s.entries_total ? 100.0 * s.entries_traced[0] / s.entries_total : 0.0,
        s.entries_total ? 100.0 * s.entries_traced[1] / s.entries_total : 0.0,
        static_cast<unsigned long long>(s.total_rays[0]), static_cast<unsigned long long>(s.total_rays[1]),
        static_cast<unsigned long long>(s.rays[0]), s.seconds[0], static_cast<unsigned long long>(s.rays[1]),
        s.seconds[1]);
    std::cout << line;
  }

  stages::SampleOptions options_;
  std::optional<double> radius_;
  std::string tolerance_;
  bool json_ = false;
  std::optional<long long> features_;
  std::string row_filter_;
  std::string channels_ = "mono", channel_;
  std::string sparse_mode_;
  CLI::Option* sparse_opt_ = nullptr;
  std::optional<double> sparse_margin_;
  long long factor_term_ = -1;
  std::string factor_grid_ = "96,32", factor_text_;
  std::optional<sample::FactorChoice> factor_choice_;
  long long cube_res_ = -1, spp_ = -1, bounces_ = -1, seed_ = -1;
  CommonFlags flags_;
  ShardFlags shard_flags_;
};

}  // namespace

std::unique_ptr<Command> RegisterSample(CLI::App* parent) { return std::make_unique<SampleCommand>(parent); }

}  // namespace ltb::cli
