#include "stages/view/view_session.h"

#include <stdlib.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <glm/geometric.hpp>
#include <numbers>
#include <optional>

#include "format/io/atomic_file.h"
#include "format/io/container_reader.h"
#include "stages/common/cubemap.h"
#include "stages/common/quantity.h"
#include "stages/images/image_io.h"
#include "stages/sample/camera.h"

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
                                       uint64_t maps, uint64_t sequence_frames, bool eye) {
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
    } else if (key == "orbit" || key == "tilt") {
      if (!eye) {
        return InvalidArgument(key + "=" + shown + ": only a vertex bake is seen from an eye that moves; " +
                               "an image bake's camera is fixed (drag turns the environment)");
      }
      auto v = ParseDecimal(value, -RelightOptions::kMaxRotateDegrees, RelightOptions::kMaxRotateDegrees);
      if (!v.ok()) return InvalidArgument(key + ": " + v.status().message() + " (degrees)");
      (key == "orbit" ? r.orbit_deg : r.tilt_deg) = *v;
    } else {
      return InvalidArgument("unknown parameter \"" + (key.size() > 40 ? key.substr(0, 40) + "..." : key) +
                             "\" (map, rotate, terms, method, exposure, show, t" + (eye ? ", orbit, tilt)" : ")"));
    }
  }
  return r;
}

namespace {

// The bake's rows: vertices (true), pixels of a camera (false), read from its metadata (the
// first file of a set).
Result<bool> RowsAreVertices(const std::string& path) {
  LTB_ASSIGN_OR_RETURN(std::vector<SetMember> members, ChannelFiles(path));
  const std::string first = members.empty() ? path : SetLeaf(members.front().path);  // a colour term: its red file
  LTB_ASSIGN_OR_RETURN(io::ContainerReader r, io::ContainerReader::Open(first));
  const nlohmann::json& j = r.metadata().json;
  return j.contains("basis") && j["basis"].contains("rows") && j["basis"]["rows"].value("kind", "") == "vertices";
}

}  // namespace

