#include "stages/view/view_session.h"

#include <stdlib.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <numbers>
#include <optional>

#include "format/io/atomic_file.h"
#include "stages/common/cubemap.h"
#include "stages/common/quantity.h"
#include "stages/images/image_io.h"

namespace ltb::stages::view {
namespace {

// Marks the face texels a lighting column's basis function covers — the whole face for the
// scaling function, else the block of side R/2^l of a level-l detail (Mallat layout) — with
// a strength that grows with the level, so that fine terms stand out over face-wide ones.
void Support(uint64_t column, uint64_t r, bool wavelet, std::vector<uint8_t>* mark) {
  const uint64_t rr = r * r, face = column / rr, p = column % rr, s = p % r, t = p / r;
  if (!wavelet) {
    (*mark)[column] = 255;
    return;
  }
  int levels = 1;
  while ((uint64_t{1} << levels) < r) ++levels;
  const uint64_t m = std::max(s, t);
  uint64_t x0 = 0, y0 = 0, side = r;
  int l = -1;
  if (m > 0) {
    l = 63 - __builtin_clzll(m);
    const uint64_t n = uint64_t{1} << l;  // blocks per side at this level
    side = r / n;
    x0 = (s % n) * side;
    y0 = (t % n) * side;
  }
  const uint8_t strength = static_cast<uint8_t>(255 * (l + 2) / (levels + 1));
  for (uint64_t y = y0; y < y0 + side; ++y)
    for (uint64_t x = x0; x < x0 + side; ++x) {
      uint8_t& v = (*mark)[face * rr + y * r + x];
      v = std::max(v, strength);
    }
}

// Lighting terms the approximation holds (nonzero applied coefficients).
uint64_t InEffect(const std::vector<float>& applied) {
  uint64_t n = 0;
  for (size_t j = 0; j + 2 < applied.size(); j += 3) n += applied[j] != 0 || applied[j + 1] != 0 || applied[j + 2] != 0;
  return n;
}

}  // namespace

const char* FrameShowName(FrameShow s) {
  switch (s) {
    case FrameShow::kReference:
      return "reference";
    case FrameShow::kDifference:
      return "difference";
    case FrameShow::kMatrix:
      break;
  }
  return "matrix";
}

std::optional<uint64_t> ParseIndex(const std::string& value, size_t max_digits) {
  if (value.empty() || value.size() > max_digits || value.find_first_not_of("0123456789") != std::string::npos)
    return std::nullopt;
  return std::stoull(value);
}

Result<FrameRequest> ParseFrameRequest(const std::map<std::string, std::string>& params, const FrameRequest& d,
                                       uint64_t maps, uint64_t sequence_frames) {
  FrameRequest r = d;
  for (const auto& [key, value] : params) {
    const std::string shown = value.size() > 40 ? value.substr(0, 40) + "..." : value;
    if (key == "map") {
      const std::optional<uint64_t> map = ParseIndex(value, 9);
      if (!map || *map >= maps) {
        return InvalidArgument("map=" + shown + ": expected 0.." + std::to_string(maps - 1) +
                               " (the --env maps, in order)");
      }
      r.map = *map;
    } else if (key == "rotate") {
      auto v = ParseDecimal(value, -RelightOptions::kMaxRotateDegrees, RelightOptions::kMaxRotateDegrees);
      if (!v.ok()) return InvalidArgument("rotate: " + v.status().message() + " (degrees)");
      r.rotate_deg = *v;
    } else if (key == "terms") {
      if (value == "all") {
        r.terms = RelightOptions::kAllTerms;
      } else if (const std::optional<uint64_t> terms = ParseIndex(value, 9); terms && *terms > 0) {
        r.terms = *terms;
      } else {
        return InvalidArgument("terms=" + shown + ": expected an integer >= 1 or all");
      }
    } else if (key == "method") {
      auto m = ParseSequenceMethod(value);
      if (!m.ok()) return InvalidArgument("method=" + shown + ": expected nwa, bi or pbi");
      r.method = *m;
    } else if (key == "exposure") {
      auto v = ParseDecimal(value, 0, kMaxExposure);
      if (!v.ok()) return InvalidArgument("exposure: " + v.status().message() + " (0: automatic)");
      r.exposure = *v;
    } else if (key == "show") {
      if (value == "matrix") {
        r.show = FrameShow::kMatrix;
      } else if (value == "reference") {
        r.show = FrameShow::kReference;
      } else if (value == "difference") {
        r.show = FrameShow::kDifference;
      } else {
        return InvalidArgument("show=" + shown + ": expected matrix, reference or difference");
      }
    } else if (key == "t") {
      if (sequence_frames == 0) {
        return InvalidArgument("t=" + shown + ": there is no sequence (start ltbake view with --sequence SPEC)");
      }
      const std::optional<uint64_t> t = ParseIndex(value, 9);
      if (!t || *t >= sequence_frames) {
        return InvalidArgument("t=" + shown + ": expected a frame of the sequence, 0.." +
                               std::to_string(sequence_frames - 1));
      }
      r.t = static_cast<int64_t>(*t);
    } else {
      return InvalidArgument("unknown parameter \"" + (key.size() > 40 ? key.substr(0, 40) + "..." : key) +
                             "\" (map, rotate, terms, method, exposure, show, t)");
    }
  }
  return r;
}

Result<std::unique_ptr<ViewSession>> ViewSession::Open(const ViewOptions& o) {
  LTB_ASSIGN_OR_RETURN(RelightMatrix m, RelightMatrix::Open(o.matrix, o.mem_limit, o.jobs, Progress{}, nullptr));
  if (m.width() == 0) {
    return FailedPrecondition(o.matrix + ": its rows are not an image (a vertex bake); view shows image bakes");
  }
  EnvLoadOptions eo;
  eo.clamp = o.clamp_env;
  eo.layout = o.env_layout;
  eo.max_bytes = o.mem_limit;
  if (o.envs.empty()) return InvalidArgument("view needs an environment map (--env)");
  if (o.envs.size() > kMaxMaps) {
    return InvalidArgument("view takes at most " + std::to_string(kMaxMaps) + " maps (--env given " +
                           std::to_string(o.envs.size()) + " times)");
  }
  std::unique_ptr<ViewSession> s(new ViewSession(std::move(m)));
  s->env_options_ = eo;
  s->sequence_ = o.sequence;
  float peak = 0;
  for (const std::string& path : o.envs) {
    LTB_ASSIGN_OR_RETURN(Environment env,
                         Environment::Open(path, s->m_.basis().cube_res(), eo, EnvResampling::kPerFrame));
    if (!env.rotates()) {
      return FailedPrecondition(path + ": a cubemap .npy cannot rotate; view needs an .exr or .hdr map");
    }
    peak = std::max(peak, env.peak());
    s->envs_.push_back(std::move(env));
    s->env_paths_.push_back(path);
  }
  // A map near float32's largest value is relit at 2^-k (one k for the session, from the
  // brightest map, a sequence's maps too: the incremental image adds up across frames) and
  // the image scaled back.
  s->exponent_ = LightingExponent(peak);
  for (size_t k = 0; k < o.envs.size() && !o.sequence.empty(); ++k) {
    LTB_ASSIGN_OR_RETURN(LightingSequence seq,
                         LightingSequence::Open(o.sequence, o.envs[k], 0.0, s->m_.basis().cube_res(), eo));
    s->exponent_ = std::max(s->exponent_, seq.exponent());
    s->sequences_.push_back(std::move(seq));
  }
  if (!o.reference.empty()) {
    LTB_ASSIGN_OR_RETURN(RelightMatrix r, RelightMatrix::Open(o.reference, o.mem_limit, o.jobs, Progress{}, nullptr));
    LTB_RETURN_IF_ERROR(CheckSameBake(r, s->m_));
    s->reference_ = std::move(r);
  }
  s->defaults_.terms = o.terms;
  s->defaults_.method = o.method;
  return s;
}

Result<std::string> ViewSession::Render(const FrameRequest& q) {
  if (q.show != FrameShow::kMatrix && !reference_) {
    return InvalidArgument(std::string("show=") + FrameShowName(q.show) +
                           ": there is no reference to compare with (start ltbake view with --reference FILE)");
  }
  auto a = std::chrono::steady_clock::now();
  if (q.map >= envs_.size())
    return InvalidArgument("map=" + std::to_string(q.map) + ": there are " + std::to_string(envs_.size()) + " maps");
  // Another map starts over: the carried approximation is the old map's.
  if (!relighter_ || q.method != last_.method || q.terms != last_.terms || q.map != last_.map) {
    relighter_ = std::make_unique<IncrementalRelighter>(m_, q.method, q.terms, Weighting::kArea);
  }
  const double turn = q.rotate_deg * std::numbers::pi / 180.0;
  if (q.t >= 0 && static_cast<uint64_t>(q.t) < sequence_frames()) {
    LTB_RETURN_IF_ERROR(sequences_[q.map].Cubemap(static_cast<uint64_t>(q.t), &cube_, turn));
  } else {
    LTB_RETURN_IF_ERROR(envs_[q.map].Cubemap(turn, &cube_));
  }
  const int exponent = exponent_;
  ScaleByPowerOfTwo(&cube_, -exponent);
  LTB_RETURN_IF_ERROR(relighter_->Frame(cube_));
  const double ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - a).count();
  std::vector<float> out = relighter_->image();
  ScaleByPowerOfTwo(&out, exponent);
  FinishRelitImage(m_.mask(), false, &out);
  LTB_RETURN_IF_ERROR(CheckRelitImageFinite(out, m_.width(), env_paths_[q.map]));
  const double exposure = q.exposure > 0 ? q.exposure : AutoExposure(out.data(), m_.rows());
  const FrameUpdate& u = relighter_->update();
  nlohmann::json bands = nlohmann::json::array();
  for (size_t k = 0; k < u.bands.size(); ++k) {
    bands.push_back({{"band", k}, {"terms", u.bands[k].terms}, {"incremental", u.bands[k].incremental}});
  }
  stats_ = {{"frame", frame_++},
            {"map", q.map},
            {"map_name", std::filesystem::path(env_paths_[q.map]).filename().string()},
            {"rotate", q.rotate_deg},
            {"method", SequenceMethodName(q.method)},
            {"terms", TermsJson(q.terms)},
            {"terms_used", u.budget_terms},
            {"columns_touched", u.terms.column.size()},
            {"terms_in_effect", InEffect(relighter_->lighting().applied())},
            {"ms", ms},
            {"exposure", exposure},
            {"width", m_.width()},
            {"height", m_.height()},
            {"bands", std::move(bands)},
            {"show", FrameShowName(q.show)}};
  if (q.t >= 0) stats_["t"] = q.t;
  last_ = q;
  if (!reference_) {
    std::vector<uint8_t> px = ToSrgb8(out.data(), m_.rows(), exposure);
    shown_ = std::move(out);
    shown_frame_ = frame_ - 1;
    return EncodePng(px.data(), m_.width(), m_.height());
  }
  std::vector<float> full = cube_, exact;
  reference_->basis().ToBasis(full.data());
  LTB_RETURN_IF_ERROR(reference_->RelightDense(full, &exact));
  ScaleByPowerOfTwo(&exact, exponent);
  FinishRelitImage(m_.mask(), false, &exact);
  stats_["rel_l2"] = CompareImages(out.data(), exact.data(), m_.rows(), m_.width(), m_.height()).rel_l2;
  std::vector<float> diff(out.size());
  for (size_t i = 0; i < out.size(); ++i) diff[i] = std::fabs(out[i] - exact[i]);
  // The difference is small beside the image: at the frame's exposure it would be black, so
  // it gets its own (automatic, or 16x the frame's when that is given).
  const double diff_exposure = q.exposure > 0 ? 16 * q.exposure : AutoExposure(diff.data(), m_.rows());
  stats_["difference_exposure"] = diff_exposure;
  const std::vector<float>& shown = q.show == FrameShow::kReference    ? exact
                                    : q.show == FrameShow::kDifference ? diff
                                                                       : out;
  std::vector<uint8_t> px =
      ToSrgb8(shown.data(), m_.rows(), q.show == FrameShow::kDifference ? diff_exposure : exposure);
  shown_ = shown;
  shown_frame_ = frame_ - 1;
  return EncodePng(px.data(), m_.width(), m_.height());
}

