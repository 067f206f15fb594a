// ltbake relight MATRIX --env ENV -o IMAGE [--terms N] [--weighting area|transport|none]
//                      [--reference RAW.ltm] [--frames N] [--rotate DEG] [--json]
// ltbake relight VIS.ltm --material MAT.ltm... --eye X,Y,Z --env ENV -o IMAGE [--method M]
//                      (the triple-product path, docs/TRIPLE.md)
#include <cctype>
#include <cmath>
#include <cstdio>
#include <glm/vec3.hpp>
#include <iomanip>
#include <iostream>
#include <limits>
#include <nlohmann/json.hpp>
#include <sstream>
#include <string>
#include <tuple>
#include <vector>

#include "cli/commands.h"
#include "cli/common.h"
#include "format/json_text.h"
#include "stages/common/quantity.h"
#include "stages/images/envmap.h"
#include "stages/images/image_io.h"
#include "stages/relight/glossy_view.h"
#include "stages/relight/relight.h"
#include "stages/relight/run_relight.h"
#include "stages/relight/run_sequence.h"
#include "stages/triple/render.h"

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
                    "the map in the matrix's lighting basis; for a pixel-basis matrix, the N brightest texels); "
                    "a vertex bake seen from --eye and the triple-product path take every term unless this is given")
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
    app->add_option("--rotate", rotate_text_,
                    "rotate the environment about +Z by this many degrees (within ±1e6; an .exr or .hdr map)")
        ->default_val("0")
        ->check(DecimalCheck(-stages::RelightOptions::kMaxRotateDegrees, stages::RelightOptions::kMaxRotateDegrees));
    app->add_option("--light-turn", light_turn_text_,
                    "triple-product path, with --orbit DEG:FRAMES: the map turns this many more degrees about +Z "
                    "every frame (light and view changing together; --orbit 0:FRAMES keeps the eye)")
        ->check(DecimalCheck(-360, 360));
    app->add_option("--env-layout", layout_, "auto, latlong, hcross, vcross, faces or angular (light probe)")
        ->default_val("auto")
        ->check(CLI::IsMember({"auto", "latlong", "hcross", "vcross", "faces", "angular"}));
    app->add_flag("--clamp", clamp_, "clamp negative, NaN and infinite radiance to valid values (counted)");
    app->add_flag("--no-clamp-output", keep_negative_,
                  "keep negative radiance in the relit image (by default clamped to 0: compression ringing)");
    app->add_option("--exposure", exposure_text_, "PNG exposure, 0..1e12 (0: automatic)")
        ->default_val("0")
        ->check(DecimalCheck(0, stages::kMaxExposure));
    app->add_flag("--json", json_, "print timings and metrics as JSON");
    // The triple-product path (MATRIX is a visibility field, sample --visibility).
    app->add_option("--material", materials_,
                    "triple-product path: a material field (ltbake material); one Lambert field and one Phong field "
                    "per exponent the scene's materials use (repeat the flag)");
    app->add_option("--eye", eye_,
                    "a factored bake (sample --factor) or the triple-product path: the camera position X,Y,Z");
    app->add_option("--target", target_, "triple-product path: the point looked at X,Y,Z")->default_val("0,0,0");
    app->add_option("--up", up_, "triple-product path: the camera's up X,Y,Z")->default_val("0,0,1");
    app->add_option("--fov", fov_text_, "triple-product path: vertical field of view in degrees, in (0, 180)")
        ->default_val("40")
        ->check(DecimalCheck(0, 180));
    app->add_option("--size", size_, "triple-product path: image WIDTHxHEIGHT")->default_val("256x256");
    app->add_option(
           "--method", method_,
           "with --sequence: nwa (each frame on its own), bi (basic incremental) or pbi (per-band "
           "incremental, the default). Triple-product path: shared (the default: each sampled BRDF row lit once "
           "a frame and shared by the vertices that use it; linear's result at any terms), sublinear (the "
           "kept terms only, per vertex), linear (every coefficient, per vertex) or pixel (the exact "
           "pixel-basis reference; --terms keeps the brightest texels)")
        ->check(CLI::IsMember({"nwa", "bi", "pbi", "sublinear", "linear", "shared", "pixel"}));
    app->add_option("--sequence", sequence_,
                    "a lighting sequence, comma-separated segments played in order: rotate:DEG_PER_FRAME:FRAMES "
                    "(about +Z), hold:FRAMES, maps:A.exr+B.hdr+... (one map a frame), fade:A.exr+B.exr:FRAMES; -o is "
                    "then a pattern with one %04d, or an .mp4 (docs/SEQUENCE.md)");
    app->add_option("--csv", csv_, "with --sequence: the per-frame table (time, terms per band, errors) as CSV");
    app->add_option("--applied-lighting", applied_,
                    "with --sequence: a pattern like -o's (.npy) for each frame's applied lighting (6R² x 3, in the "
                    "matrix's column basis)");
    app->add_option("--fps", fps_text_, "with --sequence and an .mp4 output: frames per second, in (0, 1000]")
        ->default_val("25")
        ->check(DecimalCheck(0, 1000));
    app->add_option("--brdf-terms", brdf_terms_text_,
                    "triple-product path: wavelet terms kept of each sampled BRDF row (largest first), N or all")
        ->default_val("all")
        ->check(TermsCheck());
    app->add_option("--orbit", orbit_,
                    "triple-product path: DEG:FRAMES, the eye turning DEG a frame about +Z through the target; -o is "
                    "then a pattern with one %d");
    app->add_option("--scene", scene_, "triple-product path: the scene, when not where the visibility field says");
    app->add_option("--vertex-output", vertex_output_,
                    "triple-product path: every vertex's radiance (rows x 3 .npy), from the first eye");
    AddCommonFlags(app, &flags_);
    app_ = app;
  }

  // A flag's value that DecimalCheck passed, read by the same parser.
  static double Decimal(const std::string& text) {
    return *stages::ParseDecimal(text, -std::numeric_limits<double>::max(), std::numeric_limits<double>::max());
  }

  bool Triple() const { return !materials_.empty() || (!method_.empty() && triple::ParseTripleMethod(method_).ok()); }

  // --eye, --target, --up, --size and --orbit of a view (the triple-product path, a
  // factored bake): kExitOk, or the usage error's code.
  int ParseView(glm::dvec3* eye, glm::dvec3* target, glm::dvec3* up, uint32_t* width, uint32_t* height,
                double* orbit_deg, uint32_t* orbit_frames) {
    for (auto [text, dst, name] :
         {std::tuple{&eye_, eye, "--eye"}, std::tuple{&target_, target, "--target"}, std::tuple{&up_, up, "--up"}}) {
      if (!ParseVec3(*text, dst))
        return ReportUsage(InvalidArgument(std::string(name) + " " + *text + ": expected X,Y,Z"));
    }
    if (!ParseViewSize(size_, width, height)) {
      return ReportUsage(InvalidArgument("--size " + size_ + ": expected WIDTHxHEIGHT, each 1..16384, e.g. 512x384"));
    }
    char tail = 0;
    if (!orbit_.empty()) {
      const size_t colon = orbit_.find(':');
      auto deg = stages::ParseDecimal(orbit_.substr(0, colon), -360, 360);
      unsigned n = 0;
      if (colon == std::string::npos || !deg.ok() || std::sscanf(orbit_.c_str() + colon + 1, "%u%c", &n, &tail) != 1 ||
          n == 0 || !std::isdigit(static_cast<unsigned char>(orbit_[colon + 1]))) {
        return ReportUsage(
            InvalidArgument("--orbit " + orbit_ + ": expected DEG:FRAMES, DEG in [-360, 360], e.g. 10:36"));
      }
      *orbit_deg = *deg;
      *orbit_frames = n;
    }
    return kExitOk;
  }

  // The map and output options a view shares (triple::RenderOptions, stages::GlossyViewOptions).
  template <typename ViewOptions>
  void FillViewOptions(ViewOptions* o) const {
    o->env = env_;
    o->env_layout = *stages::ParseEnvLayout(layout_);  // checked by IsMember
    o->clamp_env = clamp_;
    o->rotate_deg = Decimal(rotate_text_);
    o->output = output_;
    o->vertex_output = vertex_output_;
    o->exposure = Decimal(exposure_text_);
    o->fov_degrees = Decimal(fov_text_);
  }

  int RunTriple() {
    triple::RenderOptions o;
    o.visibility = matrix_;
    o.materials = materials_;
    o.scene = scene_;
    FillViewOptions(&o);
    if (!sequence_.empty()) {
      return ReportUsage(InvalidArgument("--sequence belongs to the matrix path, not the triple-product one"));
    }
    if (method_.empty()) method_ = "shared";
    auto method = triple::ParseTripleMethod(method_);
    if (!method.ok()) {
      return ReportUsage(
          InvalidArgument("--method " + method_ +
                          ": the triple-product path takes shared, sublinear, linear or pixel (nwa, bi and pbi "
                          "are for --sequence)"));
    }
    o.method = *method;
    if (!light_turn_text_.empty()) o.light_turn_deg = Decimal(light_turn_text_);
    o.light_terms =
        terms_text_ == "all" || app_->count("--terms") == 0 ? triple::RenderOptions::kAll : std::stoull(terms_text_);
    o.brdf_terms = brdf_terms_text_ == "all" ? triple::RenderOptions::kAll : std::stoull(brdf_terms_text_);
    if (eye_.empty())
      return ReportUsage(InvalidArgument("the triple-product path (--material, --method) needs --eye X,Y,Z"));
    if (int code = ParseView(&o.eye, &o.target, &o.up, &o.width, &o.height, &o.orbit_deg, &o.orbit_frames);
        code != kExitOk) {
      return code;
    }
    if (frames_ > 0 || !reference_.empty() || weighting_ != "area") {
      return ReportUsage(InvalidArgument(
          "--frames, --reference and --weighting belong to the matrix path, not the triple-product one"));
    }
    StageFlags sf;
    if (int code = ResolveStageFlags(flags_, nullptr, &sf); code != kExitOk) return code;
    o.mem_limit = sf.mem_limit;
    o.jobs = sf.jobs;
    return Report([&](const Progress& p) { return triple::RunTripleRender(o, p); },
                  [&](const nlohmann::json& report) {
                    const nlohmann::json& f = report["frames"];
                    std::cout << "wrote " << output_;
                    if (!f.empty()) {
                      std::cout << " (" << f.size() << (f.size() == 1 ? " frame" : " frames") << "): " << method_
                                << ", " << report["light_terms_used"].get<uint64_t>()
                                << " lighting terms; frame 0: " << f[0]["visible_vertices"].get<uint64_t>()
                                << " visible vertices relit in " << std::setprecision(3)
                                << f[0]["relight_ms"].get<double>() << " ms";
                    }
                    std::cout << "\n";
                  });
  }

  // A factored bake from a view (sample --factor K; docs/GLOSSY.md).
  int RunGlossy() {
    stages::GlossyViewOptions o;
    o.set = matrix_;
    FillViewOptions(&o);
    // Every lighting term unless --terms says otherwise: the K terms are relit once per map,
    // so the exact product costs one relight, and a cut lighting is the view's largest error
    // (30–61% at 100 texels of a pixel-basis set, docs/GLOSSY.md).
    o.terms = terms_text_ == "all" || app_->count("--terms") == 0 ? stages::GlossyViewOptions::kAll
                                                                  : std::stoull(terms_text_);
    o.use_terms = brdf_terms_text_ == "all"
                      ? 0
                      : static_cast<uint32_t>(std::min<unsigned long long>(std::stoull(brdf_terms_text_), 64));
    if (!sequence_.empty() || frames_ > 0 || !reference_.empty() || weighting_ != "area" || !method_.empty()) {
      return ReportUsage(InvalidArgument(
          "--sequence, --frames, --reference, --weighting and --method are not for a view of a factored bake"));
    }
    if (int code = ParseView(&o.eye, &o.target, &o.up, &o.width, &o.height, &o.orbit_deg, &o.orbit_frames);
        code != kExitOk) {
      return code;
    }
    StageFlags sf;
    if (int code = ResolveStageFlags(flags_, nullptr, &sf); code != kExitOk) return code;
    o.mem_limit = sf.mem_limit;
    o.jobs = sf.jobs;
    return Report([&](const Progress& p) { return stages::RunGlossyView(o, p); },
                  [&](const nlohmann::json& report) {
                    const nlohmann::json& f = report["frames"];
                    const nlohmann::json& lt = report["lighting_terms"];
                    const uint64_t used = lt["used"], available = lt["available"];
                    std::ostringstream lighting;
                    if (used >= available) {
                      lighting << "every lighting term (" << available << ")";
                    } else {  // a cut lighting says what it dropped
                      lighting << used << " of " << available << " lighting terms ("
                               << (lt["basis"] == "pixels" ? "the brightest texels" : "the largest coefficients")
                               << ", " << std::setprecision(3) << 100 * lt["energy_kept"].get<double>()
                               << "% of the map's energy; --terms all for every one)";
                    }
                    std::cout << "wrote " << output_ << " (" << f["count"].get<uint64_t>()
                              << " view(s)): " << lighting.str() << ", " << report["terms_used"].get<uint64_t>()
                              << " of " << report["terms_in_bake"].get<uint64_t>() << " BRDF terms, "
                              << report["vertices"].get<uint64_t>() << " vertices; relit in " << std::setprecision(3)
                              << report["relight_ms"].get<double>() << " ms, then " << f["median_ms"].get<double>()
                              << " ms a view (median)\n";
                  });
  }

  int Run() override {
    if (!light_turn_text_.empty() && !Triple()) {
      return ReportUsage(InvalidArgument(
          "--light-turn belongs to the triple-product path (--material ...; docs/TRIPLE.md); a matrix's lighting "
          "sequence is --sequence rotate:DEG:FRAMES"));
    }
    if (!eye_.empty() && materials_.empty() && !Triple()) return RunGlossy();
    if (Triple()) return RunTriple();
    if (!sequence_.empty()) return RunSequence();
    if (!method_.empty() || !csv_.empty() || !applied_.empty()) {
      return ReportUsage(InvalidArgument(
          "--method, --csv and --applied-lighting belong to lighting sequences: add --sequence (docs/SEQUENCE.md)"));
    }
    stages::RelightOptions o;
    if (int code = FillOptions(&o); code != kExitOk) return code;
    return Report(
        [&](const Progress& p) { return stages::RunRelight(o, p); },
        [&](const nlohmann::json& report) {
          const uint64_t terms_used = report["terms_used"];
          const bool pixels = report["terms_basis"] == "pixels";
          const uint64_t available = report["terms_available"];
          std::cout << "wrote " << output_ << ": " << terms_used << " of " << available << " lighting terms ("
                    << (pixels ? "texels"
                               : "wavelet coefficients, " + report["terms_basis"].get<std::string>().substr(8))
                    << ", " << weighting_ << " weighting; " << std::setprecision(3)
                    << 100 * report["lighting_energy_kept"].get<double>() << "% of the map's energy); lighting "
                    << report["lighting_ms"].get<double>() << " ms, relight " << report["relight_ms"].get<double>()
                    << " ms";
          if (report.contains("frames")) {
            std::cout << "; " << frames_ << " frames: median " << report["frames"]["median_ms"].get<double>() << " ms ("
                      << report["frames"]["fps"].get<double>() << " fps)";
            if (report["frames"].contains("roofline")) {
              const nlohmann::json& r = report["frames"]["roofline"];
              std::cout << "; the matrix product " << r["product_median_ms"].get<double>() << " ms for "
                        << r["coefficient_bytes"].get<double>() / 1e6 << " MB of coefficients, "
                        << 100 * r["fraction_of_bound"].get<double>() << "% of the copy-bandwidth bound ("
                        << r["copy_bytes_per_s"].get<double>() / 1e9 << " GB/s)";
            }
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
        });
  }

  // The matrix path's options from the flags (kExitOk, or the usage error's code).
  int FillOptions(stages::RelightOptions* o) {
    o->matrix = matrix_;
    o->env = env_;
    o->output = output_;
    o->reference = reference_;
    o->weighting = *stages::ParseWeighting(weighting_);  // checked by IsMember
    // "all": every nonzero coefficient (SelectTerms keeps min(N, nonzeros)).
    o->terms = terms_text_ == "all" ? stages::RelightOptions::kAllTerms : std::stoull(terms_text_);
    o->frames = frames_;
    o->rotate_deg = Decimal(rotate_text_);
    o->exposure = Decimal(exposure_text_);
    o->keep_negative = keep_negative_;
    o->clamp_env = clamp_;
    o->env_layout = *stages::ParseEnvLayout(layout_);  // checked by IsMember
    StageFlags sf;
    if (int code = ResolveStageFlags(flags_, nullptr, &sf); code != kExitOk) return code;
    o->mem_limit = sf.mem_limit;
    o->jobs = sf.jobs;
    return kExitOk;
  }

  int RunSequence() {
    stages::RelightOptions o;
    if (int code = FillOptions(&o); code != kExitOk) return code;
    stages::SequenceOptions so;
    so.spec = sequence_;
    so.method = *stages::ParseSequenceMethod(method_.empty() ? "pbi" : method_);  // checked by IsMember
    so.csv = csv_;
    so.fps = Decimal(fps_text_);
    so.applied_output = applied_;
    return Report([&](const Progress& p) { return stages::RunRelightSequence(o, so, p); },
                  [&](const nlohmann::json& report) {
                    const nlohmann::json& s = report["summary"];
                    std::cout << "wrote " << s["frames"].get<uint64_t>() << " frames to " << output_ << ": " << so.spec
                              << ", " << report["method"].get<std::string>() << " with " << terms_text_
                              << " terms a frame; median " << std::setprecision(3) << s["median_ms"].get<double>()
                              << " ms a frame";
                    if (s.contains("mean_rel_l2")) {
                      std::cout << "; against " << reference_ << ": mean rel. L2 " << s["mean_rel_l2"].get<double>()
                                << ", last frame " << s["final_rel_l2"].get<double>();
                    }
                    std::cout << "\n";
                  });
  }

  // Runs one relight path under a progress bar and prints its report: as JSON with --json,
  // else (unless --quiet) through `text`. The exit code.
  template <typename RunFn, typename TextFn>
  int Report(RunFn run, TextFn text) {
    ProgressBar bar(flags_, "relight");
    auto r = run(bar.hook());
    if (!r.ok()) return ReportFailure(r.status());
    bar.Done();
    if (json_) {
      std::cout << JsonText(r->report, 2) << "\n";
    } else if (!flags_.quiet) {
      text(r->report);
    }
    return kExitOk;
  }

 private:
  std::string matrix_, env_, output_, weighting_ = "area", reference_, layout_ = "auto";
  std::string terms_text_ = "100";
  std::vector<std::string> materials_;
  std::string eye_, target_ = "0,0,0", up_ = "0,0,1", size_ = "256x256", method_, sequence_, csv_, applied_,
                    brdf_terms_text_ = "all", orbit_, scene_, vertex_output_;
  std::string fov_text_ = "40", fps_text_ = "25";
  int frames_ = 0;
  std::string rotate_text_ = "0", exposure_text_ = "0", light_turn_text_;
  bool clamp_ = false, json_ = false, keep_negative_ = false;
  CommonFlags flags_;
  CLI::App* app_ = nullptr;
};

}  // namespace

std::unique_ptr<Command> RegisterRelight(CLI::App* parent) { return std::make_unique<RelightCommand>(parent); }

}  // namespace ltb::cli