// Over 60 lines: the matrix (image or vertex bake, and its view), the maps, the sequences and
// the reference, each checked in turn.
Result<std::unique_ptr<ViewSession>> ViewSession::Open(const ViewOptions& o) {
  if (o.envs.empty()) return InvalidArgument("view needs an environment map (--env)");
  if (o.envs.size() > kMaxMaps) {
    return InvalidArgument("view takes at most " + std::to_string(kMaxMaps) + " maps (--env given " +
                           std::to_string(o.envs.size()) + " times)");
  }
  std::unique_ptr<ViewSession> s(new ViewSession());
  LTB_ASSIGN_OR_RETURN(const bool vertices, RowsAreVertices(o.matrix));
  if (vertices) {  // seen from an eye: the bake's mesh, its terms relit per lighting
    LTB_ASSIGN_OR_RETURN(VertexRenderer v,
                         VertexRenderer::Open(o.matrix, o.brdf_terms, o.mem_limit, o.jobs, Progress{}));
    s->vertex_ = std::make_unique<VertexRenderer>(std::move(v));
    s->width_ = o.width;
    s->height_ = o.height;
    s->fov_degrees_ = o.fov_degrees;
    s->up_ = o.up;
    const glm::dvec3 low = s->vertex_->low(), high = s->vertex_->high();
    s->target_ = o.target.value_or((low + high) * 0.5);
    // In front (−Y) and raised 25°, at the distance where the box's bounding sphere fills the
    // field of view.
    const double radius = std::max(0.5 * glm::length(high - low), 1e-6);
    const double distance = radius / std::sin(0.5 * o.fov_degrees * std::numbers::pi / 180.0);
    const double el = 25 * std::numbers::pi / 180.0;
    s->eye_ = o.eye.value_or(s->target_ + distance * glm::dvec3(0, -std::cos(el), std::sin(el)));
    LTB_RETURN_IF_ERROR(sample::ValidateView(s->eye_, s->target_, s->up_, s->fov_degrees_)
                            .WithContext("the view (--eye, --target, --up, --fov)"));
    LTB_RETURN_IF_ERROR(sample::CheckViewMemory(o.width, o.height, o.mem_limit));
    s->defaults_.method = SequenceMethod::kNwa;  // relit afresh each frame: nothing carries
  } else {
    if (!o.eye_flags.empty()) {
      return InvalidArgument(o.matrix + ": an image bake is seen from its own camera; " + o.eye_flags +
                             " are for vertex bakes (docs/VIEW.md)");
    }
    LTB_ASSIGN_OR_RETURN(RelightMatrix m, RelightMatrix::Open(o.matrix, o.mem_limit, o.jobs, Progress{}, nullptr));
    s->width_ = m.width();
    s->height_ = m.height();
    s->m_.emplace(std::move(m));
    s->defaults_.method = o.method;
  }
  EnvLoadOptions eo;
  eo.clamp = o.clamp_env;
  eo.layout = o.env_layout;
  eo.max_bytes = o.mem_limit;
  s->env_options_ = eo;
  s->sequence_ = o.sequence;
  float peak = 0;
  for (const std::string& path : o.envs) {
    LTB_ASSIGN_OR_RETURN(Environment env, Environment::Open(path, s->cube_res(), eo, EnvResampling::kPerFrame));
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
    LTB_ASSIGN_OR_RETURN(LightingSequence seq, LightingSequence::Open(o.sequence, o.envs[k], 0.0, s->cube_res(), eo));
    s->exponent_ = std::max(s->exponent_, seq.exponent());
    s->sequences_.push_back(std::move(seq));
  }
  if (!o.reference.empty() && s->vertex_) {  // the same mesh's bake, every lighting term
    LTB_ASSIGN_OR_RETURN(VertexRenderer r, VertexRenderer::Open(o.reference, 0, o.mem_limit, o.jobs, Progress{}));
    if (r.vertices() != s->vertex_->vertices() || r.basis().cube_res() != s->cube_res()) {
      return InvalidArgument(o.reference + ": " + std::to_string(r.vertices()) +
                             " vertices at R = " + std::to_string(r.basis().cube_res()) + ", " + o.matrix + " " +
                             std::to_string(s->vertex_->vertices()) + " at R = " + std::to_string(s->cube_res()) +
                             ": not a bake of the same mesh to compare with");
    }
    s->vertex_reference_ = std::make_unique<VertexRenderer>(std::move(r));
  } else if (!o.reference.empty()) {
    LTB_ASSIGN_OR_RETURN(RelightMatrix r, RelightMatrix::Open(o.reference, o.mem_limit, o.jobs, Progress{}, nullptr));
    LTB_RETURN_IF_ERROR(CheckSameBake(r, *s->m_));
    s->reference_ = std::move(r);
  }
  // A vertex bake's lighting is relit once per change (not per frame): every term unless asked.
  s->defaults_.terms = s->vertex_ && !o.terms_given ? RelightOptions::kAllTerms : o.terms;
  return s;
}

glm::dvec3 ViewSession::Eye(const FrameRequest& q) const {
  glm::dvec3 eye = eye_;
  if (q.tilt_deg != 0) {  // raise (or lower) the eye about the target, its distance kept
    const glm::dvec3 rel = eye_ - target_;
    const double flat = std::hypot(rel.x, rel.y), dist = glm::length(rel);
    const double limit = 85 * std::numbers::pi / 180.0;
    const double el = std::clamp(std::atan2(rel.z, flat) + q.tilt_deg * std::numbers::pi / 180.0, -limit, limit);
    const glm::dvec3 dir = flat > 0 ? glm::dvec3(rel.x / flat, rel.y / flat, 0) : glm::dvec3(0, -1, 0);
    eye = target_ + dist * (std::cos(el) * dir + glm::dvec3(0, 0, std::sin(el)));
  }
  return sample::OrbitEye(eye, target_, q.orbit_deg, 1);
}

Status ViewSession::RenderFromEye(const FrameRequest& q, std::vector<float>* out, std::vector<float>* exact) {
  if (q.method != SequenceMethod::kNwa) {
    return InvalidArgument(std::string("method=") + SequenceMethodName(q.method) +
                           ": a vertex bake is relit afresh every frame (nwa); the incremental methods are for "
                           "image bakes");
  }
  const std::tuple<uint64_t, double, uint64_t, int64_t> key{q.map, q.rotate_deg, q.terms, q.t};
  if (relit_for_ != key) {  // new lighting: P_k = T_k·L again (an eye that moves alone reuses them)
    relit_for_.reset();
    LTB_RETURN_IF_ERROR(vertex_->Relight(cube_, q.terms));
    if (vertex_reference_) LTB_RETURN_IF_ERROR(vertex_reference_->Relight(cube_, VertexRenderer::kAll));
    relit_for_ = key;
  }
  const glm::dvec3 eye = Eye(q);
  LTB_ASSIGN_OR_RETURN(sample::PinholeCamera camera,
                       sample::PinholeCamera::Create(eye, target_, up_, fov_degrees_, width_, height_));
  std::vector<float> b;
  LTB_RETURN_IF_ERROR(vertex_->Render(eye, camera, exponent_, env_paths_[q.map], &b, out));
  if (vertex_reference_)
    LTB_RETURN_IF_ERROR(vertex_reference_->Render(eye, camera, exponent_, env_paths_[q.map], &b, exact));
  return Status::Ok();
}

