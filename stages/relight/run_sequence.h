// `ltbake relight MATRIX --env ENV --sequence SPEC -o PATTERN` as a library call
// (docs/SEQUENCE.md): a lighting sequence — rotations, holds, map lists, fades — relit frame
// by frame with the non-linear (nwa), basic incremental (bi) or per-band incremental (pbi)
// lighting approximation of Overbeck et al. 2006, each frame written through a printf
// pattern or into an .mp4, with per-frame timings and, against a reference matrix, errors.
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "format/progress.h"
#include "format/status.h"
#include "stages/images/environment.h"
#include "stages/relight/incremental.h"
#include "stages/relight/run_relight.h"
#include "stages/relight/sequence_spec.h"

namespace ltb::stages {

// The lighting of each frame (6R² × 3 radiance in pixels). Maps are loaded when a frame
// needs them and at most two are held (a fade's two ends), so a long list of maps costs the
// memory of two.
class LightingSequence {
 public:
  // `first`: the map the sequence starts from (--env), turned by `rotation` radians. Every
  // map must be a regular file; `first` is loaded now.
  static Result<LightingSequence> Open(const std::vector<SequenceSegment>& segments, const std::string& first,
                                       double rotation, uint64_t cube_res, const EnvLoadOptions& options);
  uint64_t frames() const { return frames_.size(); }
  // Frame `frame`'s lighting, turned `turn` radians more about +Z (ltbake view's drag).
  Status Cubemap(uint64_t frame, std::vector<float>* out, double turn = 0);
  double Rotation(uint64_t frame) const { return frames_[frame].rotation; }
  // The power of two k to relight every frame at (× 2^-k; LightingExponent of the largest
  // value of any of its maps): one k for the whole sequence, so the incremental images add up.
  int exponent() const { return exponent_; }

 private:
  struct Frame {
    uint32_t a = 0, b = 0;  // maps blended (1 − t)·a + t·b
    float t = 0;
    double rotation = 0;  // radians about +Z
  };
  Result<const Environment*> Load(uint32_t map);
  std::vector<std::string> paths_;
  uint64_t cube_res_ = 0;
  EnvLoadOptions options_;
  std::vector<std::pair<uint32_t, std::unique_ptr<Environment>>> cache_;  // most recent last, at most 2
  std::vector<Frame> frames_;
  int exponent_ = 0;
};

class RelightMatrix;

// A matrix relit frame after frame under one lighting approximation: nwa relights the
// frame's terms; bi and pbi add T·ΔL̃ to the image kept (in double) from frame to frame.
class IncrementalRelighter {
 public:
  IncrementalRelighter(RelightMatrix& matrix, SequenceMethod method, uint64_t terms, Weighting weighting);
  // `cube`: the frame's full lighting in pixels (6R² × 3). Fills image() (T·L̃, before the
  // output policy) and update().
  Status Frame(const std::vector<float>& cube);
  const std::vector<float>& image() const { return image_; }
  const FrameUpdate& update() const { return update_; }
  const IncrementalLighting& lighting() const { return lighting_; }
  double lighting_ms() const { return lighting_ms_; }  // transform and term selection
  double relight_ms() const { return relight_ms_; }    // the matrix product and the image update
  // What bi and pbi hold beyond nwa.
  uint64_t overhead_bytes() const;

 private:
  RelightMatrix& m_;
  IncrementalLighting lighting_;
  FrameUpdate update_;
  std::vector<float> basis_cube_, image_, delta_;
  std::vector<double> acc_;
  double lighting_ms_ = 0, relight_ms_ = 0;
};

struct SequenceOptions {
  std::string spec;
  SequenceMethod method = SequenceMethod::kPbi;
  std::string csv;  // the per-frame table (empty: none)
  double fps = 25;  // .mp4 output
  // A pattern like -o's: each frame's applied lighting L̃ (6R² × 3 .npy, in the matrix's
  // column basis), for checking T·L̃ against the image. Empty: not written.
  std::string applied_output;
};

// -o is a pattern with one integer conversion (%d, %04d; %% for a literal %) or an .mp4.
// Cancelled between frames; the frames written stay.
Result<RelightResult> RunRelightSequence(const RelightOptions& options, const SequenceOptions& sequence,
                                         const Progress& progress);

}  // namespace ltb::stages
