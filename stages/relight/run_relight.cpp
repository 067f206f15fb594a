#include "stages/relight/run_relight.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <memory>
#include <numbers>
#include <optional>

#include "format/io/container_reader.h"
#include "stages/common/basis.h"
#include "stages/cpca/cpca_model.h"
#include "stages/images/environment.h"
#include "stages/images/image_io.h"
#include "stages/relight/relight_matrix.h"

namespace ltb::stages {
namespace {

using Clock = std::chrono::steady_clock;
double Ms(Clock::time_point a, Clock::time_point b) { return std::chrono::duration<double, std::milli>(b - a).count(); }

std::string Shortest(double v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%g", v);
  return buf;
}

// The frames relight renders, sharing their buffers: `cube` holds the last frame's
// lighting in the basis, `terms` its kept terms, `image` its output, `fixes` what the
// output policy changed in it.
struct Frames {
  Frames(const RelightOptions& o, const Environment& env, const LightingBasis& basis, RelightMatrix& m)
      : o(o), env(env), basis(basis), m(m), image(m.rows() * 3) {}

  // The column norms the transport weighting needs (in-memory matrices only).
  const std::vector<double>& norms() const { return m.column_norms(); }

  // The output policy (mask-0 rows black, negatives clamped unless kept).
  OutputFixes Finish(std::vector<float>* img) const { return FinishRelitImage(m.mask(), o.keep_negative, img); }

  // One frame: resample, transform, select, relight. A map near float32's largest value is
  // relit at 2^-exponent (LightingExponent) and the image scaled back; an image beyond
  // float32 is an error, never written.
  Status Render(double rot, double* lighting_ms, double* relight_ms) {
    auto a = Clock::now();
    LTB_RETURN_IF_ERROR(env.Cubemap(rot, &cube));
    exponent = LightingExponent(cube);
    ScaleByPowerOfTwo(&cube, -exponent);
    basis.ToBasis(cube.data());
    LTB_RETURN_IF_ERROR(basis.SelectTerms(cube.data(), o.terms, o.weighting, norms(), &terms));
    auto b = Clock::now();
    LTB_RETURN_IF_ERROR(m.Relight(terms, &image));
    product_ms = Ms(b, Clock::now());
    ScaleByPowerOfTwo(&image, exponent);
    fixes = Finish(&image);
    LTB_RETURN_IF_ERROR(CheckRelitImageFinite(image, m.width(), o.env));
    auto c = Clock::now();
    if (lighting_ms) *lighting_ms = Ms(a, b);
    if (relight_ms) *relight_ms = Ms(b, c);
    return Status::Ok();
  }

