// ltbake relight MATRIX --env ENV -o IMAGE [--terms N] [--weighting area|transport|none]
//                      [--reference RAW.ltm] [--frames N] [--rotate DEG] [--json]
#include <iomanip>
#include <iostream>
#include <nlohmann/json.hpp>
#include <string>

#include "cli/commands.h"
#include "cli/common.h"
#include "stages/common/quantity.h"
#include "stages/relight/envmap.h"
#include "stages/relight/relight.h"
#include "stages/relight/run_relight.h"

namespace ltb::cli {
namespace {

class RelightCommand : public Command {
 public:
  explicit RelightCommand(CLI::App* parent) {
    auto* app =
        parent->add_subcommand("relight", "relight a baked matrix under an environment map (Eq. 8 for final.ltm)");
    app->add_option("MATRIX", matrix_,
                    "final.ltm or cols4d.ltm (fast, in memory); cpca.ltm (in memory); cols.ltm; "
                    "rows.ltm / raw.ltm (streamed)")
        ->required();
    app->add_option("--env", env_,
                    "environment map: .exr or .hdr (lat-long, cross, or six files with {face}), or a "
                    "6R²×3 cubemap .npy")
        ->required();
    app->add_option("-o,--output", output_, "relit image: .exr (linear), .png (sRGB), .npy (rows × 3)")->required();
    app->add_option("--terms", terms_text_,
                    "lighting terms kept, N >= 1 or all (non-linear approximation: the N largest coefficients of "
                    "the map in the matrix's lighting basis; for a pixel-basis matrix, the N brightest texels)")
        ->default_val("100")
        ->check(TermsCheck());
    app->add_option("--weighting", weighting_,
                    "rank lighting terms by area (magnitude × support area), transport "
                    "(× the column's norm) or none")
        ->default_val("area")
        ->check(CLI::IsMember({"area", "transport", "none"}));
    app->add_option("--reference", reference_, "uncompressed matrix (raw.ltm or rows.ltm) for error metrics");
    app->add_option("--frames", frames_, "time this many frames of the environment rotating once about +Z")
        ->default_val(0)
        ->check(CLI::Range(0, 1 << 20));
    app->add_option("--rotate", rotate_deg_, "rotate the environment about +Z by this many degrees")->default_val(0.0);
    app->add_option("--env-layout", layout_, "auto, latlong, hcross, vcross, faces or angular (light probe)")
        ->default_val("auto")
        ->check(CLI::IsMember({"auto", "latlong", "hcross", "vcross", "faces", "angular"}));
    app->add_flag("--clamp", clamp_, "clamp negative, NaN and infinite radiance to valid values (counted)");
    app->add_flag("--no-clamp-output", keep_negative_,
                  "keep negative radiance in the relit image (by default clamped to 0: compression ringing)");
    app->add_option("--exposure", exposure_, "PNG exposure (0: automatic)")->default_val(0.0);
    app->add_flag("--json", json_, "print timings and metrics as JSON");
    AddCommonFlags(app, &flags_);
  }

  int Run() override {
    stages::RelightOptions o;
    o.matrix = matrix_;
    o.env = env_;
    o.output = output_;
    o.reference = reference_;
    o.weighting = *stages::ParseWeighting(weighting_);  // checked by IsMember
    // "all": every nonzero coefficient (SelectTerms keeps min(N, nonzeros)).
    o.terms = terms_text_ == "all" ? stages::RelightOptions::kAllTerms : std::stoull(terms_text_);
    o.frames = frames_;
    o.rotate_deg = rotate_deg_;
    o.exposure = exposure_;
    o.keep_negative = keep_negative_;
    o.clamp_env = clamp_;
    o.env_layout = *stages::ParseEnvLayout(layout_);  // checked by IsMember
    StageFlags sf;
    if (int code = ResolveStageFlags(flags_, nullptr, &sf); code != kExitOk) return code;
    o.mem_limit = sf.mem_limit;
    o.jobs = sf.jobs;
    ProgressBar bar(flags_, "relight");
    auto r = stages::RunRelight(o, bar.hook());
    if (!r.ok()) return ReportFailure(r.status());
    const nlohmann::json& report = r->report;
    const uint64_t terms_used = report["terms_used"];
    bar.Done();
    if (json_) {
      std::cout << report.dump(2) << "\n";
    } else if (!flags_.quiet) {
      const bool pixels = report["terms_basis"] == "pixels";
      const uint64_t available = report["terms_available"];
      std::cout << "wrote " << output_ << ": " << terms_used << " of " << available << " lighting terms ("
                << (pixels ? "texels" : "wavelet coefficients, " + report["terms_basis"].get<std::string>().substr(8))
                << ", " << weighting_ << " weighting; " << std::setprecision(3)
                << 100 * report["lighting_energy_kept"].get<double>() << "% of the map's energy); lighting "
                << report["lighting_ms"].get<double>() << " ms, relight " << report["relight_ms"].get<double>()
                << " ms";
      if (report.contains("frames")) {
        std::cout << "; " << frames_ << " frames: median " << report["frames"]["median_ms"].get<double>() << " ms ("
                  << report["frames"]["fps"].get<double>() << " fps)";
      }
      std::cout << "\n";
      if (pixels && terms_used < available) {
        std::cout << "  note: " << matrix_ << " has pixel-basis columns, so a term is one texel and " << terms_used
                  << " texels keep only part of the light; relight a row-transformed bake "
                     "(rows.ltm, cols4d.ltm, final.ltm) for wavelet terms, or pass --terms all\n";
      }
      if (report.contains("error")) {
        auto line = [&](const char* what, const nlohmann::json& e) {
          std::cout << "  " << what << ": rel. L2 " << e["rel_l2"].get<double>();
          if (e.contains("rel_h1")) std::cout << ", rel. H1 " << e["rel_h1"].get<double>();
          std::cout << ", PSNR " << e["psnr_db"].get<double>() << " dB\n";
        };
        std::cout << "  against " << reference_ << " relit with every lighting term (the exact image):\n";
        line("  error of this image", report["error"]);
        line("    lighting approximation alone (these terms through the reference)", report["error_lighting_only"]);
        line("    matrix compression alone (every term through this matrix)", report["error_matrix_only"]);
      }
    }
    return kExitOk;
  }

 private:
  std::string matrix_, env_, output_, weighting_ = "area", reference_, layout_ = "auto";
  std::string terms_text_ = "100";
  int frames_ = 0;
  double rotate_deg_ = 0, exposure_ = 0;
  bool clamp_ = false, json_ = false, keep_negative_ = false;
  CommonFlags flags_;
};

}  // namespace

std::unique_ptr<Command> RegisterRelight(CLI::App* parent) { return std::make_unique<RelightCommand>(parent); }

}  // namespace ltb::cli
