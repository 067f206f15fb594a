#include "stages/column_transform/column_compressor.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <functional>
#include <string>

#include "stages/column_transform/column_codec.h"

namespace ltb::stages {

namespace {

// 2^(k/8) for k = 0..7.
const std::array<double, kBinsPerOctave>& OctaveSteps() {
  static const std::array<double, kBinsPerOctave> steps = [] {
    std::array<double, kBinsPerOctave> s{};
    for (int k = 0; k < kBinsPerOctave; ++k) s[k] = std::exp2(static_cast<double>(k) / kBinsPerOctave);
    return s;
  }();
  return steps;
}

int FloorDiv(int a, int b) { return a >= 0 ? a / b : -((-a + b - 1) / b); }

}  // namespace

int EnergyBin(double e) {
  int ex = 0;
  double f = std::frexp(e, &ex);  // e = f · 2^ex, f in [0.5, 1)
  double m = 2.0 * f;             // [1, 2)
  const auto& steps = OctaveSteps();
  int k = 0;
  while (k + 1 < kBinsPerOctave && m >= steps[k + 1]) ++k;
  return kBinsPerOctave * (ex - 1) + k;
}

double BinLowerEdge(int bin) {
  int octave = FloorDiv(bin, kBinsPerOctave);
  return std::ldexp(OctaveSteps()[bin - octave * kBinsPerOctave], octave);
}

Result<ColumnCompressor> ColumnCompressor::Create(wavelet::Filter filter, uint64_t width, uint64_t height,
                                                  int min_depth, int max_depth) {
  if (max_depth > 0) LTB_RETURN_IF_ERROR(wavelet::CheckSize(filter, width, height));
  int deepest = wavelet::MaxDepth(width, height);
  if (min_depth < 0 || max_depth < min_depth || max_depth > deepest) {
    return InvalidArgument("depths " + std::to_string(min_depth) + ".." + std::to_string(max_depth) +
                           " are outside 0.." + std::to_string(deepest) + " for a " + std::to_string(width) + "x" +
                           std::to_string(height) + " image");
  }
  ColumnCompressor c;
  c.filter_ = filter;
  c.orthonormal_ = wavelet::IsOrthonormal(filter);
  c.width_ = width;
  c.height_ = height;
  c.pixels_ = width * height;
  c.min_depth_ = min_depth;
  c.max_depth_ = max_depth;
  c.bands_ = wavelet::BandSizes(width, height, max_depth);
  c.coeffs_.resize(c.pixels_ * kLanes);
  c.scratch_.resize(wavelet::ScratchSize(width, height, kLanes));
  c.mag_.resize(c.pixels_);
  c.bins_.resize(c.pixels_);
  c.keys_.resize(c.pixels_ * kLanes);
  c.key_hist_.resize(kKeyBins * kLanes);
  c.weights_.resize(max_depth + 1);
  if (!c.orthonormal_ && max_depth > 0) {
    c.work_.resize(c.pixels_ * kLanes);
    c.weights_ = SynthesisEnergies(filter, width, height, max_depth);
    c.root_weights_.resize((max_depth + 1) * c.pixels_);
    for (int d = 0; d <= max_depth; ++d)
      for (uint64_t p = 0; p < c.pixels_; ++p)
        c.root_weights_[d * c.pixels_ + p] = static_cast<float>(std::sqrt(c.weights_[d][p]));
  }
  return c;
}

uint64_t ColumnCompressor::WorkingBytes(uint64_t width, uint64_t height, int max_depth, bool orthonormal) {
  uint64_t p = width * height;
  uint64_t b = p * kLanes * 4 * 3      // coefficients, wavelet scratch, selection keys
               + p * (8 + 4 + 4)       // weighted energies, bins, candidates
               + p * kLanes * (4 + 4)  // kept positions and values per lane (worst case)
               + p * kLanes * 4;       // the caller's output chunk
  if (!orthonormal) b += p * kLanes * 4 + p * (8 + 4) * static_cast<uint64_t>(max_depth + 1);
  return b;
}

Status ColumnCompressor::Load(const float* const* columns, size_t n, double* energy, bool* live) {
  std::fill(coeffs_.begin(), coeffs_.end(), 0.0f);
  for (size_t k = 0; k < n; ++k) {
    const float* col = columns[k];
    double e = 0;
    bool finite = true;
    uint64_t bad = 0;
    for (uint64_t p = 0; p < pixels_; ++p) {
      float v = col[p];
      finite &= std::isfinite(v);
      double dv = v;
      e += dv * dv;
      coeffs_[p * kLanes + k] = v;
    }
    if (!finite) {
      while (std::isfinite(col[bad])) ++bad;
      return InvalidArgument("column " + std::to_string(k) + " of this group: pixel " + std::to_string(bad) + " (x " +
                             std::to_string(bad % width_) + ", y " + std::to_string(bad / width_) + ") is " +
                             std::to_string(col[bad]) + "; the transport matrix must be finite");
    }
    energy[k] = e;
    live[k] = e > 0;
  }
  return Status::Ok();
}

void ColumnCompressor::UpdateKeys(size_t lane, int depth) {
  uint32_t* keys = keys_.data() + lane * pixels_;
  uint32_t* hist = key_hist_.data() + lane * kKeyBins;
  const float* rw = !orthonormal_ && depth > 0 ? root_weights_.data() + depth * pixels_ : nullptr;
  auto key = [&](uint64_t p) {
    float k = std::fabs(coeffs_[p * kLanes + lane]);
    if (rw) k *= rw[p];
    uint32_t bits;
    std::memcpy(&bits, &k, 4);
    return bits;
  };
  if (depth > 0 && key_depth_[lane] == depth - 1) {
    // Only the previous low band changed (and, biorthogonal, its weights).
    const auto& band = bands_[depth - 1];
    for (uint64_t y = 0; y < band.height; ++y)
      for (uint64_t x = 0; x < band.width; ++x) {
        uint64_t p = y * width_ + x;
        hist[keys[p] >> kKeyShift]--;
        keys[p] = key(p);
        hist[keys[p] >> kKeyShift]++;
      }
  } else {
    std::fill(hist, hist + kKeyBins, 0u);
    for (uint64_t p = 0; p < pixels_; ++p) {
      keys[p] = key(p);
      hist[keys[p] >> kKeyShift]++;
    }
  }
  key_depth_[lane] = depth;
}

void ColumnCompressor::SelectTerms(size_t lane, int depth, uint64_t terms, std::vector<uint32_t>* kept) {
  UpdateKeys(lane, depth);
  const uint32_t* keys = keys_.data() + lane * pixels_;
  const uint32_t* hist = key_hist_.data() + lane * kKeyBins;
  // Positive keys: all but the zeros, which sit in bin 0.
  uint64_t zeros = 0;
  if (hist[0] > 0)
    for (uint64_t p = 0; p < pixels_; ++p) zeros += keys[p] == 0;
  const uint64_t positive = pixels_ - zeros;
  const uint64_t n = std::min<uint64_t>(terms, positive);
  if (n == 0) return;
  if (n == positive) {
    for (uint64_t p = 0; p < pixels_; ++p)
      if (keys[p] != 0) kept->push_back(static_cast<uint32_t>(p));
    return;
  }
  // The bin holding the n-th largest key, then selection within it.
  uint64_t above = 0;
  size_t b = kKeyBins - 1;
  while (above + hist[b] < n) above += hist[b--];
  cand_.clear();
  for (uint64_t p = 0; p < pixels_; ++p)
    if ((keys[p] >> kKeyShift) == b && keys[p] != 0) cand_.push_back(keys[p]);
  const uint64_t r = n - above;  // 1 <= r <= cand_.size()
  std::nth_element(cand_.begin(), cand_.begin() + static_cast<std::ptrdiff_t>(r - 1), cand_.end(), std::greater<>());
  const uint32_t t = cand_[r - 1];
  for (uint32_t k : cand_) above += k > t;
  uint64_t ties = n - above;  // keys equal to t, taken in position order
  for (uint64_t p = 0; p < pixels_; ++p) {
    if (keys[p] > t || (keys[p] == t && ties > 0 && ties--)) kept->push_back(static_cast<uint32_t>(p));
  }
}

void ColumnCompressor::Select(size_t lane, int depth, const Selection& sel, double energy, std::vector<uint32_t>* kept,
                              double* dropped) {
  kept->clear();
  const bool weighted = !orthonormal_ && depth > 0;
  const double trim_total = kExactRelativeEnergy * energy;
  if (sel.kind == Selection::Kind::kTerms) {
    SelectTerms(lane, depth, sel.terms, kept);
    // Rounding residue: kept terms whose total is within the exactness tolerance add
    // nothing measurable and are dropped.
    if (!kept->empty()) {
      const double trim = trim_total / static_cast<double>(kept->size());
      const double* w = weighted ? weights_[depth].data() : nullptr;
      kept->erase(std::remove_if(kept->begin(), kept->end(),
                                 [&](uint32_t p) {
                                   double c = coeffs_[p * kLanes + lane];
                                   return c * c * (w ? w[p] : 1.0) <= trim;
                                 }),
                  kept->end());
    }
  } else {
    const double* w = weighted ? weights_[depth].data() : nullptr;
    uint64_t extra = sel.terms;
    for (uint64_t p = 0; p < pixels_; ++p) {
      double c = coeffs_[p * kLanes + lane];
      double m = c * c * (w ? w[p] : 1.0);
      if (m <= 0) continue;
      int b = EnergyBin(m);
      if (b >= sel.threshold_bin || (b == sel.threshold_bin - 1 && extra > 0 && extra--)) {
        kept->push_back(static_cast<uint32_t>(p));
      }
    }
    if (!kept->empty()) {
      const double trim = trim_total / static_cast<double>(kept->size());
      kept->erase(std::remove_if(kept->begin(), kept->end(),
                                 [&](uint32_t p) {
                                   double c = coeffs_[p * kLanes + lane];
                                   return c * c * (w ? w[p] : 1.0) <= trim;
                                 }),
                  kept->end());
    }
  }
  *dropped = -1;
  if (!weighted) {  // orthonormal or pixels: the error is the dropped energy (Parseval)
    double e = 0;
    auto it = kept->begin();
    for (uint64_t p = 0; p < pixels_; ++p) {
      if (it != kept->end() && *it == p) {
        ++it;
        continue;
      }
      double c = coeffs_[p * kLanes + lane];
      e += c * c;
    }
    *dropped = e;
  }
}

void ColumnCompressor::Errors(int depth, const std::vector<uint32_t>* kept, const bool* active, double* error) {
  // Biorthogonal: reconstruct the dropped part and measure it in pixels.
  std::copy(coeffs_.begin(), coeffs_.end(), work_.begin());
  for (size_t k = 0; k < kLanes; ++k)
    if (active[k])
      for (uint32_t p : kept[k]) work_[p * kLanes + k] = 0.0f;
  for (int l = depth; l-- > 0;) {
    wavelet::SynthesisStep2D(filter_, work_.data(), width_, kLanes, bands_[l].width, bands_[l].height, scratch_.data());
  }
  for (size_t k = 0; k < kLanes; ++k) {
    if (!active[k]) continue;
    double e = 0;
    for (uint64_t p = 0; p < pixels_; ++p) {
      double v = work_[p * kLanes + k];
      e += v * v;
    }
    error[k] = e;
  }
}

Status ColumnCompressor::Choose(const float* const* columns, size_t n, const Selection* selection,
                                const int* depth_override, ColumnChoice* out) {
  double energy[kLanes] = {};
  bool live[kLanes] = {};
  LTB_RETURN_IF_ERROR(Load(columns, n, energy, live));
  int first = max_depth_, last = min_depth_;
  for (size_t k = 0; k < n; ++k) {
    out[k] = ColumnChoice{};
    out[k].depth = min_depth_;
    out[k].energy = energy[k];
    if (!live[k]) continue;
    int lo = depth_override && depth_override[k] >= 0 ? depth_override[k] : min_depth_;
    int hi = depth_override && depth_override[k] >= 0 ? depth_override[k] : max_depth_;
    first = std::min(first, lo);
    last = std::max(last, hi);
  }
  if (first > last) return Status::Ok();  // every column is empty
  std::vector<uint32_t> kept[kLanes];
  bool have[kLanes] = {};
  std::fill(std::begin(key_depth_), std::end(key_depth_), -1);  // new columns: no keys yet
  for (int d = 0; d < first; ++d) {
    wavelet::AnalysisStep2D(filter_, coeffs_.data(), width_, kLanes, bands_[d].width, bands_[d].height,
                            scratch_.data());
  }
  for (int d = first; d <= last; ++d) {
    if (d > first) {
      wavelet::AnalysisStep2D(filter_, coeffs_.data(), width_, kLanes, bands_[d - 1].width, bands_[d - 1].height,
                              scratch_.data());
    }
    bool active[kLanes] = {};
    double error[kLanes] = {};
    bool reconstruct = false;
    for (size_t k = 0; k < n; ++k) {
      if (!live[k]) continue;
      if (depth_override && depth_override[k] >= 0 ? depth_override[k] != d : d < min_depth_) continue;
      active[k] = true;
      Select(k, d, selection[k], energy[k], &kept[k], &error[k]);
      reconstruct |= error[k] < 0;
    }
    if (reconstruct) Errors(d, kept, active, error);
    for (size_t k = 0; k < n; ++k) {
      if (!active[k]) continue;
      ColumnChoice& best = out[k];
      double tol = kExactRelativeEnergy * energy[k];
      bool take;
      if (!have[k]) {
        take = true;
      } else if (error[k] <= tol && best.error <= tol) {
        take = kept[k].size() < best.index.size();  // both exact: fewer nonzeros; a tie keeps the shallower
      } else {
        take = error[k] < best.error;
      }
      if (!take) continue;
      have[k] = true;
      best.depth = d;
      best.error = error[k];
      best.index = kept[k];
      best.value.resize(kept[k].size());
      for (size_t i = 0; i < kept[k].size(); ++i) best.value[i] = coeffs_[kept[k][i] * kLanes + k];
    }
  }
  return Status::Ok();
}

Status ColumnCompressor::Histograms(const float* const* columns, size_t n, EnergyHistogram* out, double* energy) {
  bool live[kLanes] = {};
  LTB_RETURN_IF_ERROR(Load(columns, n, energy, live));
  for (size_t i = 0; i < n * static_cast<size_t>(depths()); ++i) out[i] = EnergyHistogram{};
  for (int d = 0; d < min_depth_; ++d) {
    wavelet::AnalysisStep2D(filter_, coeffs_.data(), width_, kLanes, bands_[d].width, bands_[d].height,
                            scratch_.data());
  }
  for (int d = min_depth_; d <= max_depth_; ++d) {
    if (d > min_depth_) {
      wavelet::AnalysisStep2D(filter_, coeffs_.data(), width_, kLanes, bands_[d - 1].width, bands_[d - 1].height,
                              scratch_.data());
    }
    const bool weighted = !orthonormal_ && d > 0;
    for (size_t k = 0; k < n; ++k) {
      if (!live[k]) continue;
      int lo = INT32_MAX, hi = INT32_MIN;
      for (uint64_t p = 0; p < pixels_; ++p) {
        double c = coeffs_[p * kLanes + k];
        double m = c * c;
        if (weighted) m *= weights_[d][p];
        mag_[p] = m;
        if (m > 0) {
          int b = EnergyBin(m);
          bins_[p] = b;
          lo = std::min(lo, b);
          hi = std::max(hi, b);
        }
      }
      EnergyHistogram& h = out[k * depths() + (d - min_depth_)];
      if (lo > hi) continue;
      size_t span = static_cast<size_t>(hi - lo) + 1;
      hist_count_.assign(span, 0);
      hist_energy_.assign(span, 0.0);
      for (uint64_t p = 0; p < pixels_; ++p) {
        if (mag_[p] > 0) {
          hist_count_[bins_[p] - lo]++;
          hist_energy_[bins_[p] - lo] += mag_[p];
        }
      }
      for (size_t i = 0; i < span; ++i) {
        if (hist_count_[i] == 0) continue;
        h.bin.push_back(lo + static_cast<int32_t>(i));
        h.count.push_back(hist_count_[i]);
        h.energy.push_back(hist_energy_[i]);
      }
    }
  }
  return Status::Ok();
}

}  // namespace ltb::stages
