#include "stages/wavelet/wavelet.h"

#include <algorithm>
#include <cstring>

#include "format/bits.h"

namespace ltb::wavelet {
namespace {

// Analysis low-pass filters as PyWavelets defines them (dec_lo); the high-pass is
// dec_hi[j] = (-1)^(j+1) dec_lo[F-1-j].
constexpr double kHaar[] = {0.7071067811865476, 0.7071067811865476};
constexpr double kDb2[] = {-0.12940952255126037, 0.2241438680420134, 0.8365163037378079, 0.48296291314453416};
constexpr double kDb3[] = {0.03522629188570953, -0.08544127388202666, -0.13501102001025458,
                           0.45987750211849154, 0.8068915093110925,   0.33267055295008263};
constexpr double kDb4[] = {-0.010597401785069032, 0.0328830116668852, 0.030841381835560764, -0.18703481171909309,
                           -0.027983769416859854, 0.6308807679298589, 0.7148465705529157,   0.2303778133088965};

// JPEG 2000 Part 1 (ITU-T T.800 Annex F) 9/7 irreversible lifting constants.
constexpr double kAlpha = -1.586134342059924;
constexpr double kBeta = -0.052980118572961;
constexpr double kGamma = 0.882911075530934;
constexpr double kDelta = 0.443506852043971;
constexpr double kK = 1.230174104914001;

struct Taps {
  const double* lo;
  int size;
};

Taps OrthoTaps(Filter f) {
  switch (f) {
    case Filter::kHaar:
      return {kHaar, 2};
    case Filter::kDb2:
      return {kDb2, 4};
    case Filter::kDb3:
      return {kDb3, 6};
    case Filter::kDb4:
      return {kDb4, 8};
    default:
      return {nullptr, 0};
  }
}

// Copies n samples of `lanes` values between a strided signal and a packed buffer.
template <typename T>
void Pack(const T* data, size_t n, size_t stride, size_t lanes, T* out) {
  for (size_t i = 0; i < n; ++i) std::memcpy(out + i * lanes, data + i * stride, lanes * sizeof(T));
}
template <typename T>
void Unpack(const T* in, size_t n, size_t stride, size_t lanes, T* data) {
  for (size_t i = 0; i < n; ++i) std::memcpy(data + i * stride, in + i * lanes, lanes * sizeof(T));
}

// y += c * x over lanes.
template <typename T>
inline void Axpy(T* __restrict y, const T* __restrict x, T c, size_t lanes) {
  for (size_t l = 0; l < lanes; ++l) y[l] += c * x[l];
}

// k mod n for k within a few periods of [0, n): tap offsets are at most F/2 out of range,
// so this is one or two additions where `%` would be an integer division per tap.
inline size_t Wrap(long long k, size_t n) {
  const long long nn = static_cast<long long>(n);
  while (k < 0) k += nn;
  while (k >= nn) k -= nn;
  return static_cast<size_t>(k);
}

// Periodized orthonormal analysis, PyWavelets indexing:
//   a[o] = Σ_j lo[j] x[(2o + F/2 - j) mod n],  d[o] = Σ_j hi[j] x[(2o + F/2 - j) mod n].
// F (taps) and L (lanes; 0 = given at run time) are compile-time so the lane loop is a
// few vector operations. Every path accumulates from 0 in ascending j, so a lane's
// result is bit-identical whichever path computed it.
template <typename T, int F, size_t L>
void OrthoAnalysisImpl(const double* taps, T* data, size_t n, size_t stride, size_t lanes_rt, T* scratch) {
  const size_t lanes = L ? L : lanes_rt;
  const size_t half = n / 2;
  T lo[F], hi[F];
  for (int j = 0; j < F; ++j) {
    lo[j] = static_cast<T>(taps[j]);
    hi[j] = static_cast<T>(((j & 1) ? 1.0 : -1.0) * taps[F - 1 - j]);
  }
  for (size_t o = 0; o < half; ++o) {
    const T* x[F];
    for (int j = 0; j < F; ++j) x[j] = data + Wrap(static_cast<long long>(2 * o) + F / 2 - j, n) * stride;
    T* __restrict lo_out = scratch + o * lanes;
    T* __restrict hi_out = scratch + (half + o) * lanes;
    if constexpr (L != 0) {
      // Short fixed lanes: accumulate in registers.
      for (size_t l = 0; l < lanes; ++l) {
        T a = 0, d = 0;
        for (int j = 0; j < F; ++j) {
          a += lo[j] * x[j][l];
          d += hi[j] * x[j][l];
        }
        lo_out[l] = a;
        hi_out[l] = d;
      }
    } else {
      // Long lanes (a whole band row): stream each tap over the lanes, the same sums in
      // the same order.
      std::fill(lo_out, lo_out + lanes, T(0));
      std::fill(hi_out, hi_out + lanes, T(0));
      for (int j = 0; j < F; ++j) {
        Axpy(lo_out, x[j], lo[j], lanes);
        Axpy(hi_out, x[j], hi[j], lanes);
      }
    }
  }
  if (stride == lanes)
    std::memcpy(data, scratch, n * lanes * sizeof(T));
  else
    Unpack(scratch, n, stride, lanes, data);
}

template <typename T, int F>
void OrthoAnalysisTaps(const double* taps, T* data, size_t n, size_t stride, size_t lanes, T* scratch) {
  if (lanes == 16)
    OrthoAnalysisImpl<T, F, 16>(taps, data, n, stride, lanes, scratch);
  else
    OrthoAnalysisImpl<T, F, 0>(taps, data, n, stride, lanes, scratch);
}

template <typename T>
void OrthoAnalysis(Taps t, T* data, size_t n, size_t stride, size_t lanes, T* scratch) {
  switch (t.size) {
    case 2:
      return OrthoAnalysisTaps<T, 2>(t.lo, data, n, stride, lanes, scratch);
    case 4:
      return OrthoAnalysisTaps<T, 4>(t.lo, data, n, stride, lanes, scratch);
    case 6:
      return OrthoAnalysisTaps<T, 6>(t.lo, data, n, stride, lanes, scratch);
    case 8:
      return OrthoAnalysisTaps<T, 8>(t.lo, data, n, stride, lanes, scratch);
  }
}

// The transpose of OrthoAnalysis (its inverse, the filters being orthonormal).
template <typename T>
void OrthoSynthesis(Taps t, T* data, size_t n, size_t stride, size_t lanes, T* scratch) {
  size_t half = n / 2;
  std::fill(scratch, scratch + n * lanes, T(0));
  for (size_t o = 0; o < half; ++o) {
    const T* a = data + o * stride;
    const T* d = data + (half + o) * stride;
    for (int j = 0; j < t.size; ++j) {
      T* x = scratch + Wrap(static_cast<long long>(2 * o) + t.size / 2 - j, n) * lanes;
      T lo = static_cast<T>(t.lo[j]);
      T hi = static_cast<T>(((j & 1) ? 1.0 : -1.0) * t.lo[t.size - 1 - j]);
      Axpy(x, a, lo, lanes);
      Axpy(x, d, hi, lanes);
    }
  }
  Unpack(scratch, n, stride, lanes, data);
}

// Whole-sample symmetric extension: index -1 -> 1, n -> n-2.
inline size_t Mirror(long long i, size_t n) {
  if (i < 0) return static_cast<size_t>(-i);
  if (i >= static_cast<long long>(n)) return static_cast<size_t>(2 * (static_cast<long long>(n) - 1) - i);
  return static_cast<size_t>(i);
}

// x[p] += c * (x[p-1] + x[p+1]) for every p of the given parity, in natural order (n >= 2).
template <typename T>
void Lift(T* x, size_t n, size_t lanes, size_t parity, T c) {
  for (size_t p = parity; p < n; p += 2) {
    T* y = x + p * lanes;
    const T* a = x + Mirror(static_cast<long long>(p) - 1, n) * lanes;
    const T* b = x + Mirror(static_cast<long long>(p) + 1, n) * lanes;
    for (size_t l = 0; l < lanes; ++l) y[l] += c * (a[l] + b[l]);
  }
}

template <typename T>
void Scale(T* x, size_t n, size_t lanes, size_t parity, T c) {
  for (size_t p = parity; p < n; p += 2) {
    T* y = x + p * lanes;
    for (size_t l = 0; l < lanes; ++l) y[l] *= c;
  }
}

// LeGall 5/3 in one pass per direction. The two lifting steps
//   predict  d_i = x_{2i+1} + (-1/2)(x_{2i} + x_{2i+2}),
//   update   s_i = x_{2i}   + (1/4)(d_{i-1} + d_i)
// (whole-sample symmetric extension, so x_n = x_{n-2}, d_{-1} = d_0 and, for odd n, the last
// s takes d_{low-2} twice) are computed sample by sample from the natural-order signal: the
// low band is written in place (s_i over sample i, which no later sample needs) and the high
// band through the scratch buffer. Each value is the same expression of the same operands
// as the two separate lifting passes (no contraction: -ffp-contract=off), so results are
// identical bit for bit; the gain is the memory passes (one read and 1.5 writes instead
// of a pack, two lifting passes and an unpack). L: lanes at compile time (0 = lanes_rt).
template <typename T, size_t L>
void LeGallAnalysisImpl(T* data, size_t n, size_t stride, size_t lanes_rt, T* scratch) {
  const size_t lanes = L ? L : lanes_rt;
  const size_t low = LowCount(n), high = n - low;
  const T cp = T(-0.5), cu = T(0.25);
  for (size_t i = 0; i < low; ++i) {
    if (i < high) {
      const T* __restrict e = data + 2 * i * stride;
      const T* __restrict o = e + stride;
      const T* __restrict f = 2 * i + 2 < n ? o + stride : e;
      T* __restrict d = scratch + i * lanes;
      for (size_t l = 0; l < lanes; ++l) d[l] = o[l] + cp * (e[l] + f[l]);
    }
    const T* dl = scratch + (i > 0 ? i - 1 : 0) * lanes;
    const T* dr = scratch + (i < high ? i : i - 1) * lanes;
    const T* e = data + 2 * i * stride;
    T* s = data + i * stride;  // s_i over x_i: e is x_{2i}, the same row only at i = 0
    for (size_t l = 0; l < lanes; ++l) s[l] = e[l] + cu * (dl[l] + dr[l]);
  }
  if (stride == lanes)
    std::memcpy(data + low * stride, scratch, high * lanes * sizeof(T));
  else
    Unpack(scratch, high, stride, lanes, data + low * stride);
}

// The inverse, as the two lifting passes of the synthesis:
//   x_{2i}   = s_i + (-1/4)(d_{i-1} + d_i),   x_{2i+1} = d_i + (1/2)(x_{2i} + x_{2i+2}).
// The low band is copied to the scratch buffer first; the output is then written in place
// in natural order, even samples one ahead of the odd ones. Writing x_{2i+2} over row 2i+2
// destroys d_{2i+2-low}: a value no later sample reads except at i = low − 2, where it is
// d_i itself, still needed for x_{2i+1}; that one row is saved first. Row 2i+1 holds
// d_{2i+1-low}, never one after d_i.
template <typename T, size_t L>
void LeGallSynthesisImpl(T* data, size_t n, size_t stride, size_t lanes_rt, T* scratch) {
  const size_t lanes = L ? L : lanes_rt;
  const size_t low = LowCount(n), high = n - low;
  const T cu = T(-0.25), cp = T(0.5);
  if (stride == lanes)
    std::memcpy(scratch, data, low * lanes * sizeof(T));
  else
    Pack(data, low, stride, lanes, scratch);
  const T* dband = data + low * stride;
  auto even = [&](size_t k) {  // x_{2k} from s_k (scratch) and the high band (rows low..)
    const T* __restrict s = scratch + k * lanes;
    const T* dl = dband + (k > 0 ? k - 1 : 0) * stride;
    const T* dr = dband + (k < high ? k : k - 1) * stride;
    T* x = data + 2 * k * stride;
    for (size_t l = 0; l < lanes; ++l) x[l] = s[l] + cu * (dl[l] + dr[l]);
  };
  T* saved = scratch + low * lanes;  // one row (high >= 1)
  even(0);
  for (size_t i = 0; i < high; ++i) {
    const T* d = dband + i * stride;
    if (i + 2 == low) {
      std::memcpy(saved, d, lanes * sizeof(T));
      d = saved;
    }
    if (i + 1 < low) even(i + 1);
    const T* e = data + 2 * i * stride;
    const T* f = 2 * i + 2 < n ? e + 2 * stride : e;
    T* o = data + (2 * i + 1) * stride;
    for (size_t l = 0; l < lanes; ++l) o[l] = d[l] + cp * (e[l] + f[l]);
  }
}

// One LeGall 5/3 step either way, the lane count compiled in where it is a common one (8:
// the column-transform search; 16: row blocks), else given at run time.
template <typename T, size_t L>
void LeGallStep(bool inverse, T* data, size_t n, size_t stride, size_t lanes, T* scratch) {
  if (inverse)
    LeGallSynthesisImpl<T, L>(data, n, stride, lanes, scratch);
  else
    LeGallAnalysisImpl<T, L>(data, n, stride, lanes, scratch);
}

template <typename T>
void LeGall(bool inverse, T* data, size_t n, size_t stride, size_t lanes, T* scratch) {
  if (lanes == 8) return LeGallStep<T, 8>(inverse, data, n, stride, lanes, scratch);
  if (lanes == 16) return LeGallStep<T, 16>(inverse, data, n, stride, lanes, scratch);
  LeGallStep<T, 0>(inverse, data, n, stride, lanes, scratch);
}

// CDF 9/7: lifting runs in natural (interleaved) order in the scratch buffer; the data
// holds the Mallat order (even samples = low band first, odd = high band after).
template <typename T>
void BiorthAnalysis(Filter f, T* data, size_t n, size_t stride, size_t lanes, T* scratch) {
  if (f == Filter::kLeGall53) return LeGall(false, data, n, stride, lanes, scratch);
  Pack(data, n, stride, lanes, scratch);
  Lift(scratch, n, lanes, 1, static_cast<T>(kAlpha));
  Lift(scratch, n, lanes, 0, static_cast<T>(kBeta));
  Lift(scratch, n, lanes, 1, static_cast<T>(kGamma));
  Lift(scratch, n, lanes, 0, static_cast<T>(kDelta));
  Scale(scratch, n, lanes, 1, static_cast<T>(kK));
  Scale(scratch, n, lanes, 0, static_cast<T>(1.0 / kK));
  size_t low = LowCount(n);
  for (size_t p = 0; p < n; ++p) {
    size_t dst = (p & 1) ? low + p / 2 : p / 2;
    std::memcpy(data + dst * stride, scratch + p * lanes, lanes * sizeof(T));
  }
}

template <typename T>
void BiorthSynthesis(Filter f, T* data, size_t n, size_t stride, size_t lanes, T* scratch) {
  if (f == Filter::kLeGall53) return LeGall(true, data, n, stride, lanes, scratch);
  size_t low = LowCount(n);
  for (size_t p = 0; p < n; ++p) {
    size_t src = (p & 1) ? low + p / 2 : p / 2;
    std::memcpy(scratch + p * lanes, data + src * stride, lanes * sizeof(T));
  }
  Scale(scratch, n, lanes, 0, static_cast<T>(kK));
  Scale(scratch, n, lanes, 1, static_cast<T>(1.0 / kK));
  Lift(scratch, n, lanes, 0, static_cast<T>(-kDelta));
  Lift(scratch, n, lanes, 1, static_cast<T>(-kGamma));
  Lift(scratch, n, lanes, 0, static_cast<T>(-kBeta));
  Lift(scratch, n, lanes, 1, static_cast<T>(-kAlpha));
  Unpack(scratch, n, stride, lanes, data);
}

}  // namespace

Result<Filter> ParseFilter(const std::string& name) {
  if (name == "haar" || name == "db1") return Filter::kHaar;
  if (name == "db2") return Filter::kDb2;
  if (name == "db3") return Filter::kDb3;
  if (name == "db4") return Filter::kDb4;
  if (name == "legall53") return Filter::kLeGall53;
  if (name == "cdf97") return Filter::kCdf97;
  return InvalidArgument("unknown wavelet filter \"" + name + "\" (known: haar, db1, db2, db3, db4, legall53, cdf97)");
}

const char* FilterName(Filter f) {
  switch (f) {
    case Filter::kHaar:
      return "haar";
    case Filter::kDb2:
      return "db2";
    case Filter::kDb3:
      return "db3";
    case Filter::kDb4:
      return "db4";
    case Filter::kLeGall53:
      return "legall53";
    case Filter::kCdf97:
      return "cdf97";
  }
  return "?";
}

bool IsOrthonormal(Filter f) { return f != Filter::kLeGall53 && f != Filter::kCdf97; }

std::span<const double> OrthoLowPass(Filter f) {
  Taps t = OrthoTaps(f);
  return {t.lo, static_cast<size_t>(t.size)};
}

int MaxDepth(size_t width, size_t height) {
  int d = 0;
  while (width > 1 || height > 1) {
    width = LowCount(width);
    height = LowCount(height);
    ++d;
  }
  return d;
}

std::vector<BandSize> BandSizes(size_t width, size_t height, int depth) {
  std::vector<BandSize> out{{width, height}};
  for (int l = 0; l < depth; ++l) {
    width = LowCount(width);
    height = LowCount(height);
    out.push_back({width, height});
  }
  return out;
}

Status CheckSize(Filter f, size_t width, size_t height) {
  if (width == 0 || height == 0) return InvalidArgument("empty image");
  if (IsOrthonormal(f) && (!IsPowerOfTwo(width) || !IsPowerOfTwo(height))) {
    return InvalidArgument(std::string("filter ") + FilterName(f) + " needs power-of-two sizes, got " +
                           std::to_string(width) + "x" + std::to_string(height) +
                           " (legall53 and cdf97 take any size)");
  }
  return Status::Ok();
}

template <typename T>
void AnalysisStep1D(Filter f, T* data, size_t n, size_t stride, size_t lanes, T* scratch) {
  if (n < 2) return;
  if (IsOrthonormal(f))
    OrthoAnalysis(OrthoTaps(f), data, n, stride, lanes, scratch);
  else
    BiorthAnalysis(f, data, n, stride, lanes, scratch);
}

template <typename T>
void SynthesisStep1D(Filter f, T* data, size_t n, size_t stride, size_t lanes, T* scratch) {
  if (n < 2) return;
  if (IsOrthonormal(f))
    OrthoSynthesis(OrthoTaps(f), data, n, stride, lanes, scratch);
  else
    BiorthSynthesis(f, data, n, stride, lanes, scratch);
}

template <typename T>
void Forward1D(Filter f, T* data, size_t n, size_t stride, size_t lanes, int depth, T* scratch) {
  for (int l = 0; l < depth && n > 1; ++l) {
    AnalysisStep1D(f, data, n, stride, lanes, scratch);
    n = LowCount(n);
  }
}

template <typename T>
void Inverse1D(Filter f, T* data, size_t n, size_t stride, size_t lanes, int depth, T* scratch) {
  std::vector<size_t> sizes{n};
  for (int l = 0; l < depth && sizes.back() > 1; ++l) sizes.push_back(LowCount(sizes.back()));
  for (size_t l = sizes.size() - 1; l-- > 0;) SynthesisStep1D(f, data, sizes[l], stride, lanes, scratch);
}

template <typename T>
void AnalysisStep2D(Filter f, T* data, size_t width, size_t lanes, size_t band_w, size_t band_h, T* scratch) {
  // Row step: each of the band's rows is one signal of band_w samples.
  if (band_w > 1) {
    for (size_t y = 0; y < band_h; ++y) AnalysisStep1D(f, data + y * width * lanes, band_w, lanes, lanes, scratch);
  }
  // Column step: the band_w pixels of an image row are contiguous, so a whole row of the
  // band is one "sample" of band_w * lanes values.
  if (band_h > 1) AnalysisStep1D(f, data, band_h, width * lanes, band_w * lanes, scratch);
}

template <typename T>
void SynthesisStep2D(Filter f, T* data, size_t width, size_t lanes, size_t band_w, size_t band_h, T* scratch) {
  if (band_h > 1) SynthesisStep1D(f, data, band_h, width * lanes, band_w * lanes, scratch);
  if (band_w > 1) {
    for (size_t y = 0; y < band_h; ++y) SynthesisStep1D(f, data + y * width * lanes, band_w, lanes, lanes, scratch);
  }
}

template <typename T>
void Forward2D(Filter f, T* data, size_t width, size_t height, size_t lanes, int depth, T* scratch) {
  auto sizes = BandSizes(width, height, depth);
  for (int l = 0; l < depth; ++l) AnalysisStep2D(f, data, width, lanes, sizes[l].width, sizes[l].height, scratch);
}

template <typename T>
void Inverse2D(Filter f, T* data, size_t width, size_t height, size_t lanes, int depth, T* scratch) {
  auto sizes = BandSizes(width, height, depth);
  for (int l = depth; l-- > 0;) SynthesisStep2D(f, data, width, lanes, sizes[l].width, sizes[l].height, scratch);
}

#define LTB_INSTANTIATE(T)                                                          \
  template void AnalysisStep1D<T>(Filter, T*, size_t, size_t, size_t, T*);          \
  template void SynthesisStep1D<T>(Filter, T*, size_t, size_t, size_t, T*);         \
  template void Forward1D<T>(Filter, T*, size_t, size_t, size_t, int, T*);          \
  template void Inverse1D<T>(Filter, T*, size_t, size_t, size_t, int, T*);          \
  template void AnalysisStep2D<T>(Filter, T*, size_t, size_t, size_t, size_t, T*);  \
  template void SynthesisStep2D<T>(Filter, T*, size_t, size_t, size_t, size_t, T*); \
  template void Forward2D<T>(Filter, T*, size_t, size_t, size_t, int, T*);          \
  template void Inverse2D<T>(Filter, T*, size_t, size_t, size_t, int, T*);
LTB_INSTANTIATE(float)
LTB_INSTANTIATE(double)
#undef LTB_INSTANTIATE

}  // namespace ltb::wavelet
