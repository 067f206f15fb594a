// The state behind `ltbake view` (docs/VIEW.md): one matrix, its environment maps, and the
// lighting approximation carried from frame to frame, so that dragging the environment
// relights incrementally (pbi or bi) exactly like `relight --sequence`. HTTP-free: the
// server (server.h) parses requests into FrameRequest and sends what Render returns.
#pragma once

#include <cstdint>
#include <glm/vec3.hpp>
#include <map>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <tuple>
#include <vector>

#include "format/status.h"
#include "stages/images/environment.h"
#include "stages/relight/glossy_view.h"
#include "stages/relight/relight_matrix.h"
#include "stages/relight/run_sequence.h"

namespace ltb::stages::view {

struct ViewOptions {
  std::string matrix, reference;
  std::vector<std::string> envs;  // --env, once or more: the page picks among them
  uint64_t terms = 100;
  bool terms_given = false;  // --terms was given (else a vertex bake starts with every term)
  SequenceMethod method = SequenceMethod::kPbi;
  EnvLayout env_layout = EnvLayout::kAuto;
  bool clamp_env = false;
  uint64_t mem_limit = 1ull << 30;
  int jobs = 2;
  int port = 0;  // 0: a free one
  // --sequence: a lighting sequence (docs/SEQUENCE.md) from each map, which the page's time
  // slider scrubs and plays (FrameRequest::t); empty: none.
  std::vector<SequenceSegment> sequence;
  // A vertex bake (plain, or factored by sample --factor K) is seen from an eye, which each
  // frame's orbit and tilt move (FrameRequest); unset eye or target: from the vertices'
  // bounding box (the target its centre, the eye in front of it, raised 25°, all in view).
  std::optional<glm::dvec3> eye, target;
  glm::dvec3 up{0, 0, 1};
  double fov_degrees = 40;
  uint32_t width = 256, height = 256;
  uint32_t brdf_terms = 0;  // a factored bake's BRDF terms used (0: all)
  // Which of --eye, --target, --up, --fov, --size, --brdf-terms were given ("" for none): an
  // image bake's camera is its own, so it refuses them.
  std::string eye_flags;
};

// What a frame's PNG shows: the matrix's relit image, the reference's exact one under the
// same lighting (A/B), or their difference |A − B| per channel at an exposure of its own.
enum class FrameShow { kMatrix, kReference, kDifference };
const char* FrameShowName(FrameShow s);

// A query parameter's unsigned decimal number of at most `max_digits` digits (no sign, no
// spaces, no leading '+'); nothing when the text is anything else.
std::optional<uint64_t> ParseIndex(const std::string& value, size_t max_digits);

struct FrameRequest {
  uint64_t map = 0;  // index into ViewOptions::envs
  double rotate_deg = 0;
  uint64_t terms = 100;  // RelightOptions::kAllTerms: every term
  SequenceMethod method = SequenceMethod::kPbi;
  double exposure = 0;                  // 0: automatic (the 99th percentile of luminance to 0.9)
  FrameShow show = FrameShow::kMatrix;  // reference and difference need --reference
  int64_t t = -1;                       // a frame of the --sequence (rotate turns it further); −1: none
  // A vertex bake's eye: turned orbit_deg about +Z through the target, after raising it
  // tilt_deg (its elevation kept within ±85°). Only for a vertex bake.
  double orbit_deg = 0, tilt_deg = 0;
};
// From a query's parameters (map, rotate, terms, method, exposure, show, t, and with `eye` (a
// vertex bake) orbit and tilt; each optional, defaults from `defaults`; map below `maps`, t
// below `sequence_frames`); an InvalidArgument names the parameter and the value.
Result<FrameRequest> ParseFrameRequest(const std::map<std::string, std::string>& params, const FrameRequest& defaults,
                                       uint64_t maps = 1, uint64_t sequence_frames = 0, bool eye = false);

class ViewSession {
 public:
  static Result<std::unique_ptr<ViewSession>> Open(const ViewOptions& options);
  const FrameRequest& defaults() const { return defaults_; }
  // A vertex bake, seen from an eye (else an image bake, seen from its camera).
  bool from_eye() const { return vertex_ != nullptr; }
  uint64_t width() const { return width_; }
  uint64_t height() const { return height_; }
  // The eye of `q` (a vertex bake) and the target it looks at.
  glm::dvec3 Eye(const FrameRequest& q) const;
  const glm::dvec3& target() const { return target_; }
  bool has_reference() const { return reference_.has_value() || vertex_reference_ != nullptr; }
  // The maps' file names, in --env order (the page's choice of map).
  std::vector<std::string> map_names() const;
  uint64_t maps() const { return envs_.size(); }
  // A map sent by the page (POST /map): `name` is its file name (letters, digits, '.', '-',
  // '_'; ending .exr or .hdr, which says how to read it), `bytes` the file. LoadMap checks and
  // loads it like an --env map (and makes its --sequence) without changing the session, so
  // frames may render meanwhile; AddMap then adds it (under the caller's lock): the new map's
  // index. InvalidArgument for a bad name or file, naming it; FailedPrecondition past kMaxMaps
  // maps.
  static constexpr uint64_t kMaxMaps = 16;
  struct LoadedMap {
    std::string name;
    Environment env;
    std::optional<LightingSequence> sequence;
  };
  Result<LoadedMap> LoadMap(const std::string& name, const std::string& bytes) const;
  Result<uint64_t> AddMap(LoadedMap map);
  // Frames of the --sequence (0: none).
  uint64_t sequence_frames() const { return sequences_.empty() ? 0 : sequences_.front().frames(); }