Result<std::string> ViewSession::FrameExr(std::optional<uint64_t> frame) const {
  if (frame_ == 0) return FailedPrecondition("no frame yet: /frame.exr saves the last frame /frame.png rendered");
  if (frame && *frame != frame_ - 1) {
    return FailedPrecondition("frame=" + std::to_string(*frame) + ": the last frame is " + std::to_string(frame_ - 1) +
                              " (only the last one is kept)");
  }
  if (shown_frame_ != frame_ - 1) {
    return FailedPrecondition("frame " + std::to_string(frame_ - 1) + " failed; there is no frame to save");
  }
  return EncodeExr(shown_.data(), m_.width(), m_.height());
}

Result<uint64_t> ViewSession::AddMap(const std::string& name, const std::string& bytes) {
  std::string ext = name.size() >= 4 ? name.substr(name.size() - 4) : std::string();
  std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return std::tolower(c); });
  if (name.empty() || name.size() > 100 || name.front() == '.' ||
      name.find_first_not_of("abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789.-_") !=
          std::string::npos ||
      (ext != ".exr" && ext != ".hdr")) {
    return InvalidArgument("name=" + (name.size() > 40 ? name.substr(0, 40) + "..." : name) +
                           ": expected the map's file name, ending .exr or .hdr (letters, digits, '.', '-', '_')");
  }
  if (envs_.size() >= kMaxMaps) {
    return FailedPrecondition("the page has " + std::to_string(envs_.size()) + " maps, the most it takes; restart " +
                              "ltbake view with the maps wanted as --env");
  }
  if (bytes.empty()) return InvalidArgument(name + ": the upload is empty");
  // The loaders read files: the bytes go to a private directory, read, then removed.
  std::string dir = (std::filesystem::temp_directory_path() / "ltbake-view-XXXXXX").string();
  if (::mkdtemp(dir.data()) == nullptr) return IoError("view: a temporary directory for " + name, errno);
  const std::string path = dir + "/" + name;
  struct Remove {
    std::string dir;
    ~Remove() {
      std::error_code ec;
      std::filesystem::remove_all(dir, ec);
    }
  } remove{dir};
  LTB_RETURN_IF_ERROR(io::WriteFileAtomically(path, bytes));
  // Errors name the upload, not the temporary file.
  auto named = [&](const Status& st) {
    std::string text = st.message();
    for (size_t at; (at = text.find(path)) != std::string::npos;) text.replace(at, path.size(), "uploaded " + name);
    const bool ours = st.code() == StatusCode::kIo || st.code() == StatusCode::kInternal;  // else the file's fault
    return Status(ours ? st.code() : StatusCode::kInvalidArgument, text);
  };
  auto env = Environment::Open(path, m_.basis().cube_res(), env_options_, EnvResampling::kPerFrame);
  if (!env.ok()) return named(env.status());
  std::optional<LightingSequence> seq;
  if (!sequence_.empty()) {
    auto made = LightingSequence::Open(sequence_, path, 0.0, m_.basis().cube_res(), env_options_);
    if (!made.ok()) return named(made.status());
    seq.emplace(std::move(*made));
  }
  // A brighter map than any before moves the session's power-of-two scale: the carried
  // approximation was made at the old one, so the next frame starts afresh.
  const int exponent = std::max({exponent_, LightingExponent(env->peak()), seq ? seq->exponent() : 0});
  if (exponent != exponent_) relighter_.reset();
  exponent_ = exponent;
  envs_.push_back(std::move(*env));
  env_paths_.push_back(name);
  if (seq) sequences_.push_back(std::move(*seq));
  return envs_.size() - 1;
}