  const RelightOptions& o;
  const Environment& env;
  const LightingBasis& basis;
  RelightMatrix& m;
  std::vector<float> cube, image;  // `cube`: the lighting at 2^-exponent, in the basis
  LightTerms terms;                // at 2^-exponent
  OutputFixes fixes;
  int exponent = 0;
  double product_ms = 0;  // the last frame's m.Relight alone
};

// Bytes a memcpy moves per second between two buffers larger than the caches, the best of
// four (the pages touched first): the bandwidth the relight roofline is measured against.
constexpr size_t kCopyBytes = size_t{64} << 20;  // each buffer; the roofline needs --mem-limit >= 8x
double CopyBandwidth() {
  const size_t kBytes = kCopyBytes;
  std::vector<char> from(kBytes, 1), to(kBytes, 0);
  double best = 0;
  for (int k = 0; k < 4; ++k) {
    auto a = Clock::now();
    std::memcpy(to.data(), from.data(), kBytes);
    const double s = std::chrono::duration<double>(Clock::now() - a).count();
    if (s > 0) best = std::max(best, static_cast<double>(kBytes) / s);
    from[k] = to[kBytes - 1 - k];  // (keeps the copies from being elided)
  }
  return best;
}

// What a term is in this matrix's column basis, and how much of the map it keeps.
void ReportTerms(const LightingBasis& basis, const Frames& frames, nlohmann::json* report) {
  double total = 0, kept = 0;  // `cube` holds the first frame's lighting in the basis
  for (float v : frames.cube) total += static_cast<double>(v) * v;
  for (float v : frames.terms.rgb) kept += static_cast<double>(v) * v;
  (*report)["terms_basis"] = basis.wavelet() ? "wavelet " + std::string(wavelet::FilterName(basis.filter())) : "pixels";
  (*report)["terms_available"] = frames.cube.size() / 3;
  (*report)["lighting_energy_kept"] = total > 0 ? kept / total : 1.0;
}

// `o.frames` timing frames, the environment rotating once about +Z from `rotation`.
Status TimeFrames(const RelightOptions& o, const Environment& env, double rotation, const Progress& progress,
                  Frames* frames, nlohmann::json* report) {
  std::vector<double> ms, product_ms, coefficient_bytes;
  for (int f = 0; f < o.frames; ++f) {
    // The timing loop runs until done or interrupted; the image above is already written.
    if (progress.Cancelled()) {
      return Cancelled("relight: interrupted after " + std::to_string(f) + " of " + std::to_string(o.frames) +
                       " timing frames; " + o.output + " was written before them");
    }
    auto a = Clock::now();
    LTB_RETURN_IF_ERROR(frames->Render(rotation + 2 * std::numbers::pi * f / o.frames, nullptr, nullptr));
    ms.push_back(Ms(a, Clock::now()));
    product_ms.push_back(frames->product_ms);
    if (auto bytes = frames->m.CoefficientBytes(frames->terms))
      coefficient_bytes.push_back(static_cast<double>(*bytes));
  }
  auto median_of = [](std::vector<double> v) {
    std::sort(v.begin(), v.end());
    return v[v.size() / 2];
  };
  std::sort(ms.begin(), ms.end());
  double median = ms[ms.size() / 2];
  (*report)["frames"] = {{"count", o.frames},    {"median_ms", median}, {"fps", 1000.0 / median},
                         {"min_ms", ms.front()}, {"max_ms", ms.back()}, {"rotates", env.rotates()}};
  // The matrix product against the memory roofline: the kept coefficients' bytes a frame
  // reads, at the copy bandwidth of this process, against the product's median time. Not
  // under a --mem-limit too small for copy buffers beyond the caches (smaller ones would
  // measure the cache).
  if (coefficient_bytes.size() == ms.size() && o.mem_limit >= 8 * kCopyBytes) {
    const double bandwidth = CopyBandwidth(), bytes = median_of(coefficient_bytes);
    const double product = median_of(product_ms), bound_ms = bandwidth > 0 ? 1e3 * bytes / bandwidth : 0;
    (*report)["frames"]["roofline"] = {{"coefficient_bytes", bytes},
                                       {"copy_bytes_per_s", bandwidth},
                                       {"bound_ms", bound_ms},
                                       {"product_median_ms", product},
                                       {"fraction_of_bound", product > 0 ? bound_ms / product : 0.0}};
  }
  return Status::Ok();
}

// The errors of the written image (`first`, from `first_terms` at 2^-exponent) against the uncompressed
// reference matrix o.reference: in all, of the lighting approximation alone, and of the
// compressed matrix alone.
Status MeasureErrors(const RelightOptions& o, const Environment& env, const LightingBasis& basis, RelightMatrix& m,
                     const Frames& frames, const std::vector<float>& first, const LightTerms& first_terms, int exponent,
                     double rotation, const Progress& progress, nlohmann::json* report) {
  const uint64_t rows = m.rows();
  // The reference goes through RelightMatrix too (streamed from its row blocks), so a channel
  // set or a reflectance table is applied to it as to the matrix.
  LTB_ASSIGN_OR_RETURN(RelightMatrix ref, RelightMatrix::Open(o.reference, o.mem_limit, o.jobs, progress, nullptr));
  const LightingBasis& ref_basis = ref.basis();
  LTB_RETURN_IF_ERROR(CheckSameBake(ref, m));
  // Exact: the full lighting in the reference's basis. All at 2^-exponent, as `first_terms`
  // (the errors are relative), `first` too.
  std::vector<float> full;
  LTB_RETURN_IF_ERROR(env.Cubemap(rotation, &full));
  ScaleByPowerOfTwo(&full, -exponent);
  std::vector<float> first_scaled = first;
  ScaleByPowerOfTwo(&first_scaled, -exponent);
  std::vector<float> full_ref = full;
  ref_basis.ToBasis(full_ref.data());
  std::vector<float> exact;
  LTB_RETURN_IF_ERROR(ref.RelightDense(full_ref, &exact));
  frames.Finish(&exact);  // T·L ≥ 0: clamps f32 rounding at most
  // Lighting alone: the kept terms, back in pixels, then into the reference's basis.
  std::vector<float> approx(full.size(), 0.0f);
  for (size_t k = 0; k < first_terms.column.size(); ++k)
    for (int c = 0; c < 3; ++c) approx[first_terms.column[k] * 3 + c] = first_terms.rgb[k * 3 + c];
  basis.ToPixels(approx.data());
  ref_basis.ToBasis(approx.data());
  std::vector<float> light_only;
  LTB_RETURN_IF_ERROR(ref.RelightDense(approx, &light_only));
  frames.Finish(&light_only);
  auto metrics = [&](const std::vector<float>& img) {
    auto e = CompareImages(img.data(), exact.data(), rows, m.width(), m.height());
    nlohmann::json j = {{"rel_l2", e.rel_l2}, {"psnr_db", e.psnr}};
    if (e.rel_h1 >= 0) j["rel_h1"] = e.rel_h1;
    return j;
  };
  (*report)["error"] = metrics(first_scaled);
  (*report)["error_lighting_only"] = metrics(light_only);
  // Matrix alone: every lighting term through the compressed matrix.
  std::vector<float> all = full;
  basis.ToBasis(all.data());
  std::vector<float> matrix_only;
  LTB_RETURN_IF_ERROR(m.RelightDense(all, &matrix_only));
  frames.Finish(&matrix_only);
  (*report)["error_matrix_only"] = metrics(matrix_only);
  return Status::Ok();
}

}  // namespace

Status CheckRelightNumbers(const RelightOptions& o) {
  if (!(std::fabs(o.rotate_deg) <= RelightOptions::kMaxRotateDegrees)) {
    return InvalidArgument("--rotate " + Shortest(o.rotate_deg) + ": expected degrees within ±" +
                           Shortest(RelightOptions::kMaxRotateDegrees));
  }
  if (!(o.exposure >= 0 && o.exposure <= kMaxExposure)) {
    return InvalidArgument("--exposure " + Shortest(o.exposure) + ": expected 0 (automatic) .. " +
                           Shortest(kMaxExposure));
  }
  return Status::Ok();
}

nlohmann::json TermsJson(uint64_t terms) {
  return terms == RelightOptions::kAllTerms ? nlohmann::json("all") : nlohmann::json(terms);
}

Result<RelightResult> RunRelight(const RelightOptions& o, const Progress& progress) {
  if (o.terms == 0) return InvalidArgument("--terms must be at least 1 (or all)");
  LTB_RETURN_IF_ERROR(CheckRelightNumbers(o));
  EnvLoadOptions eo;
  eo.clamp = o.clamp_env;
  eo.layout = o.env_layout;
  eo.max_bytes = o.mem_limit;  // the map's pixels (and an .hdr's bytes) within --mem-limit
  eo.progress = progress;
  eo.jobs = o.jobs;
  const nlohmann::json terms_json = TermsJson(o.terms);
  nlohmann::json report = {
      {"matrix", o.matrix}, {"env", o.env}, {"terms", terms_json}, {"weighting", WeightingName(o.weighting)}};

  auto t0 = Clock::now();
  LTB_ASSIGN_OR_RETURN(RelightMatrix m, RelightMatrix::Open(o.matrix, o.mem_limit, o.jobs, progress, &report));
  const LightingBasis& basis = m.basis();
  auto t1 = Clock::now();
  LTB_ASSIGN_OR_RETURN(Environment env,
                       o.env_cubemap.empty()
                           ? Environment::Open(o.env, basis.cube_res(), eo)
                           : Environment::FromCubemap(o.env_cubemap, basis.cube_res(), o.clamp_env, o.env));
  auto t2 = Clock::now();
  report["load_matrix_ms"] = Ms(t0, t1);
  report["load_env_ms"] = Ms(t1, t2);
  if (env.clamped()) report["clamped_values"] = env.clamped();
  if (o.rotate_deg != 0 && !env.rotates()) {
    return InvalidArgument("--rotate " + Shortest(o.rotate_deg) + ": " + o.env +
                           " is a cubemap .npy, which cannot rotate; pass the .exr or .hdr map it was converted from");
  }
  const double rotation = o.rotate_deg * std::numbers::pi / 180.0;

  Frames frames(o, env, basis, m);
  double lighting_ms = 0, relight_ms = 0;
  LTB_RETURN_IF_ERROR(frames.Render(rotation, &lighting_ms, &relight_ms));
  report["lighting_ms"] = lighting_ms;
  report["relight_ms"] = relight_ms;
  report["terms_used"] = frames.terms.column.size();
  ReportTerms(basis, frames, &report);
  report["output"] = {{"masked_rows", frames.fixes.masked_rows}, {"clamped_values", nullptr}};
  if (!o.keep_negative) report["output"]["clamped_values"] = frames.fixes.clamped_values;
  if (!o.output.empty()) {
    LTB_RETURN_IF_ERROR(
        WriteImage(o.output, frames.image.data(), m.rows(), m.width(), m.height(), {.exposure = o.exposure}));
  }
  std::vector<float> first = frames.image;
  LightTerms first_terms = frames.terms;
  const int first_exponent = frames.exponent;

  if (o.frames > 0) LTB_RETURN_IF_ERROR(TimeFrames(o, env, rotation, progress, &frames, &report));
  if (!o.reference.empty()) {
    LTB_RETURN_IF_ERROR(
        MeasureErrors(o, env, basis, m, frames, first, first_terms, first_exponent, rotation, progress, &report));
  }
  RelightResult result{std::move(report), {}};
  if (o.return_image) result.image = std::move(first);
  return result;
}

}  // namespace ltb::stages
