#include "stages/column_transform/column_compressor.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <functional>
#include <string>

#if defined(__AVX2__)
#include <immintrin.h>
#endif

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
  c.sub_hist_.resize(kKeyBins * 4);
  c.cand_.reserve(c.pixels_);
  if (max_depth > 0) c.saved_.resize(kLanes * c.bands_[1].width * c.bands_[1].height);
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
               + p * kLanes * 4        // the caller's output chunk
               + p * kLanes;           // saved low bands (a quarter of the image, 4 bytes)
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

void ColumnCompressor::SelectTerms(size_t lane, int depth, uint64_t terms, std::vector<uint32_t>* kept) {
  UpdateKeys(lane, depth);
  const uint32_t* keys = keys_.data() + lane * pixels_;
  const uint32_t* hist = key_hist_.data() + lane * kKeyBins;
  const uint64_t positive = pixels_ - key_zeros_[lane];
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
  Candidates(keys, static_cast<uint32_t>(b));
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

void ColumnCompressor::Candidates(const uint32_t* keys, uint32_t bin) {
  // The positive keys of one histogram bin, in position order. Few keys match, so the
  // scan compares eight at a time and only touches the matches.
  cand_.clear();
  uint64_t p = 0;
#if defined(__AVX2__)
  const __m256i want = _mm256_set1_epi32(static_cast<int32_t>(bin));
  const __m256i zero = _mm256_setzero_si256();
  for (; p + 8 <= pixels_; p += 8) {
    __m256i k = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(keys + p));
    __m256i hit =
        _mm256_andnot_si256(_mm256_cmpeq_epi32(k, zero), _mm256_cmpeq_epi32(_mm256_srli_epi32(k, kKeyShift), want));
    unsigned m = static_cast<unsigned>(_mm256_movemask_ps(_mm256_castsi256_ps(hit)));
    while (m) {
      cand_.push_back(keys[p + static_cast<unsigned>(__builtin_ctz(m))]);
      m &= m - 1;
    }
  }
#endif
  for (; p < pixels_; ++p)
    if ((keys[p] >> kKeyShift) == bin && keys[p] != 0) cand_.push_back(keys[p]);
}

bool ColumnCompressor::CutTerms(size_t lane, int depth, const Selection& sel, double energy, Cut* cut) {
  if (reference_path_ || sel.kind != Selection::Kind::kTerms) return false;
  UpdateKeys(lane, depth);
  const uint32_t* keys = keys_.data() + lane * pixels_;
  const uint32_t* hist = key_hist_.data() + lane * kKeyBins;
  const uint64_t positive = pixels_ - key_zeros_[lane];
  const uint64_t n = std::min<uint64_t>(sel.terms, positive);
  *cut = Cut{};
  if (n == 0) {  // nothing to keep
    cut->t = INT32_MAX;
    return true;
  }
  uint32_t t;           // the smallest kept key
  if (n == positive) {  // every nonzero: keys > 0
    t = UINT32_MAX;
    uint64_t p = 0;
#if defined(__AVX2__)
    __m256i mv = _mm256_set1_epi32(-1);
    for (; p + 8 <= pixels_; p += 8) {
      const __m256i k = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(keys + p));
      mv = _mm256_min_epu32(mv, _mm256_or_si256(k, _mm256_cmpeq_epi32(k, _mm256_setzero_si256())));
    }
    alignas(32) uint32_t lanes[8];
    _mm256_store_si256(reinterpret_cast<__m256i*>(lanes), mv);
    for (uint32_t v : lanes) t = std::min(t, v);
#endif
    for (; p < pixels_; ++p) t = std::min(t, keys[p] == 0 ? UINT32_MAX : keys[p]);
    cut->t = 0;
  } else {
    // As SelectTerms: the bin of the n-th largest key, then selection within it.
    uint64_t above = 0;
    size_t b = kKeyBins - 1;
    while (above + hist[b] < n) above += hist[b--];
    Candidates(keys, static_cast<uint32_t>(b));
    const uint64_t r = n - above;
    std::nth_element(cand_.begin(), cand_.begin() + static_cast<std::ptrdiff_t>(r - 1), cand_.end(), std::greater<>());
    t = cand_[r - 1];
    for (uint32_t k : cand_) above += k > t;
    cut->t = t;
    cut->ties = n - above;
  }
  cut->n = n;
  // Select's trim drops kept terms with c²·‖ψ̃‖² <= trim; the smallest kept key is t.
  // Unweighted the key is |c|, so the test is exact; weighted, key² is c²‖ψ̃‖² to a few
  // float roundings, so a margin of 2^-18 (and a normal t) decides it safely.
  const double trim = kExactRelativeEnergy * energy / static_cast<double>(n);
  float tf;
  std::memcpy(&tf, &t, 4);
  const double m = static_cast<double>(tf) * static_cast<double>(tf);
  const bool weighted = !orthonormal_ && depth > 0;
  if (!weighted) return m > trim;
  return tf >= 0x1p-100f && m * (1.0 - 0x1p-18) > trim;
}

