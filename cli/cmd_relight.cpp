// ltbake relight MATRIX --env ENV -o IMAGE [--terms N] [--weighting area|transport|none]
//                      [--reference RAW.ltm] [--frames N] [--rotate DEG] [--json]
#include <algorithm>
#include <chrono>
#include <cmath>
#include <iomanip>
#include <iostream>
#include <limits>
#include <numbers>

#include <nlohmann/json.hpp>

#include "cli/commands.h"
#include "cli/common.h"
#include "format/io/container_reader.h"
#include "stages/common/basis.h"
#include "stages/cpca/cpca_model.h"
#include "stages/relight/envmap.h"
#include "stages/relight/image_io.h"
#include "stages/relight/relight.h"

namespace ltb::cli {
namespace {

using Clock = std::chrono::steady_clock;
double Ms(Clock::time_point a, Clock::time_point b) { return std::chrono::duration<double, std::milli>(b - a).count(); }

// The lighting: a resampled environment map (rotatable) or a ready cubemap from .npy.
class Environment {
 public:
  static Result<Environment> Open(const std::string& path, uint64_t cube_res, const stages::EnvLoadOptions& o) {
    Environment e;
    e.cube_res_ = cube_res;
    if (path.ends_with(".npy")) {
      LTB_ASSIGN_OR_RETURN(std::vector<float> m, stages::ReadCubemapNpy(path, cube_res));
      e.fixed_ = std::move(m);
      return e;
    }
    LTB_ASSIGN_OR_RETURN(stages::EnvMap map, stages::LoadEnvMap(path, o));
    e.clamped_ = map.clamped;
    LTB_ASSIGN_OR_RETURN(stages::CubemapResampler r, stages::CubemapResampler::Create(map, cube_res, o.progress));
    e.resampler_ = std::make_unique<stages::CubemapResampler>(std::move(r));
    return e;
  }
  // 6R² × 3 radiance for a rotation about +Z (a .npy cubemap cannot rotate).
  void Cubemap(double rotation, std::vector<float>* out) const {
    out->resize(6 * cube_res_ * cube_res_ * 3);
    if (resampler_) {
      resampler_->Resample(rotation, out->data());
    } else {
      std::copy(fixed_.begin(), fixed_.end(), out->begin());
    }
  }
  bool rotates() const { return resampler_ != nullptr; }
  uint64_t clamped() const { return clamped_; }

