#include "stages/relight/run_sequence.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <map>
#include <numbers>
#include <optional>
#include <span>
#include <sstream>

#include "format/io/atomic_file.h"
#include "format/io/file.h"
#include "stages/common/cubemap.h"
#include "stages/images/image_io.h"
#include "stages/images/video.h"
#include "stages/relight/relight_matrix.h"

namespace ltb::stages {
namespace {

using SeqClock = std::chrono::steady_clock;
double SeqMs(SeqClock::time_point a, SeqClock::time_point b) {
  return std::chrono::duration<double, std::milli>(b - a).count();
}

// Relative L2 and relative L1 of `x` against `ref`, each entry weighted by w (per row).
std::pair<double, double> RelErrors(const float* x, const float* ref, uint64_t rows, const std::vector<double>* w) {
  double d2 = 0, r2 = 0, d1 = 0, r1 = 0;
  for (uint64_t i = 0; i < rows; ++i) {
    const double wi = w ? (*w)[i] : 1.0;
    for (int c = 0; c < 3; ++c) {
      const double d = static_cast<double>(x[i * 3 + c]) - ref[i * 3 + c], r = ref[i * 3 + c];
      d2 += wi * d * d;
      r2 += wi * r * r;
      d1 += wi * std::fabs(d);
      r1 += wi * std::fabs(r);
    }
  }
  return {r2 > 0 ? std::sqrt(d2 / r2) : std::sqrt(d2), r1 > 0 ? d1 / r1 : d1};
}

}  // namespace

Result<LightingSequence> LightingSequence::Open(const std::vector<SequenceSegment>& segments, const std::string& first,
                                                double rotation, uint64_t cube_res, const EnvLoadOptions& options) {
  LightingSequence seq;
  seq.cube_res_ = cube_res;
  seq.options_ = options;
  std::map<std::string, uint32_t> index;
  auto map = [&](const std::string& path) -> Result<uint32_t> {
    auto it = index.find(path);
    if (it != index.end()) return it->second;
    LTB_RETURN_IF_ERROR(io::RequireRegularFile(path, "name an environment map (.exr, .hdr or a cubemap .npy)"));
    seq.paths_.push_back(path);
    return index[path] = static_cast<uint32_t>(seq.paths_.size() - 1);
  };
  LTB_ASSIGN_OR_RETURN(uint32_t current, map(first));
  const double kRad = std::numbers::pi / 180.0;
  for (const SequenceSegment& s : segments) {
    switch (s.kind) {
      case SequenceSegment::Kind::kRotate:
        for (uint64_t k = 0; k < s.frames; ++k)
          seq.frames_.push_back({current, current, 0.0f, rotation + k * s.degrees * kRad});
        rotation += s.frames * s.degrees * kRad;
        break;
      case SequenceSegment::Kind::kHold:
        for (uint64_t k = 0; k < s.frames; ++k) seq.frames_.push_back({current, current, 0.0f, rotation});
        break;
      case SequenceSegment::Kind::kMaps:
        for (const std::string& m : s.maps) {
          LTB_ASSIGN_OR_RETURN(current, map(m));
          seq.frames_.push_back({current, current, 0.0f, rotation});
        }
        break;
      case SequenceSegment::Kind::kFade: {
        LTB_ASSIGN_OR_RETURN(uint32_t a, map(s.maps[0]));
        LTB_ASSIGN_OR_RETURN(uint32_t b, map(s.maps[1]));
        for (uint64_t k = 0; k < s.frames; ++k) {
          const float t = s.frames == 1 ? 1.0f : static_cast<float>(k) / static_cast<float>(s.frames - 1);
          seq.frames_.push_back({a, b, t, rotation});
        }
        current = b;
        break;
      }
    }
  }
  for (const Frame& f : seq.frames_) {
    for (uint32_t e : {f.a, f.b}) {
      if (seq.paths_[e].ends_with(".npy") && f.rotation != 0) {
        return InvalidArgument("--sequence rotates " + seq.paths_[e] +
                               ", a cubemap .npy, which cannot rotate; give an .exr or .hdr map, or drop the rotation");
      }
    }
  }
  // Every map's largest value, for one exponent (the first map last: it stays cached).
  float peak = 0;
  for (uint32_t i = uint32_t(seq.paths_.size()); i-- > 0;) {
    LTB_ASSIGN_OR_RETURN(const Environment* e, seq.Load(i));  // --env: its errors before any frame
    peak = std::max(peak, e->peak());
  }
  seq.exponent_ = LightingExponent(peak);
  return seq;
}

Result<const Environment*> LightingSequence::Load(uint32_t map) {
  for (size_t i = 0; i < cache_.size(); ++i) {
    if (cache_[i].first != map) continue;
    std::rotate(cache_.begin() + i, cache_.begin() + i + 1, cache_.end());  // most recent last
    return cache_.back().second.get();
  }
  LTB_ASSIGN_OR_RETURN(Environment e, Environment::Open(paths_[map], cube_res_, options_, EnvResampling::kPerFrame));
  if (cache_.size() == 2) cache_.erase(cache_.begin());
  cache_.emplace_back(map, std::make_unique<Environment>(std::move(e)));
  return cache_.back().second.get();
}

Status LightingSequence::Cubemap(uint64_t frame, std::vector<float>* out, double turn) {
  const Frame& f = frames_[frame];
  LTB_ASSIGN_OR_RETURN(const Environment* a, Load(f.a));
  LTB_RETURN_IF_ERROR(a->Cubemap(f.rotation + turn, out));
  if (f.b == f.a || f.t == 0.0f) return Status::Ok();
  LTB_ASSIGN_OR_RETURN(const Environment* b, Load(f.b));
  std::vector<float> other;
  LTB_RETURN_IF_ERROR(b->Cubemap(f.rotation + turn, &other));
  for (size_t i = 0; i < out->size(); ++i) (*out)[i] = (1.0f - f.t) * (*out)[i] + f.t * other[i];
  return Status::Ok();
}

IncrementalRelighter::IncrementalRelighter(RelightMatrix& matrix, SequenceMethod method, uint64_t terms,
                                           Weighting weighting)
    : m_(matrix),
      lighting_(matrix.basis(), method, terms, weighting, matrix.column_norms()),
      image_(matrix.rows() * 3, 0.0f),
      acc_(method == SequenceMethod::kNwa ? 0 : matrix.rows() * 3, 0.0) {}

uint64_t IncrementalRelighter::overhead_bytes() const {
  return acc_.size() * 8 + delta_.capacity() * 4 + lighting_.applied().size() * 4 * 3;
}

Status IncrementalRelighter::Frame(const std::vector<float>& cube) {
  auto a = SeqClock::now();
  basis_cube_ = cube;
  m_.basis().ToBasis(basis_cube_.data());
  LTB_RETURN_IF_ERROR(lighting_.Step(basis_cube_, &update_));
  auto b = SeqClock::now();
  if (update_.absolute) {
    LTB_RETURN_IF_ERROR(m_.Relight(update_.terms, &image_));
  } else if (!update_.terms.column.empty()) {
    LTB_RETURN_IF_ERROR(m_.Relight(update_.terms, &delta_));
    for (size_t i = 0; i < acc_.size(); ++i) {
      acc_[i] += delta_[i];
      image_[i] = static_cast<float>(acc_[i]);
    }
  }
  lighting_ms_ = SeqMs(a, b);
  relight_ms_ = SeqMs(b, SeqClock::now());
  return Status::Ok();
}

namespace {

// --output's frame directory made (frames go into one of their own more often than not) and
// --applied-lighting's pattern checked, before any frame is relit.
Status PrepareSequenceOutputs(const RelightOptions& o, const SequenceOptions& so) {
  if (!o.output.ends_with(".mp4")) {
    LTB_ASSIGN_OR_RETURN(std::string first, FramePath(o.output, 0));
    const std::filesystem::path dir = std::filesystem::path(first).parent_path();
    std::error_code ec;
    if (!dir.empty()) std::filesystem::create_directories(dir, ec);
    if (ec) return IoError(o.output + ": cannot make the frames' directory " + dir.string(), ec.value());
  }
  if (!so.applied_output.empty()) {
    if (!so.applied_output.ends_with(".npy")) {
      return InvalidArgument("--applied-lighting " + so.applied_output + ": it writes .npy files (a %04d pattern)");
    }
    LTB_RETURN_IF_ERROR(FramePath(so.applied_output, 0).status());
  }
  return Status::Ok();
}

// One frame's report entry: its times, its term budget and every band's update.
nlohmann::json FrameJson(uint64_t f, double frame_ms, const IncrementalRelighter& inc, double rotation) {
  const FrameUpdate& u = inc.update();
  nlohmann::json fr = {{"frame", f},
                       {"ms", frame_ms},
                       {"lighting_ms", inc.lighting_ms()},
                       {"relight_ms", inc.relight_ms()},
                       {"terms", u.budget_terms},
                       {"columns_touched", u.terms.column.size()},
                       {"rotate_deg", rotation * 180.0 / std::numbers::pi}};
  nlohmann::json bands = nlohmann::json::array();
  for (size_t k = 0; k < u.bands.size(); ++k) {
    bands.push_back({{"band", k},
                     {"terms", u.bands[k].terms},
                     {"update", u.bands[k].incremental ? "incremental" : "reset"},
                     {"reset_terms", u.bands[k].reset_terms}});
  }
  fr["bands"] = std::move(bands);
  return fr;
}

// Frame f's image (into the video or its own file) and, with --applied-lighting, the lighting
// it was relit with (`applied_scaled`, at 2^-exponent).
Status WriteSequenceFrame(const RelightOptions& o, const SequenceOptions& so, uint64_t f, const std::vector<float>& out,
                          const RelightMatrix& m, double exposure, const std::vector<float>& applied_scaled,
                          int exponent, std::optional<Mp4Writer>* mp4) {
  if (o.output.ends_with(".mp4")) {
    if (!*mp4) {
      LTB_ASSIGN_OR_RETURN(Mp4Writer w, Mp4Writer::Open(o.output, m.width(), m.height(), so.fps));
      mp4->emplace(std::move(w));
    }
    std::vector<uint8_t> px = ToSrgb8(out.data(), m.rows(), exposure);
    LTB_RETURN_IF_ERROR((*mp4)->Add(px.data()));
  } else {
    LTB_ASSIGN_OR_RETURN(std::string path, FramePath(o.output, f));
    LTB_RETURN_IF_ERROR(WriteImage(path, out.data(), m.rows(), m.width(), m.height(), {.exposure = exposure}));
  }

  if (!so.applied_output.empty()) {
    LTB_ASSIGN_OR_RETURN(std::string path, FramePath(so.applied_output, f));
    std::vector<float> applied = applied_scaled;
    ScaleByPowerOfTwo(&applied, exponent);
    LTB_RETURN_IF_ERROR(WriteImage(path, applied.data(), applied.size() / 3, 0, 0));
  }
  return Status::Ok();
}

// The run's summary: frame times (median and mean), output, exposure and memory overhead.
nlohmann::json SequenceSummary(const std::vector<double>& ms_all, uint64_t frames, const IncrementalRelighter& inc,
                               const std::string& output, double exposure) {
  std::vector<double> sorted = ms_all;
  std::sort(sorted.begin(), sorted.end());
  double mean_ms = 0;
  for (double v : ms_all) mean_ms += v / static_cast<double>(ms_all.size());
  return {{"frames", frames},
          {"bands", inc.lighting().bands()},
          {"median_ms", sorted[sorted.size() / 2]},
          {"mean_ms", mean_ms},
          {"output", output},
          {"exposure", exposure},
          {"memory_overhead_bytes", inc.overhead_bytes()}};
}

// --csv: one line a frame (the report's frames), written atomically.
Status WriteSequenceCsv(const std::string& path, const nlohmann::json& frames) {
  std::ostringstream csv;
  csv << "frame,ms,relight_ms,terms,columns_touched,rel_l2,l1_area,lighting_rel_l2,lighting_l1_area,bands\n";
  csv.precision(9);
  for (const auto& fr : frames) {
    csv << fr["frame"].get<uint64_t>() << ',' << fr["ms"].get<double>() << ',' << fr["relight_ms"].get<double>() << ','
        << fr["terms"].get<uint64_t>() << ',' << fr["columns_touched"].get<uint64_t>() << ',';
    for (const char* k : {"rel_l2", "l1_area"}) {
      if (!fr[k].is_null()) csv << fr[k].get<double>();
      csv << ',';
    }
    csv << fr["lighting_rel_l2"].get<double>() << ',' << fr["lighting_l1_area"].get<double>() << ',';
    bool first_band = true;
    for (const auto& bd : fr["bands"]) {  // per band: terms and i (incremental) or r (reset)
      csv << (first_band ? "" : " ") << bd["terms"].get<uint64_t>() << (bd["update"] == "incremental" ? 'i' : 'r');
      first_band = false;
    }
    csv << '\n';
  }
  LTB_ASSIGN_OR_RETURN(io::AtomicFile file, io::AtomicFile::Create(path));
  const std::string text = csv.str();
  LTB_RETURN_IF_ERROR(file.file().WriteAt(0, std::as_bytes(std::span(text.data(), text.size()))));
  LTB_RETURN_IF_ERROR(file.Commit());
  return Status::Ok();
}

}  // namespace

Result<RelightResult> RunRelightSequence(const RelightOptions& o, const SequenceOptions& so, const Progress& progress) {
  if (o.terms == 0) return InvalidArgument("--terms must be at least 1 (or all)");
  if (o.frames > 0) return InvalidArgument("--frames times a rotation of one image; with --sequence drop it");
  LTB_RETURN_IF_ERROR(CheckRelightNumbers(o));
  LTB_ASSIGN_OR_RETURN(std::vector<SequenceSegment> segments, ParseSequence(so.spec));
  LTB_RETURN_IF_ERROR(PrepareSequenceOutputs(o, so));
  EnvLoadOptions eo;
  eo.clamp = o.clamp_env;
  eo.layout = o.env_layout;
  eo.max_bytes = o.mem_limit;
  eo.progress = progress;
  eo.jobs = o.jobs;
  const nlohmann::json terms_json = TermsJson(o.terms);
  nlohmann::json report = {{"matrix", o.matrix},  {"env", o.env},
                           {"sequence", so.spec}, {"method", SequenceMethodName(so.method)},
                           {"terms", terms_json}, {"weighting", WeightingName(o.weighting)}};
  auto t0 = SeqClock::now();
  LTB_ASSIGN_OR_RETURN(RelightMatrix m, RelightMatrix::Open(o.matrix, o.mem_limit, o.jobs, progress, &report));
  const LightingBasis& basis = m.basis();
  std::optional<RelightMatrix> ref_storage;
  RelightMatrix* ref = nullptr;
  if (!o.reference.empty()) {
    if (o.reference == o.matrix) {
      ref = &m;
    } else {
      LTB_ASSIGN_OR_RETURN(RelightMatrix r, RelightMatrix::Open(o.reference, o.mem_limit, o.jobs, progress, nullptr));
      LTB_RETURN_IF_ERROR(CheckSameBake(r, m));
      ref_storage = std::move(r);
      ref = &*ref_storage;
    }
  }
  auto t1 = SeqClock::now();
  LTB_ASSIGN_OR_RETURN(
      LightingSequence seq,
      LightingSequence::Open(segments, o.env, o.rotate_deg * std::numbers::pi / 180.0, basis.cube_res(), eo));
  report["load_matrix_ms"] = SeqMs(t0, t1);
  report["load_env_ms"] = SeqMs(t1, SeqClock::now());

  const uint64_t rows = m.rows(), r = basis.cube_res(), texels = 6 * r * r;
  std::vector<double> omega(texels);
  for (uint64_t j = 0; j < texels; ++j)
    omega[j] = cubemap::TexelSolidAngle(cubemap::ColumnToTexel(j, static_cast<uint32_t>(r)), static_cast<uint32_t>(r));
  IncrementalRelighter inc(m, so.method, o.terms, o.weighting);
  std::vector<float> cube, out, exact, applied_px;
  std::optional<Mp4Writer> mp4;
  double exposure = o.exposure;
  nlohmann::json frames = nlohmann::json::array();
  std::vector<double> ms_all;
  double sum_l2 = 0, sum_l1 = 0;
  uint64_t measured = 0;
  for (uint64_t f = 0; f < seq.frames(); ++f) {
    if (progress.Cancelled()) {
      return Cancelled("relight: interrupted after " + std::to_string(f) + " of " + std::to_string(seq.frames()) +
                       " frames (those are written)");
    }
    auto a = SeqClock::now();
    LTB_RETURN_IF_ERROR(seq.Cubemap(f, &cube));
    ScaleByPowerOfTwo(&cube, -seq.exponent());  // a map near float32's largest value: relit at 2^-k
    LTB_RETURN_IF_ERROR(inc.Frame(cube));
    const double frame_ms = SeqMs(a, SeqClock::now());
    ms_all.push_back(frame_ms);

    out = inc.image();
    ScaleByPowerOfTwo(&out, seq.exponent());
    FinishRelitImage(m.mask(), o.keep_negative, &out);
    LTB_RETURN_IF_ERROR(CheckRelitImageFinite(out, m.width(), o.env).WithContext("frame " + std::to_string(f)));
    if (exposure <= 0 && m.width() > 0) exposure = AutoExposure(out.data(), rows);  // fixed from frame 0 on
    LTB_RETURN_IF_ERROR(WriteSequenceFrame(o, so, f, out, m, exposure, inc.lighting().applied(), seq.exponent(), &mp4));
    nlohmann::json fr = FrameJson(f, frame_ms, inc, seq.Rotation(f));
    // The applied lighting against the frame's true lighting, in pixels (area-weighted L1).
    applied_px = inc.lighting().applied();
    basis.ToPixels(applied_px.data());
    auto [ll2, ll1] = RelErrors(applied_px.data(), cube.data(), texels, &omega);
    fr["lighting_rel_l2"] = ll2;
    fr["lighting_l1_area"] = ll1;
    if (ref) {
      std::vector<float> full = cube;
      ref->basis().ToBasis(full.data());
      LTB_RETURN_IF_ERROR(ref->RelightDense(full, &exact));
      ScaleByPowerOfTwo(&exact, seq.exponent());
      FinishRelitImage(m.mask(), o.keep_negative, &exact);
      auto [l2, l1] = RelErrors(out.data(), exact.data(), rows, nullptr);
      fr["rel_l2"] = l2;
      fr["l1_area"] = l1;
      sum_l2 += l2;
      sum_l1 += l1;
      ++measured;
    } else {
      fr["rel_l2"] = nullptr;
      fr["l1_area"] = nullptr;
    }
    frames.push_back(std::move(fr));
    progress.Report(f + 1, seq.frames(), "frames");
  }
  if (mp4) LTB_RETURN_IF_ERROR(mp4->Finish());

  nlohmann::json summary = SequenceSummary(ms_all, seq.frames(), inc, o.output, exposure);
  if (measured > 0) {
    summary["mean_rel_l2"] = sum_l2 / static_cast<double>(measured);
    summary["mean_l1_area"] = sum_l1 / static_cast<double>(measured);
    summary["final_rel_l2"] = frames.back()["rel_l2"];
  }
  report["frames"] = std::move(frames);
  report["summary"] = std::move(summary);

  if (!so.csv.empty()) LTB_RETURN_IF_ERROR(WriteSequenceCsv(so.csv, report["frames"]));
  return RelightResult{std::move(report), {}};
}

}  // namespace ltb::stages