// Over 60 lines: the lighting, the frame (from an eye, or the image's approximation carried
// on), then its figures, in order.
Result<std::string> ViewSession::Render(const FrameRequest& q) {
  if (q.show != FrameShow::kMatrix && !reference_ && !vertex_reference_) {
    return InvalidArgument(std::string("show=") + FrameShowName(q.show) +
                           ": there is no reference to compare with (start ltbake view with --reference FILE)");
  }
  auto a = std::chrono::steady_clock::now();
  if (q.map >= envs_.size())
    return InvalidArgument("map=" + std::to_string(q.map) + ": there are " + std::to_string(envs_.size()) + " maps");
  const double turn = q.rotate_deg * std::numbers::pi / 180.0;
  if (q.t >= 0 && static_cast<uint64_t>(q.t) < sequence_frames()) {
    LTB_RETURN_IF_ERROR(sequences_[q.map].Cubemap(static_cast<uint64_t>(q.t), &cube_, turn));
  } else {
    LTB_RETURN_IF_ERROR(envs_[q.map].Cubemap(turn, &cube_));
  }
  const int exponent = exponent_;
  ScaleByPowerOfTwo(&cube_, -exponent);
  std::vector<float> out, exact;
  if (vertex_) {
    LTB_RETURN_IF_ERROR(RenderFromEye(q, &out, &exact));
  } else {
    // Another map starts over: the carried approximation is the old map's.
    if (!relighter_ || q.method != last_.method || q.terms != last_.terms || q.map != last_.map) {
      relighter_ = std::make_unique<IncrementalRelighter>(*m_, q.method, q.terms, Weighting::kArea);
    }
    LTB_RETURN_IF_ERROR(relighter_->Frame(cube_));
    out = relighter_->image();
    ScaleByPowerOfTwo(&out, exponent);
    FinishRelitImage(m_->mask(), false, &out);
    LTB_RETURN_IF_ERROR(CheckRelitImageFinite(out, width_, env_paths_[q.map]));
  }
  const double ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - a).count();
  const double exposure = q.exposure > 0 ? q.exposure : AutoExposure(out.data(), width_ * height_);
  stats_ = {{"frame", frame_++},
            {"map", q.map},
            {"map_name", std::filesystem::path(env_paths_[q.map]).filename().string()},
            {"rotate", q.rotate_deg},
            {"method", SequenceMethodName(q.method)},
            {"terms", TermsJson(q.terms)},
            {"ms", ms},
            {"exposure", exposure},
            {"width", width_},
            {"height", height_},
            {"show", FrameShowName(q.show)}};
  if (vertex_) {
    const glm::dvec3 eye = Eye(q);
    stats_["terms_used"] = vertex_->terms().column.size();
    stats_["columns_touched"] = 0;  // nothing carries over: each frame is relit afresh
    stats_["terms_in_effect"] = vertex_->terms().column.size();
    stats_["bands"] = nlohmann::json::array();
    stats_["brdf_terms"] = vertex_->terms_used();
    stats_["orbit"] = q.orbit_deg;
    stats_["tilt"] = q.tilt_deg;
    stats_["eye"] = {eye.x, eye.y, eye.z};
  } else {
    const FrameUpdate& u = relighter_->update();
    nlohmann::json bands = nlohmann::json::array();
    for (size_t k = 0; k < u.bands.size(); ++k) {
      bands.push_back({{"band", k}, {"terms", u.bands[k].terms}, {"incremental", u.bands[k].incremental}});
    }
    stats_["terms_used"] = u.budget_terms;
    stats_["columns_touched"] = u.terms.column.size();
    stats_["terms_in_effect"] = InEffect(relighter_->lighting().applied());
    stats_["bands"] = std::move(bands);
    if (reference_) {
      std::vector<float> full = cube_;
      reference_->basis().ToBasis(full.data());
      LTB_RETURN_IF_ERROR(reference_->RelightDense(full, &exact));
      ScaleByPowerOfTwo(&exact, exponent);
      FinishRelitImage(m_->mask(), false, &exact);
    }
  }
  if (q.t >= 0) stats_["t"] = q.t;
  last_ = q;
  const bool compared = reference_ || vertex_reference_;
  return Show(q, std::move(out), compared ? &exact : nullptr, exposure);
}

