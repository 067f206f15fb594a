#include "stages/relight/incremental.h"

#include <algorithm>
#include <cmath>

namespace ltb::stages {

Result<SequenceMethod> ParseSequenceMethod(const std::string& name) {
  if (name == "nwa") return SequenceMethod::kNwa;
  if (name == "bi") return SequenceMethod::kBi;
  if (name == "pbi") return SequenceMethod::kPbi;
  return InvalidArgument("--method \"" + name + "\": a lighting sequence takes nwa, bi or pbi");
}

const char* SequenceMethodName(SequenceMethod m) {
  switch (m) {
    case SequenceMethod::kNwa:
      return "nwa";
    case SequenceMethod::kBi:
      return "bi";
    case SequenceMethod::kPbi:
      return "pbi";
  }
  return "?";
}

IncrementalLighting::IncrementalLighting(const LightingBasis& basis, SequenceMethod method, uint64_t terms,
                                         Weighting weighting, std::vector<double> column_norms)
    : basis_(basis), method_(method), terms_(terms), weighting_(weighting), norms_(std::move(column_norms)) {
  const uint64_t r = basis.cube_res(), n = 6 * r * r;
  applied_.assign(n * 3, 0.0f);
  target_.assign(n * 3, 0.0f);
  delta_.assign(n * 3, 0.0f);
  touched_.assign(n, 0);
  band_of_.assign(n, 0);
  int levels = 1;
  if (basis.wavelet()) {
    while ((uint64_t{1} << levels) < r) ++levels;  // log2 R bands (R ≥ 2)
    for (uint64_t j = 0; j < n; ++j) {
      const uint64_t p = j % (r * r), m = std::max(p % r, p / r);
      band_of_[j] = static_cast<uint8_t>(m <= 1 ? 0 : 63 - __builtin_clzll(m));
    }
  }
  band_columns_.resize(levels);
  for (uint64_t j = 0; j < n; ++j) band_columns_[band_of_[j]].push_back(static_cast<uint32_t>(j));
}

Status IncrementalLighting::Step(const std::vector<float>& lighting, FrameUpdate* u) {
  const size_t nb = band_columns_.size();
  u->bands.assign(nb, BandUpdate{});
  u->terms.column.clear();
  u->terms.rgb.clear();
  u->absolute = method_ == SequenceMethod::kNwa;
  if (lighting.size() != applied_.size()) return InvalidArgument("lighting has the wrong size for the basis");

  // The per-band test (§6.2.2, L1 norms): is L closer to L̃ than to 0?
  for (size_t b = 0; b < nb; ++b) {
    bool incremental = method_ == SequenceMethod::kBi;
    if (method_ == SequenceMethod::kPbi) {
      double diff = 0, full = 0;
      for (uint32_t j : band_columns_[b])
        for (int c = 0; c < 3; ++c) {
          diff += std::fabs(static_cast<double>(lighting[j * 3 + c]) - applied_[j * 3 + c]);
          full += std::fabs(lighting[j * 3 + c]);
        }
      incremental = diff < full;
    }
    u->bands[b].incremental = incremental;
  }
  // What each term would bring: the difference in incremental bands, the value in reset ones.
  for (size_t b = 0; b < nb; ++b)
    for (uint32_t j : band_columns_[b])
      for (int c = 0; c < 3; ++c)
        target_[j * 3 + c] = lighting[j * 3 + c] - (u->bands[b].incremental ? applied_[j * 3 + c] : 0.0f);
  LightTerms chosen;
  LTB_RETURN_IF_ERROR(basis_.SelectTerms(target_.data(), terms_, weighting_, norms_, &chosen));
  u->budget_terms = chosen.column.size();

  if (u->absolute) {  // nwa: L̃ is the approximation itself
    std::fill(applied_.begin(), applied_.end(), 0.0f);
    for (size_t k = 0; k < chosen.column.size(); ++k) {
      const uint32_t j = chosen.column[k];
      for (int c = 0; c < 3; ++c) applied_[j * 3 + c] = lighting[j * 3 + c];
      u->bands[band_of_[j]].terms++;
      u->bands[band_of_[j]].incremental = false;
    }
    for (auto& b : u->bands) b.incremental = false;
    u->terms = std::move(chosen);
    return Status::Ok();
  }

  std::vector<uint32_t> changed;
  auto touch = [&](uint32_t j) {
    if (!touched_[j]) {
      touched_[j] = 1;
      changed.push_back(j);
    }
  };
  // Reset bands give back what they held.
  for (size_t b = 0; b < nb; ++b) {
    if (u->bands[b].incremental) continue;
    for (uint32_t j : band_columns_[b]) {
      float* a = &applied_[j * 3];
      if (a[0] == 0 && a[1] == 0 && a[2] == 0) continue;
      touch(j);
      for (int c = 0; c < 3; ++c) {
        delta_[j * 3 + c] -= a[c];
        a[c] = 0.0f;
      }
    }
  }
  // The chosen terms bring their band's applied lighting up to L there.
  for (size_t k = 0; k < chosen.column.size(); ++k) {
    const uint32_t j = chosen.column[k];
    touch(j);
    u->bands[band_of_[j]].terms++;
    for (int c = 0; c < 3; ++c) {
      delta_[j * 3 + c] += lighting[j * 3 + c] - applied_[j * 3 + c];
      applied_[j * 3 + c] = lighting[j * 3 + c];
    }
  }
  std::sort(changed.begin(), changed.end());
  for (uint32_t j : changed) {
    float* d = &delta_[j * 3];
    if (d[0] != 0 || d[1] != 0 || d[2] != 0) {
      u->terms.column.push_back(j);
      u->terms.rgb.insert(u->terms.rgb.end(), d, d + 3);
      if (!std::binary_search(chosen.column.begin(), chosen.column.end(), j)) u->bands[band_of_[j]].reset_terms++;
    }
    d[0] = d[1] = d[2] = 0.0f;
    touched_[j] = 0;
  }
  return Status::Ok();
}

}  // namespace ltb::stages