void ColumnCompressor::CutPass(int depth, const Cut* cut, bool weighted, double* error) {
  const float* rw = !orthonormal_ && depth > 0 ? root_weights_.data() + depth * pixels_ : nullptr;
  alignas(32) int32_t t[kLanes];
  alignas(32) int32_t tied[kLanes];  // −1 while lane k still keeps keys equal to t[k]
  uint64_t ties[kLanes];
  for (size_t k = 0; k < kLanes; ++k) {
    t[k] = static_cast<int32_t>(cut[k].t);
    ties[k] = cut[k].ties;
    tied[k] = ties[k] > 0 ? -1 : 0;
  }
  const float* c = coeffs_.data();
  float* work = work_.data();
  uint64_t p = 0;
#if defined(__AVX2__)
  static_assert(kLanes == 8);
  const __m256i tv = _mm256_load_si256(reinterpret_cast<const __m256i*>(t));
  __m256i tiedv = _mm256_load_si256(reinterpret_cast<const __m256i*>(tied));
  const __m256 abs_mask = _mm256_castsi256_ps(_mm256_set1_epi32(0x7fffffff));
  __m256d acc0 = _mm256_setzero_pd(), acc1 = _mm256_setzero_pd();
  for (; p < pixels_; ++p) {
    const __m256 v = _mm256_loadu_ps(c + p * kLanes);
    __m256 a = _mm256_and_ps(v, abs_mask);
    if (rw) a = _mm256_mul_ps(a, _mm256_set1_ps(rw[p]));
    const __m256i key = _mm256_castps_si256(a);
    __m256i kept = _mm256_cmpgt_epi32(key, tv);
    const __m256i eq = _mm256_and_si256(_mm256_cmpeq_epi32(key, tv), tiedv);
    if (!_mm256_testz_si256(eq, eq)) {  // keys equal to a threshold: the first `ties` are kept
      alignas(32) int32_t take[kLanes] = {};
      unsigned m = static_cast<unsigned>(_mm256_movemask_ps(_mm256_castsi256_ps(eq)));
      while (m) {
        unsigned k = static_cast<unsigned>(__builtin_ctz(m));
        take[k] = -1;
        if (--ties[k] == 0) tied[k] = 0;
        m &= m - 1;
      }
      kept = _mm256_or_si256(kept, _mm256_load_si256(reinterpret_cast<const __m256i*>(take)));
      tiedv = _mm256_load_si256(reinterpret_cast<const __m256i*>(tied));
    }
    if (weighted) {
      _mm256_storeu_ps(work + p * kLanes, _mm256_andnot_ps(_mm256_castsi256_ps(kept), v));
    } else {
      const __m256d d0 = _mm256_cvtps_pd(_mm256_castps256_ps128(v));
      const __m256d d1 = _mm256_cvtps_pd(_mm256_extractf128_ps(v, 1));
      const __m256d k0 = _mm256_castsi256_pd(_mm256_cvtepi32_epi64(_mm256_castsi256_si128(kept)));
      const __m256d k1 = _mm256_castsi256_pd(_mm256_cvtepi32_epi64(_mm256_extracti128_si256(kept, 1)));
      // Adding +0 for a kept term leaves the sum as it is: the per-lane sums are the
      // scalar loop's, in the same order.
      acc0 = _mm256_add_pd(acc0, _mm256_andnot_pd(k0, _mm256_mul_pd(d0, d0)));
      acc1 = _mm256_add_pd(acc1, _mm256_andnot_pd(k1, _mm256_mul_pd(d1, d1)));
    }
  }
  if (!weighted) {
    _mm256_storeu_pd(error, acc0);
    _mm256_storeu_pd(error + 4, acc1);
  }
#else
  double acc[kLanes] = {};
  for (; p < pixels_; ++p) {
    for (size_t k = 0; k < kLanes; ++k) {
      const float v = c[p * kLanes + k];
      float a = std::fabs(v);
      if (rw) a *= rw[p];
      uint32_t key;
      std::memcpy(&key, &a, 4);
      const uint32_t tk = static_cast<uint32_t>(t[k]);
      const bool kept = key > tk || (key == tk && ties[k] > 0 && ties[k]--);
      if (weighted) {
        work[p * kLanes + k] = kept ? 0.0f : v;
      } else if (!kept) {
        const double dv = v;
        acc[k] += dv * dv;
      }
    }
  }
  if (!weighted) std::copy(acc, acc + kLanes, error);
#endif
}