Result<std::string> ViewSession::Show(const FrameRequest& q, std::vector<float> out, const std::vector<float>* exact,
                                      double exposure) {
  const uint64_t pixels = width_ * height_;
  if (exact == nullptr) {
    std::vector<uint8_t> px = ToSrgb8(out.data(), pixels, exposure);
    shown_ = std::move(out);
    shown_frame_ = frame_ - 1;
    return EncodePng(px.data(), width_, height_);
  }
  stats_["rel_l2"] = CompareImages(out.data(), exact->data(), pixels, width_, height_).rel_l2;
  std::vector<float> diff(out.size());
  for (size_t i = 0; i < out.size(); ++i) diff[i] = std::fabs(out[i] - (*exact)[i]);
  // The difference is small beside the image: at the frame's exposure it would be black, so
  // it gets its own (automatic, or 16x the frame's when that is given).
  const double diff_exposure = q.exposure > 0 ? 16 * q.exposure : AutoExposure(diff.data(), pixels);
  stats_["difference_exposure"] = diff_exposure;
  const std::vector<float>& shown = q.show == FrameShow::kReference    ? *exact
                                    : q.show == FrameShow::kDifference ? diff
                                                                       : out;
  std::vector<uint8_t> px = ToSrgb8(shown.data(), pixels, q.show == FrameShow::kDifference ? diff_exposure : exposure);
  shown_ = shown;
  shown_frame_ = frame_ - 1;
  return EncodePng(px.data(), width_, height_);
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
  return EncodeExr(shown_.data(), width_, height_);
}

Result<ViewSession::LoadedMap> ViewSession::LoadMap(const std::string& name, const std::string& bytes) const {
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
  auto env = Environment::Open(path, cube_res(), env_options_, EnvResampling::kPerFrame);
  if (!env.ok()) return named(env.status());
  std::optional<LightingSequence> seq;
  if (!sequence_.empty()) {
    auto made = LightingSequence::Open(sequence_, path, 0.0, cube_res(), env_options_);
    if (!made.ok()) return named(made.status());
    seq.emplace(std::move(*made));
  }
  return LoadedMap{name, std::move(*env), std::move(seq)};
}

Result<uint64_t> ViewSession::AddMap(LoadedMap map) {
  if (envs_.size() >= kMaxMaps) {  // again: another upload may have come first
    return FailedPrecondition("the page has " + std::to_string(envs_.size()) + " maps, the most it takes; restart " +
                              "ltbake view with the maps wanted as --env");
  }
  const std::optional<LightingSequence>& seq = map.sequence;
  // A brighter map than any before moves the session's power-of-two scale: the carried
  // approximation was made at the old one, so the next frame starts afresh.
  const int exponent = std::max({exponent_, LightingExponent(map.env.peak()), seq ? seq->exponent() : 0});
  if (exponent != exponent_) {
    relighter_.reset();
    relit_for_.reset();
  }
  exponent_ = exponent;
  envs_.push_back(std::move(map.env));
  env_paths_.push_back(map.name);
  if (map.sequence) sequences_.push_back(std::move(*map.sequence));
  return envs_.size() - 1;
}

std::vector<std::string> ViewSession::map_names() const {
  std::vector<std::string> names;
  for (const std::string& p : env_paths_) names.push_back(std::filesystem::path(p).filename().string());
  return names;
}

std::string ViewSession::EnvironmentPng(uint64_t width) const {
  const uint64_t w = std::max<uint64_t>(width, 2), h = w / 2, r = cube_res();
  std::vector<uint8_t> mark(6 * r * r, 0);
  if (vertex_ && relit_for_) {
    for (uint32_t j : vertex_->terms().column) Support(j, r, vertex_->basis().wavelet(), &mark);
  } else if (relighter_) {
    for (uint32_t j : relighter_->update().terms.column) Support(j, r, m_->basis().wavelet(), &mark);
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
