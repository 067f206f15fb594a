#include "stages/wavelet/face_kernel.h"

#include <cstring>

#if defined(__AVX2__)
#include <immintrin.h>
#endif

namespace ltb::wavelet {
namespace {

// Tap j of an F-tap filter reads x[(2o + F/2 - j) mod n]: with k = F/2 - j, that is the
// even sample E[o + k/2] for even k and the odd sample O[o + (k-1)/2] for odd k.
constexpr int TapOffset(int f, int j) { return f / 2 - j; }
constexpr bool TapIsOdd(int f, int j) { return (TapOffset(f, j) & 1) != 0; }
constexpr int TapShift(int f, int j) { return (TapOffset(f, j) - (TapOffset(f, j) & 1)) / 2; }

template <int F>
struct Coefs {
  float lo[F], hi[F];
};

// The same float taps as wavelet.cpp's OrthoAnalysisImpl.
template <int F>
Coefs<F> MakeCoefs(std::span<const double> taps) {
  Coefs<F> c;
  for (int j = 0; j < F; ++j) {
    c.lo[j] = static_cast<float>(taps[j]);
    c.hi[j] = static_cast<float>(((j & 1) ? 1.0 : -1.0) * taps[F - 1 - j]);
  }
  return c;
}

// One level in portable code, for any band side w >= 2 (a power of two).
// Row step: the w rows of `in` (row y at in + y * in_stride) into h (w × w, packed): each
// row's low half then its high half. Column step: from h, the low-low quadrant to `ll`
// (stride ll_stride), the other three to dst (stride dst_stride) at their Mallat places.
template <int F>
void RowStepScalar(const Coefs<F>& c, const float* in, size_t in_stride, size_t w, float* h) {
  const size_t half = w / 2, mask = w - 1;
  for (size_t y = 0; y < w; ++y) {
    const float* row = in + y * in_stride;
    float* out = h + y * w;
    for (size_t o = 0; o < half; ++o) {
      float a = 0, d = 0;
      for (int j = 0; j < F; ++j) {
        const float x = row[(2 * o + w * 4 + TapOffset(F, j)) & mask];
        a += c.lo[j] * x;
        d += c.hi[j] * x;
      }
      out[o] = a;
      out[half + o] = d;
    }
  }
}

template <int F>
void ColumnStepScalar(const Coefs<F>& c, const float* h, size_t w, float* ll, size_t ll_stride, float* dst,
                      size_t dst_stride) {
  const size_t half = w / 2, mask = w - 1;
  for (size_t o = 0; o < half; ++o) {
    const float* rows[F];
    for (int j = 0; j < F; ++j) rows[j] = h + ((2 * o + w * 4 + TapOffset(F, j)) & mask) * w;
    for (size_t x = 0; x < w; ++x) {
      float a = 0, d = 0;
      for (int j = 0; j < F; ++j) {
        a += c.lo[j] * rows[j][x];
        d += c.hi[j] * rows[j][x];
      }
      if (x < half) ll[o * ll_stride + x] = a;
      else dst[o * dst_stride + x] = a;
      dst[(half + o) * dst_stride + x] = d;
    }
  }
}

#if defined(__AVX2__)
template <int F>
struct VecCoefs {
  __m256 lo[F], hi[F];
  explicit VecCoefs(const Coefs<F>& c) {
    for (int j = 0; j < F; ++j) {
      lo[j] = _mm256_set1_ps(c.lo[j]);
      hi[j] = _mm256_set1_ps(c.hi[j]);
    }
  }
};

// result[i] = v[(i + S) mod 8].
template <int S>
inline __m256 Rotate(__m256 v) {
  const __m256i idx = _mm256_setr_epi32((0 + S) & 7, (1 + S) & 7, (2 + S) & 7, (3 + S) & 7, (4 + S) & 7, (5 + S) & 7,
                                        (6 + S) & 7, (7 + S) & 7);
  return _mm256_permutevar8x32_ps(v, idx);
}

// Elements 8m + S .. 8m + S + 7 of the periodic sequence held in v[0 .. nv) (|S| < 8).
template <int S>
inline __m256 Shifted(const __m256* v, size_t m, size_t nv) {
  if constexpr (S == 0) {
    return v[m];
  } else if constexpr (S > 0) {  // the last S lanes come from the next vector
    const __m256 a = Rotate<S>(v[m]), b = Rotate<S>(v[m + 1 == nv ? 0 : m + 1]);
    return _mm256_blend_ps(a, b, (0xFF << (8 - S)) & 0xFF);
  } else {  // the first -S lanes come from the previous vector
    const __m256 a = Rotate<S>(v[m]), b = Rotate<S>(v[m == 0 ? nv - 1 : m - 1]);
    return _mm256_blend_ps(a, b, (1 << (-S)) - 1);
  }
}

// a += lo[j] * x_j, d += hi[j] * x_j for j = J .. F-1, in that order.
template <int F, int J = 0>
inline void AccumulateRow(const VecCoefs<F>& c, const __m256* e, const __m256* od, size_t m, size_t nv, __m256& a,
                          __m256& d) {
  if constexpr (J < F) {
    const __m256 x = TapIsOdd(F, J) ? Shifted<TapShift(F, J)>(od, m, nv) : Shifted<TapShift(F, J)>(e, m, nv);
    a = _mm256_add_ps(a, _mm256_mul_ps(c.lo[J], x));
    d = _mm256_add_ps(d, _mm256_mul_ps(c.hi[J], x));
    AccumulateRow<F, J + 1>(c, e, od, m, nv, a, d);
  }
}

// Row step for w >= 16: per row, deinterleave into even and odd vectors, then each tap is
// a (shifted) whole vector.
template <int F>
void RowStepWide(const VecCoefs<F>& c, const float* in, size_t in_stride, size_t w, float* h) {
  const size_t nv = w / 16, half = w / 2;
  __m256 e[kMaxFaceRes / 16], od[kMaxFaceRes / 16];
  for (size_t y = 0; y < w; ++y) {
    const float* row = in + y * in_stride;
    for (size_t m = 0; m < nv; ++m) {
      const __m256 p = _mm256_loadu_ps(row + 16 * m), q = _mm256_loadu_ps(row + 16 * m + 8);
      // [x0 x2 x8 x10 | x4 x6 x12 x14] -> [x0 x2 x4 x6 | x8 x10 x12 x14], same for odd.
      const __m256 te = _mm256_shuffle_ps(p, q, _MM_SHUFFLE(2, 0, 2, 0));
      const __m256 to = _mm256_shuffle_ps(p, q, _MM_SHUFFLE(3, 1, 3, 1));
      e[m] = _mm256_castpd_ps(_mm256_permute4x64_pd(_mm256_castps_pd(te), _MM_SHUFFLE(3, 1, 2, 0)));
      od[m] = _mm256_castpd_ps(_mm256_permute4x64_pd(_mm256_castps_pd(to), _MM_SHUFFLE(3, 1, 2, 0)));
    }
    float* out = h + y * w;
    for (size_t m = 0; m < nv; ++m) {
      __m256 a = _mm256_setzero_ps(), d = _mm256_setzero_ps();
      AccumulateRow<F>(c, e, od, m, nv, a, d);
      _mm256_storeu_ps(out + 8 * m, a);
      _mm256_storeu_ps(out + half + 8 * m, d);
    }
  }
}

// result[i] = v[4 * (i / 4) + (i + S) mod 4]: a rotation inside each 128-bit half.
template <int S>
inline __m256 RotateHalves(__m256 v) {
  constexpr int s = S & 3;
  return _mm256_permute_ps(v, _MM_SHUFFLE((3 + s) & 3, (2 + s) & 3, (1 + s) & 3, s));
}

template <int F, int J = 0>
inline void AccumulateRow8(const VecCoefs<F>& c, __m256 e, __m256 od, __m256& a, __m256& d) {
  if constexpr (J < F) {
    const __m256 x = TapIsOdd(F, J) ? RotateHalves<TapShift(F, J)>(od) : RotateHalves<TapShift(F, J)>(e);
    a = _mm256_add_ps(a, _mm256_mul_ps(c.lo[J], x));
    d = _mm256_add_ps(d, _mm256_mul_ps(c.hi[J], x));
    AccumulateRow8<F, J + 1>(c, e, od, a, d);
  }
}

// Row step for w = 8: two rows per vector (one per 128-bit half), four even and four odd
// samples each, so the periodic shifts stay inside a half.
template <int F>
void RowStep8(const VecCoefs<F>& c, const float* in, size_t in_stride, float* h) {
  for (size_t y = 0; y < 8; y += 2) {
    const __m256 r0 = _mm256_loadu_ps(in + y * in_stride), r1 = _mm256_loadu_ps(in + (y + 1) * in_stride);
    const __m256 p = _mm256_permute2f128_ps(r0, r1, 0x20), q = _mm256_permute2f128_ps(r0, r1, 0x31);
    const __m256 e = _mm256_shuffle_ps(p, q, _MM_SHUFFLE(2, 0, 2, 0));
    const __m256 od = _mm256_shuffle_ps(p, q, _MM_SHUFFLE(3, 1, 3, 1));
    __m256 a = _mm256_setzero_ps(), d = _mm256_setzero_ps();
    AccumulateRow8<F>(c, e, od, a, d);
    _mm256_storeu_ps(h + y * 8, _mm256_permute2f128_ps(a, d, 0x20));
    _mm256_storeu_ps(h + (y + 1) * 8, _mm256_permute2f128_ps(a, d, 0x31));
  }
}

// Column step for w >= 8: each output row pair is F whole rows of h, 8 columns at a time.
template <int F>
void ColumnStepVec(const VecCoefs<F>& c, const float* h, size_t w, float* ll, size_t ll_stride, float* dst,
                   size_t dst_stride) {
  const size_t half = w / 2, mask = w - 1;
  for (size_t o = 0; o < half; ++o) {
    const float* rows[F];
    for (int j = 0; j < F; ++j) rows[j] = h + ((2 * o + w * 4 + TapOffset(F, j)) & mask) * w;
    float* lo_row = dst + o * dst_stride;
    float* hi_row = dst + (half + o) * dst_stride;
    for (size_t x = 0; x < w; x += 8) {
      __m256 a = _mm256_setzero_ps(), d = _mm256_setzero_ps();
      for (int j = 0; j < F; ++j) {
        const __m256 v = _mm256_loadu_ps(rows[j] + x);
        a = _mm256_add_ps(a, _mm256_mul_ps(c.lo[j], v));
        d = _mm256_add_ps(d, _mm256_mul_ps(c.hi[j], v));
      }
      if (w == 8) {
        _mm_storeu_ps(ll + o * ll_stride, _mm256_castps256_ps128(a));
        _mm_storeu_ps(lo_row + 4, _mm256_extractf128_ps(a, 1));
      } else if (x < half) {
        _mm256_storeu_ps(ll + o * ll_stride + x, a);
      } else {
        _mm256_storeu_ps(lo_row + x, a);
      }
      _mm256_storeu_ps(hi_row + x, d);
    }
  }
}
#endif

template <int F>
void ForwardFaceT(const Coefs<F>& c, size_t r, const float* src, float* dst, float* scratch) {
  if (r == 1) {
    dst[0] = src[0];
    return;
  }
#if defined(__AVX2__)
  const VecCoefs<F> vc(c);
#endif
  float* h = scratch;
  float* low[2] = {scratch + r * r, scratch + r * r + (r / 2) * (r / 2)};
  const float* in = src;
  size_t in_stride = r;
  int p = 0;
  // Level 0 reads all of src into h before anything is written to dst, and later levels
  // read only scratch: src == dst is safe.
  for (size_t w = r; w >= 2; w /= 2, p ^= 1) {
    float* ll = w == 2 ? dst : low[p];  // the last low band is the single value dst[0]
    const size_t ll_stride = w == 2 ? r : w / 2;
#if defined(__AVX2__)
    if (w >= 16) {
      RowStepWide<F>(vc, in, in_stride, w, h);
      ColumnStepVec<F>(vc, h, w, ll, ll_stride, dst, r);
    } else if (w == 8) {
      RowStep8<F>(vc, in, in_stride, h);
      ColumnStepVec<F>(vc, h, w, ll, ll_stride, dst, r);
    } else
#endif
    {
      RowStepScalar<F>(c, in, in_stride, w, h);
      ColumnStepScalar<F>(c, h, w, ll, ll_stride, dst, r);
    }
    in = ll;
    in_stride = ll_stride;
  }
}

template <int F>
const Coefs<F>& CoefsFor(Filter f) {
  // One table per tap count; the filters of a tap count are a single one.
  static const Coefs<F> c = MakeCoefs<F>(OrthoLowPass(f));
  return c;
}

bool IsPowerOfTwo(size_t v) { return v != 0 && (v & (v - 1)) == 0; }

}  // namespace

bool HasFaceKernel(Filter f, size_t r) { return IsOrthonormal(f) && IsPowerOfTwo(r) && r <= kMaxFaceRes; }

void ForwardFace(Filter f, size_t r, const float* src, float* dst, float* scratch) {
  switch (f) {
    case Filter::kHaar: return ForwardFaceT<2>(CoefsFor<2>(f), r, src, dst, scratch);
    case Filter::kDb2: return ForwardFaceT<4>(CoefsFor<4>(f), r, src, dst, scratch);
    case Filter::kDb3: return ForwardFaceT<6>(CoefsFor<6>(f), r, src, dst, scratch);
    case Filter::kDb4: return ForwardFaceT<8>(CoefsFor<8>(f), r, src, dst, scratch);
    default: return;
  }
}

}  // namespace ltb::wavelet