void ColumnCompressor::WorkEnergies(double* error) {
  const float* w = work_.data();
  uint64_t p = 0;
#if defined(__AVX2__)
  __m256d acc0 = _mm256_setzero_pd(), acc1 = _mm256_setzero_pd();
  for (; p < pixels_; ++p) {
    const __m256 v = _mm256_loadu_ps(w + p * kLanes);
    const __m256d d0 = _mm256_cvtps_pd(_mm256_castps256_ps128(v));
    const __m256d d1 = _mm256_cvtps_pd(_mm256_extractf128_ps(v, 1));
    acc0 = _mm256_add_pd(acc0, _mm256_mul_pd(d0, d0));
    acc1 = _mm256_add_pd(acc1, _mm256_mul_pd(d1, d1));
  }
  _mm256_storeu_pd(error, acc0);
  _mm256_storeu_pd(error + 4, acc1);
#else
  double acc[kLanes] = {};
  for (; p < pixels_; ++p)
    for (size_t k = 0; k < kLanes; ++k) {
      const double v = w[p * kLanes + k];
      acc[k] += v * v;
    }
  std::copy(acc, acc + kLanes, error);
#endif
}

namespace {

// Calls hit(i, key) for every i < n with key = keys[i] & mask >= t (t <= INT32_MAX), in
// order. Keys are float bits of non-negative values (< 2^31).
template <typename F>
void ScanAtLeast(const uint32_t* keys, uint64_t n, uint32_t t, uint32_t mask, F&& hit) {
  auto at = [&](uint64_t i) {  // (keys may be float storage)
    uint32_t v;
    std::memcpy(&v, reinterpret_cast<const char*>(keys) + 4 * i, 4);
    return v & mask;
  };
  uint64_t i = 0;
#if defined(__AVX2__)
  const __m256i tv = _mm256_set1_epi32(static_cast<int32_t>(t));
  const __m256i mv = _mm256_set1_epi32(static_cast<int32_t>(mask));
  for (; i + 8 <= n; i += 8) {
    const __m256i k = _mm256_and_si256(_mm256_loadu_si256(reinterpret_cast<const __m256i*>(keys + i)), mv);
    unsigned m = ~static_cast<unsigned>(_mm256_movemask_ps(_mm256_castsi256_ps(_mm256_cmpgt_epi32(tv, k)))) & 0xffu;
    while (m) {
      const unsigned j = static_cast<unsigned>(__builtin_ctz(m));
      hit(i + j, at(i + j));
      m &= m - 1;
    }
  }
#endif
  for (; i < n; ++i)
    if (at(i) >= t) hit(i, at(i));
}

}  // namespace