  // Relights one frame (the approximation carries over from the last frame when map, method
  // and terms are the same) and returns its PNG bytes; stats() describes it afterwards.
  Result<std::string> Render(const FrameRequest& request);
  // The last frame: frame, map, map_name, rotate, method, terms, columns_touched, ms, exposure, bands, show,
  // and with a reference rel_l2 against it and difference_exposure (what the difference
  // image is shown at: the frame's given exposure times 2^4, else, when the difference is
  // shown, its own automatic one).
  const nlohmann::json& stats() const { return stats_; }
  // The last frame as shown (the matrix's image, the reference's or the difference), linear,
  // as an EXR file's bytes (what `relight -o X.exr` writes); `frame`, when given, must be
  // its number (stats' "frame"), so a page saves the frame it shows. FailedPrecondition
  // before the first frame or for another frame.
  Result<std::string> FrameExr(std::optional<uint64_t> frame) const;
  // A lat-long strip (width × width/2) of the last frame's lighting, the texels its terms
  // touched tinted red.
  std::string EnvironmentPng(uint64_t width) const;

 private:
  ViewSession() = default;
  // A frame of a vertex bake into `out` (width × height × 3, linear), and `exact`, the
  // reference's, when there is one; the image path is Render's own.
  Status RenderFromEye(const FrameRequest& q, std::vector<float>* out, std::vector<float>* exact);
  // The last frame shown: stats_ gains the comparison with `exact` (when given), and the
  // PNG of what q.show asks for is returned.
  Result<std::string> Show(const FrameRequest& q, std::vector<float> out, const std::vector<float>* exact,
                           double exposure);
  uint64_t cube_res() const { return vertex_ ? vertex_->basis().cube_res() : m_->basis().cube_res(); }

  std::optional<RelightMatrix> m_;                             // an image bake
  std::unique_ptr<VertexRenderer> vertex_, vertex_reference_;  // a vertex bake, and its --reference
  uint64_t width_ = 0, height_ = 0;
  glm::dvec3 eye_{0}, target_{0}, up_{0, 0, 1};
  double fov_degrees_ = 40;
  // What the vertex bake's P_k were relit for (map, rotation, terms, t): a frame that moves
  // only the eye reuses them.
  std::optional<std::tuple<uint64_t, double, uint64_t, int64_t>> relit_for_;
  std::vector<Environment> envs_;
  std::vector<std::string> env_paths_;  // an uploaded map's: its name
  EnvLoadOptions env_options_;
  std::vector<SequenceSegment> sequence_;
  std::vector<LightingSequence> sequences_;  // --sequence from each map (empty without one)
  int exponent_ = 0;                         // every map relit at 2^-exponent_ (LightingExponent of the brightest)
  std::optional<RelightMatrix> reference_;
  FrameRequest defaults_, last_;
  std::unique_ptr<IncrementalRelighter> relighter_;
  std::vector<float> cube_;
  std::vector<float> shown_;                   // the last frame's image as shown, linear (rows × 3)
  uint64_t shown_frame_ = ~uint64_t{0};        // the frame shown_ is (a frame that failed leaves it behind)
  mutable std::vector<uint64_t> strip_texel_;  // the cube texel of each strip pixel (made once)
  uint64_t frame_ = 0;
  nlohmann::json stats_ = nlohmann::json::object();
};

}  // namespace ltb::stages::view