std::vector<std::string> ViewSession::map_names() const {
  std::vector<std::string> names;
  for (const std::string& p : env_paths_) names.push_back(std::filesystem::path(p).filename().string());
  return names;
}

std::string ViewSession::EnvironmentPng(uint64_t width) const {
  const uint64_t w = std::max<uint64_t>(width, 2), h = w / 2, r = m_.basis().cube_res();
  std::vector<uint8_t> mark(6 * r * r, 0);
  if (relighter_) {
    for (uint32_t j : relighter_->update().terms.column) Support(j, r, m_.basis().wavelet(), &mark);
  }
  std::vector<uint64_t>& texel = strip_texel_;
  if (texel.size() != w * h) {
    texel.resize(w * h);
    for (uint64_t y = 0; y < h; ++y)
      for (uint64_t x = 0; x < w; ++x) {
        // Lat-long: +Z up, longitude about +Z from +X.
        const double phi = 2 * std::numbers::pi * (x + 0.5) / w, theta = std::numbers::pi * (y + 0.5) / h;
        const glm::dvec3 d(std::sin(theta) * std::cos(phi), std::sin(theta) * std::sin(phi), std::cos(theta));
        texel[y * w + x] = cubemap::Column(cubemap::DirectionToTexel(d, static_cast<uint32_t>(r)), r);
      }
  }
  std::vector<float> rgb(w * h * 3, 0.0f);
  if (!cube_.empty())
    for (uint64_t i = 0; i < w * h; ++i)
      for (int c = 0; c < 3; ++c) rgb[i * 3 + c] = cube_[texel[i] * 3 + c];
  std::vector<uint8_t> px = ToSrgb8(rgb.data(), w * h, AutoExposure(rgb.data(), w * h));
  for (uint64_t i = 0; i < w * h; ++i) {
    const double a = mark[texel[i]] / 255.0 * 0.7;  // tint: toward red by the strength
    if (a == 0) continue;
    px[i * 3] = static_cast<uint8_t>(std::lround((1 - a) * px[i * 3] + a * 255));
    px[i * 3 + 1] = static_cast<uint8_t>(std::lround((1 - a) * px[i * 3 + 1]));
    px[i * 3 + 2] = static_cast<uint8_t>(std::lround((1 - a) * px[i * 3 + 2]));
  }
  return EncodePng(px.data(), w, h);
}

}  // namespace ltb::stages::view