 private:
  uint64_t cube_res_ = 0;
  std::vector<float> fixed_;
  std::unique_ptr<stages::CubemapResampler> resampler_;
  uint64_t clamped_ = 0;
};

class RelightCommand : public Command {
 public:
  explicit RelightCommand(CLI::App* parent) {
    auto* app = parent->add_subcommand("relight", "relight a baked matrix under an environment map (Eq. 8 for final.ltm)");
    app->add_option("MATRIX", matrix_, "final.ltm or cols4d.ltm (fast, in memory); cpca.ltm (in memory); cols.ltm; "
                                       "rows.ltm / raw.ltm (streamed)")->required();
    app->add_option("--env", env_, "environment map: .exr or .hdr (lat-long, cross, or six files with {face}), or a "
                                   "6R²×3 cubemap .npy")->required();
    app->add_option("-o,--output", output_, "relit image: .exr (linear), .png (sRGB), .npy (rows × 3)")->required();
    app->add_option("--terms", terms_text_,
                    "lighting terms kept, N >= 1 or all (non-linear approximation: the N largest coefficients of "
                    "the map in the matrix's lighting basis; for a pixel-basis matrix, the N brightest texels)")
        ->default_val("100")
        ->check(TermsCheck());
    app->add_option("--weighting", weighting_, "rank lighting terms by area (magnitude × support area), transport "
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
    auto weighting = stages::ParseWeighting(weighting_);
    // "all": every nonzero coefficient (SelectTerms keeps min(N, nonzeros)).
    terms_ = terms_text_ == "all" ? std::numeric_limits<uint64_t>::max() : std::stoull(terms_text_);
    auto mem = stages::ParseByteSize(flags_.mem_limit);
    if (!mem.ok()) return ReportUsage(mem.status().WithContext("--mem-limit"));
    ProgressBar bar(flags_, "relight");
    stages::EnvLoadOptions eo;
    eo.clamp = clamp_;
    eo.layout = *stages::ParseEnvLayout(layout_);  // checked by IsMember
    eo.max_bytes = *mem;  // the map's pixels (and an .hdr's bytes) within --mem-limit
    eo.progress = bar.hook();
    const nlohmann::json terms_json = terms_text_ == "all" ? nlohmann::json("all") : nlohmann::json(terms_);
    nlohmann::json report = {{"matrix", matrix_}, {"env", env_}, {"terms", terms_json}, {"weighting", weighting_}};

    auto t0 = Clock::now();
    auto reader = io::ContainerReader::Open(matrix_);
    if (!reader.ok()) return ReportFailure(reader.status());
    auto basis = stages::LightingBasis::FromMetadata(reader->metadata(), matrix_);
    if (!basis.ok()) return ReportFailure(basis.status());
    const bool is_cpca = stages::CpcaModel::IsCpca(reader->metadata());
    const bool streaming = !is_cpca && reader->metadata().matrix().layout == format::Layout::kRows;
    uint64_t rows = reader->metadata().matrix().rows;
    std::optional<stages::Relighter> relighter;
    std::optional<stages::CpcaRelighter> cpca;
    if (is_cpca) {  // clustered PCA: project the lighting per cluster, blend per row
      auto r = stages::CpcaRelighter::Load(matrix_, *mem);
      if (!r.ok()) return ReportFailure(r.status());
      cpca = std::move(*r);
      rows = cpca->rows();
      report["cpca"] = {{"clusters", cpca->model().clusters()}, {"basis", cpca->model().basis()}};
      report["matrix_bytes_in_memory"] = cpca->bytes();
    } else if (!streaming) {
      auto r = stages::Relighter::Load(matrix_, *mem, bar.hook());
      if (!r.ok()) return ReportFailure(r.status());
      relighter = std::move(*r);
      report["nonzeros"] = relighter->nonzeros();
      report["matrix_bytes_in_memory"] = relighter->bytes();
    }
    // Rows that see no geometry are black in every output (stages::FinishRelitImage).
    auto mask = stages::ReadRowMask(*reader);
    if (!mask.ok()) return ReportFailure(mask.status());
    stages::OutputFixes fixes;
    auto finish = [&](std::vector<float>* img) { fixes = stages::FinishRelitImage(*mask, keep_negative_, img); };
    auto t1 = Clock::now();
    auto env = Environment::Open(env_, basis->cube_res(), eo);
    if (!env.ok()) return ReportFailure(env.status());
    auto t2 = Clock::now();
    report["load_matrix_ms"] = Ms(t0, t1);
    report["load_env_ms"] = Ms(t1, t2);
    if (env->clamped()) report["clamped_values"] = env->clamped();

    uint64_t width = 0, height = 0;
    if (relighter) {
      width = relighter->image_width();
      height = relighter->image_height();
    } else if (cpca) {
      if (auto img = cpca->model().image()) {
        width = img->first;
        height = img->second;
      }
    } else if (auto img = stages::ReadImageRows(reader->metadata())) {
      width = img->width;
      height = img->height;
    }
    const std::vector<double> no_norms;
    const std::vector<double>& norms = relighter ? relighter->column_norms() : no_norms;
    const double rotation = rotate_deg_ * std::numbers::pi / 180.0;

    // One frame: resample, transform, select, relight.
    std::vector<float> cube, image(rows * 3);
    stages::LightTerms terms;
    auto frame = [&](double rot, double* lighting_ms, double* relight_ms) -> Status {
      auto a = Clock::now();
      env->Cubemap(rot, &cube);
      basis->ToBasis(cube.data());
      LTB_RETURN_IF_ERROR(basis->SelectTerms(cube.data(), terms_, *weighting, norms, &terms));
      auto b = Clock::now();
      if (relighter) {
        relighter->Relight(terms, image.data());
      } else if (cpca) {
        cpca->RelightTerms(terms.column, terms.rgb, image.data());
      } else {
        std::vector<float> dense(cube.size(), 0.0f);
        for (size_t k = 0; k < terms.column.size(); ++k)
          for (int c = 0; c < 3; ++c) dense[terms.column[k] * 3 + c] = terms.rgb[k * 3 + c];
        LTB_ASSIGN_OR_RETURN(image, stages::RelightStreaming(matrix_, dense.data(), flags_.jobs, bar.hook()));
      }
      finish(&image);
      auto c = Clock::now();
      if (lighting_ms) *lighting_ms = Ms(a, b);
      if (relight_ms) *relight_ms = Ms(b, c);
      return Status::Ok();
    };
    double lighting_ms = 0, relight_ms = 0;
    Status s = frame(rotation, &lighting_ms, &relight_ms);
    if (!s.ok()) return ReportFailure(s);
    report["lighting_ms"] = lighting_ms;
    report["relight_ms"] = relight_ms;
    report["terms_used"] = terms.column.size();
    // What a term is in this matrix's column basis, and how much of the map it keeps.
    {
      double total = 0, kept = 0;  // `cube` holds the first frame's lighting in the basis
      for (float v : cube) total += static_cast<double>(v) * v;
      for (float v : terms.rgb) kept += static_cast<double>(v) * v;
      report["terms_basis"] = basis->wavelet() ? "wavelet " + std::string(wavelet::FilterName(basis->filter())) : "pixels";
      report["terms_available"] = cube.size() / 3;
      report["lighting_energy_kept"] = total > 0 ? kept / total : 1.0;
    }
    report["output"] = {{"masked_rows", fixes.masked_rows}, {"clamped_values", nullptr}};
    if (!keep_negative_) report["output"]["clamped_values"] = fixes.clamped_values;
    s = stages::WriteImage(output_, image.data(), rows, width, height, {.exposure = exposure_});
    if (!s.ok()) return ReportFailure(s);
    std::vector<float> first = image;
    stages::LightTerms first_terms = terms;

    if (frames_ > 0) {
      std::vector<double> ms;
      for (int f = 0; f < frames_; ++f) {
        // The timing loop runs until done or interrupted (SIGINT/SIGTERM: exit 130/143; the
        // image above is already written).
        if (ReceivedSignal() != 0) {
          return ReportFailure(Cancelled("relight: interrupted after " + std::to_string(f) + " of " +
                                         std::to_string(frames_) + " timing frames; " + output_ +
                                         " was written before them"));
        }
        auto a = Clock::now();
        s = frame(rotation + 2 * std::numbers::pi * f / frames_, nullptr, nullptr);
        if (!s.ok()) return ReportFailure(s);
        ms.push_back(Ms(a, Clock::now()));
      }
      std::sort(ms.begin(), ms.end());
      double median = ms[ms.size() / 2];
      report["frames"] = {{"count", frames_},
                          {"median_ms", median},
                          {"fps", 1000.0 / median},
                          {"min_ms", ms.front()},
                          {"max_ms", ms.back()},
                          {"rotates", env->rotates()}};
    }

    if (!reference_.empty()) {
      auto ref_reader = io::ContainerReader::Open(reference_);
      if (!ref_reader.ok()) return ReportFailure(ref_reader.status());
      auto ref_basis = stages::LightingBasis::FromMetadata(ref_reader->metadata(), reference_);
      if (!ref_basis.ok()) return ReportFailure(ref_basis.status());
      if (ref_basis->cube_res() != basis->cube_res() || ref_reader->metadata().matrix().rows != rows) {
        return ReportFailure(InvalidArgument(reference_ + ": is not the same bake as " + matrix_ + " (shape or R differ)"));
      }
      // Exact: the full lighting in the reference's basis.
      std::vector<float> full;
      env->Cubemap(rotation, &full);
      std::vector<float> full_ref = full;
      ref_basis->ToBasis(full_ref.data());
      auto exact = stages::RelightStreaming(reference_, full_ref.data(), flags_.jobs, bar.hook());
      if (!exact.ok()) return ReportFailure(exact.status());
      finish(&*exact);  // T·L ≥ 0: clamps f32 rounding at most
      // Lighting alone: the kept terms, back in pixels, then into the reference's basis.
      std::vector<float> approx(full.size(), 0.0f);
      for (size_t k = 0; k < first_terms.column.size(); ++k)
        for (int c = 0; c < 3; ++c) approx[first_terms.column[k] * 3 + c] = first_terms.rgb[k * 3 + c];
      basis->ToPixels(approx.data());
      ref_basis->ToBasis(approx.data());
      auto light_only = stages::RelightStreaming(reference_, approx.data(), flags_.jobs, bar.hook());
      if (!light_only.ok()) return ReportFailure(light_only.status());
      finish(&*light_only);
      auto metrics = [&](const std::vector<float>& img) {
        auto e = stages::CompareImages(img.data(), exact->data(), rows, width, height);
        nlohmann::json j = {{"rel_l2", e.rel_l2}, {"psnr_db", e.psnr}};
        if (e.rel_h1 >= 0) j["rel_h1"] = e.rel_h1;
        return j;
      };
      report["error"] = metrics(first);
      report["error_lighting_only"] = metrics(*light_only);
      // Matrix alone: every lighting term through the compressed matrix.
      std::vector<float> all = full;
      basis->ToBasis(all.data());
      stages::LightTerms every;
      s = basis->SelectTerms(all.data(), all.size() / 3, stages::Weighting::kNone, norms, &every);
      if (!s.ok()) return ReportFailure(s);
      std::vector<float> matrix_only(rows * 3);
      if (relighter) {
        relighter->Relight(every, matrix_only.data());
      } else if (cpca) {
        cpca->Relight(all.data(), matrix_only.data());
      } else {
        auto m = stages::RelightStreaming(matrix_, all.data(), flags_.jobs, bar.hook());
        if (!m.ok()) return ReportFailure(m.status());
        matrix_only = std::move(*m);
      }
      finish(&matrix_only);
      report["error_matrix_only"] = metrics(matrix_only);
    }
    bar.Done();
    if (json_) {
      std::cout << report.dump(2) << "\n";
    } else if (!flags_.quiet) {
      const bool pixels = report["terms_basis"] == "pixels";
      const uint64_t available = report["terms_available"];
      std::cout << "wrote " << output_ << ": " << terms.column.size() << " of " << available << " lighting terms ("
                << (pixels ? "texels" : "wavelet coefficients, " + report["terms_basis"].get<std::string>().substr(8))
                << ", " << weighting_ << " weighting; " << std::setprecision(3)
                << 100 * report["lighting_energy_kept"].get<double>() << "% of the map's energy); lighting "
                << lighting_ms << " ms, relight " << relight_ms << " ms";
      if (report.contains("frames")) {
        std::cout << "; " << frames_ << " frames: median " << report["frames"]["median_ms"].get<double>() << " ms ("
                  << report["frames"]["fps"].get<double>() << " fps)";
      }
      std::cout << "\n";
      if (pixels && terms.column.size() < available) {
        std::cout << "  note: " << matrix_ << " has pixel-basis columns, so a term is one texel and "
                  << terms.column.size() << " texels keep only part of the light; relight a row-transformed bake "
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
  uint64_t terms_ = 100;
  int frames_ = 0;
  double rotate_deg_ = 0, exposure_ = 0;
  bool clamp_ = false, json_ = false, keep_negative_ = false;
  CommonFlags flags_;
};

}  // namespace

std::unique_ptr<Command> RegisterRelight(CLI::App* parent) { return std::make_unique<RelightCommand>(parent); }

}  // namespace ltb::cli
