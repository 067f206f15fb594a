// Lighting approximations for changing lighting (Overbeck et al. 2006, ch. 4–6;
// docs/SEQUENCE.md): each frame keeps at most N wavelet terms of the lighting and says what
// changed in the lighting applied so far, so the image can be updated by T·ΔL.
//
//   nwa  the non-linear approximation of every frame on its own (Ng et al. 2003): L̃ = the N
//        largest terms of L.
//   bi   basic incremental (ch. 4): the N largest terms of L − L̃ are brought up to date.
//   pbi  per-band incremental (ch. 6): the terms are grouped by wavelet level (band 0 = the
//        scaling function and the coarsest details, band b = details of side R/2^b). Each
//        band is updated incrementally when ‖L − L̃‖₁ < ‖L‖₁ over the band (the simple
//        per-band test, §6.2.2), otherwise reset — its applied lighting zeroed — and
//        approximated afresh. The N terms are dealt between bands by one ranking of
//        area(j) × |L_j − L̃_j| (incremental bands) or area(j) × |L_j| (reset bands).
//
// The per-band partial images of the thesis are not stored: resetting a band subtracts what
// it held from the image (T times its applied lighting, folded into the frame's ΔL), so the
// image is always T·L̃ and the memory beyond NWA is one image and one lighting vector.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "format/status.h"
#include "stages/relight/relight.h"

namespace ltb::stages {

enum class SequenceMethod { kNwa, kBi, kPbi };
Result<SequenceMethod> ParseSequenceMethod(const std::string& name);
const char* SequenceMethodName(SequenceMethod m);

// What one frame did in one band.
struct BandUpdate {
  uint32_t terms = 0;        // of the frame's budget
  bool incremental = true;   // false: the band was reset (zeroed) before its terms were applied
  uint32_t reset_terms = 0;  // columns the reset cleared that no new term replaced
};

struct FrameUpdate {
  // nwa: the applied lighting itself (the image is T times it). bi, pbi: its change, ΔL̃ —
  // the new terms' increments plus, for a reset band, the negation of what it held.
  LightTerms terms;
  bool absolute = false;
  uint64_t budget_terms = 0;  // terms of the budget N used (≤ N)
  std::vector<BandUpdate> bands;
};

class IncrementalLighting {
 public:
  IncrementalLighting(const LightingBasis& basis, SequenceMethod method, uint64_t terms, Weighting weighting,
                      std::vector<double> column_norms);

  // `lighting`: the frame's full lighting in the basis (6R² × 3).
  Status Step(const std::vector<float>& lighting, FrameUpdate* update);
  // L̃, the lighting applied so far, in the basis (6R² × 3).
  const std::vector<float>& applied() const { return applied_; }
  int bands() const { return static_cast<int>(band_columns_.size()); }
  // The band of a column: its wavelet level (see above); 0 for a pixel basis.
  int BandOf(uint64_t column) const { return band_of_[column]; }

 private:
  const LightingBasis& basis_;
  SequenceMethod method_;
  uint64_t terms_;
  Weighting weighting_;
  std::vector<double> norms_;
  std::vector<float> applied_, target_, delta_;
  std::vector<uint8_t> band_of_, touched_;
  std::vector<std::vector<uint32_t>> band_columns_;
};

}  // namespace ltb::stages