void ColumnCompressor::MaterializeCut(size_t lane, int depth, const Cut& cut, const float* column, ColumnChoice* out) {
  out->index.clear();
  out->value.clear();
  out->index.reserve(cut.n);
  out->value.reserve(cut.n);
  uint64_t ties = cut.ties;
  auto take = [&](uint64_t p, uint32_t key, float c) {
    if (key > cut.t || (key == cut.t && ties > 0 && ties--)) {
      out->index.push_back(static_cast<uint32_t>(p));
      out->value.push_back(c);
    }
  };
  if (depth == 0) {  // the pixels themselves: key |c|
    const uint32_t* bits = reinterpret_cast<const uint32_t*>(column);
    ScanAtLeast(bits, pixels_, cut.t, 0x7fffffffu, [&](uint64_t p, uint32_t key) { take(p, key, column[p]); });
    return;
  }
  // Outside this depth's low band, coefficients and keys are as they were at this depth
  // (later steps change only the low band); inside, the saved low band.
  const float* rw = !orthonormal_ ? root_weights_.data() + depth * pixels_ : nullptr;
  const wavelet::BandSize& lo = bands_[depth];
  const float* low = saved_.data() + lane * (saved_.size() / kLanes);
  const uint32_t* keys = keys_.data() + lane * pixels_;
  for (uint64_t y = 0; y < height_; ++y) {
    uint64_t x0 = 0;
    if (y < lo.height) {
      for (uint64_t x = 0; x < lo.width; ++x) {
        const uint64_t p = y * width_ + x;
        const float c = low[y * lo.width + x];
        float a = std::fabs(c);
        if (rw) a *= rw[p];
        uint32_t key;
        std::memcpy(&key, &a, 4);
        take(p, key, c);
      }
      x0 = lo.width;
    }
    const uint64_t row = y * width_;
    ScanAtLeast(keys + row + x0, width_ - x0, cut.t, 0xffffffffu, [&](uint64_t i, uint32_t key) {
      const uint64_t p = row + x0 + i;
      take(p, key, coeffs_[p * kLanes + lane]);
    });
  }
}

// Over 120 lines: the depth search keeps every SIMD lane's state (energy, live, deferred,
// key depth) in locals across the depths it tries.
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
  bool deferred[kLanes] = {};  // the best so far is a cut (built at the end)
  Cut best_cut[kLanes];
  uint64_t best_count[kLanes] = {};
  const uint64_t saved_stride = saved_.size() / kLanes;
  // The previous depth's cut and error, while the lane was on the cut path.
  bool prev_fast[kLanes] = {};
  Cut prev_cut[kLanes];
  double prev_error[kLanes] = {};
  std::fill(std::begin(key_depth_), std::end(key_depth_), -1);  // new columns: no keys yet
  columns_ = columns;
  for (int d = 0; d < first; ++d) {
    wavelet::AnalysisStep2D(filter_, coeffs_.data(), width_, kLanes, bands_[d].width, bands_[d].height,
                            scratch_.data());
  }
  for (int d = first; d <= last; ++d) {
    if (d > first) {
      wavelet::AnalysisStep2D(filter_, coeffs_.data(), width_, kLanes, bands_[d - 1].width, bands_[d - 1].height,
                              scratch_.data());
    }
    const bool weighted = !orthonormal_ && d > 0;
    bool active[kLanes] = {}, fast[kLanes] = {};
    double error[kLanes] = {};
    Cut cut[kLanes], pass[kLanes];
    for (Cut& c : pass) c.t = INT32_MAX;  // keeps nothing: the lane passes through whole
    bool any_fast = false, reconstruct = false;
    for (size_t k = 0; k < n; ++k) {
      if (!live[k]) continue;
      if (depth_override && depth_override[k] >= 0 ? depth_override[k] != d : d < min_depth_) continue;
      active[k] = true;
    }
    bool ranked[kLanes] = {};  // lanes whose selection ranks by keys
    for (size_t k = 0; k < n; ++k) ranked[k] = active[k] && selection[k].kind == Selection::Kind::kTerms;
    UpdateKeysGroup(d, ranked);
    bool same[kLanes] = {};  // the same kept set and error as depth d − 1
    for (size_t k = 0; k < n; ++k) {
      if (!active[k]) continue;
      // Going from d − 1 to d changes only the old low band. If it holds as many exact
      // zeros before as after, and every other key there, before and after, is above the
      // previous cut's threshold t > 0, its nonzeros are kept both times: the n-th largest
      // key, the ties and the kept terms elsewhere are unchanged, the dropped part is the
      // same values at the same positions (and signed zeros in the region, which change
      // no nonzero sum), and so is its error. Equal error and count never win over the
      // best, which was compared with depth d − 1 already.
      if (d >= 2 && prev_fast[k] && key_depth_[k] == d && !reference_path_ &&
          selection[k].kind == Selection::Kind::kTerms && prev_cut[k].t > 0 &&
          region_[k].before.zeros == region_[k].now.zeros && region_[k].before.min_key > prev_cut[k].t &&
          region_[k].now.min_key > prev_cut[k].t) {
        same[k] = fast[k] = true;
        cut[k] = prev_cut[k];
        error[k] = prev_error[k];
        continue;
      }
      fast[k] = CutTerms(k, d, selection[k], energy[k], &cut[k]);
      if (fast[k]) {
        pass[k] = cut[k];
        any_fast = true;
      } else {
        Select(k, d, selection[k], energy[k], &kept[k], &error[k]);
        reconstruct |= error[k] < 0;
      }
    }
    if (weighted && (any_fast || reconstruct)) {
      // Biorthogonal: reconstruct the dropped part of every active lane and measure it
      // in pixels (lanes on the explicit path drop all but their kept list).
      CutPass(d, pass, true, nullptr);
      for (size_t k = 0; k < kLanes; ++k)
        if (active[k] && !fast[k])
          for (uint32_t p : kept[k]) work_[p * kLanes + k] = 0.0f;
      for (int l = d; l-- > 0;) {
        wavelet::SynthesisStep2D(filter_, work_.data(), width_, kLanes, bands_[l].width, bands_[l].height,
                                 scratch_.data());
      }
      double e[kLanes];
      WorkEnergies(e);
      for (size_t k = 0; k < kLanes; ++k)
        if (active[k] && !same[k]) error[k] = e[k];
    } else if (any_fast) {
      double e[kLanes];
      CutPass(d, pass, false, e);
      for (size_t k = 0; k < kLanes; ++k)
        if (fast[k] && !same[k]) error[k] = e[k];
    }
    for (size_t k = 0; k < kLanes; ++k) {
      prev_fast[k] = active[k] && fast[k];
      prev_cut[k] = cut[k];
      prev_error[k] = error[k];
    }
    for (size_t k = 0; k < n; ++k) {
      if (!active[k]) continue;
      ColumnChoice& best = out[k];
      const uint64_t count = fast[k] ? cut[k].n : kept[k].size();
      double tol = kExactRelativeEnergy * energy[k];
      bool take;
      if (!have[k]) {
        take = true;
      } else if (error[k] <= tol && best.error <= tol) {
        take = count < best_count[k];  // both exact: fewer nonzeros; a tie keeps the shallower
      } else {
        take = error[k] < best.error;
      }
      if (!take) continue;
      have[k] = true;
      best.depth = d;
      best.error = error[k];
      best_count[k] = count;
      deferred[k] = fast[k];
      if (fast[k]) {
        best_cut[k] = cut[k];
        if (d > 0) {  // keep this depth's low band: deeper steps overwrite it
          const wavelet::BandSize& lo = bands_[d];
          float* dst = saved_.data() + k * saved_stride;
          for (uint64_t y = 0; y < lo.height; ++y)
            for (uint64_t x = 0; x < lo.width; ++x) dst[y * lo.width + x] = coeffs_[(y * width_ + x) * kLanes + k];
        }
      } else {
        best.index = kept[k];
        best.value.resize(kept[k].size());
        for (size_t i = 0; i < kept[k].size(); ++i) best.value[i] = coeffs_[kept[k][i] * kLanes + k];
      }
    }
  }
  columns_ = nullptr;
  for (size_t k = 0; k < n; ++k)
    if (deferred[k]) MaterializeCut(k, out[k].depth, best_cut[k], columns[k], &out[k]);
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
