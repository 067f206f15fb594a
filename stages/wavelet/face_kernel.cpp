#include "stages/wavelet/face_kernel.h"

#include <cstring>

#include "format/bits.h"

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

// Bit-identity with Forward2D, whose sums all start from 0 (0 + p0 + p1 + ...): a sum that
// starts at p0 instead differs from it only when both are zero, in the zero's sign (0 + x
// is x except 0 + -0 = +0). The row steps here skip that first addition; every value the
// kernel outputs comes from a column step, which keeps it, and a zero's sign in its inputs
// changes only the sign of zero products, so the outputs are bit-identical all the same
// (a sum started from +0 is never -0 in round-to-nearest).
//
// Every level function takes its band side as a template argument W (a power of two, fully
// unrolled loops) or, with W = 0, as the run-time argument w.
//
// Row step: the w rows of `in` (row y at in + y * in_stride) into h (w × w, packed): each
// row's low half then its high half. Column step: from h, the low-low quadrant to `ll`
// (stride ll_stride), the other three to dst (stride dst_stride) at their Mallat places.
template <int F, size_t W>
void RowStepScalar(const Coefs<F>& c, const float* in, size_t in_stride, size_t w_rt, float* h) {
  const size_t w = W ? W : w_rt, half = w / 2, mask = w - 1;
  for (size_t y = 0; y < w; ++y) {
    const float* row = in + y * in_stride;
    float* out = h + y * w;
    for (size_t o = 0; o < half; ++o) {
      const float x0 = row[(2 * o + w * 4 + TapOffset(F, 0)) & mask];
      float a = c.lo[0] * x0, d = c.hi[0] * x0;
      for (int j = 1; j < F; ++j) {
        const float x = row[(2 * o + w * 4 + TapOffset(F, j)) & mask];
        a += c.lo[j] * x;
        d += c.hi[j] * x;
      }
      out[o] = a;
      out[half + o] = d;
    }
  }
}

template <int F, size_t W>
void ColumnStepScalar(const Coefs<F>& c, const float* h, size_t w_rt, float* ll, size_t ll_stride, float* dst,
                      size_t dst_stride) {
  const size_t w = W ? W : w_rt, half = w / 2, mask = w - 1;
  for (size_t o = 0; o < half; ++o) {
    const float* rows[F];
    for (int j = 0; j < F; ++j) rows[j] = h + ((2 * o + w * 4 + TapOffset(F, j)) & mask) * w;
    for (size_t x = 0; x < w; ++x) {
      float a = 0, d = 0;
      for (int j = 0; j < F; ++j) {
        a += c.lo[j] * rows[j][x];
        d += c.hi[j] * rows[j][x];
      }
      if (x < half)
        ll[o * ll_stride + x] = a;
      else
        dst[o * dst_stride + x] = a;
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

// a = Σ lo[j] x_j, d = Σ hi[j] x_j, in ascending j, the first product not added to 0 (see
// RowStepScalar: the result differs from 0 + ... only in the sign of a zero).
template <int F, int J = 0>
inline void AccumulateRow(const VecCoefs<F>& c, const __m256* e, const __m256* od, size_t m, size_t nv, __m256& a,
                          __m256& d) {
  if constexpr (J < F) {
    __m256 x;
    if constexpr (TapIsOdd(F, J))
      x = Shifted<TapShift(F, J)>(od, m, nv);
    else
      x = Shifted<TapShift(F, J)>(e, m, nv);
    if constexpr (J == 0) {
      a = _mm256_mul_ps(c.lo[J], x);
      d = _mm256_mul_ps(c.hi[J], x);
    } else {
      a = _mm256_add_ps(a, _mm256_mul_ps(c.lo[J], x));
      d = _mm256_add_ps(d, _mm256_mul_ps(c.hi[J], x));
    }
    AccumulateRow<F, J + 1>(c, e, od, m, nv, a, d);
  }
}

// Row step for w >= 16: per row, deinterleave into even and odd vectors, then each tap is
// a (shifted) whole vector.
template <int F, size_t W>
void RowStepWide(const VecCoefs<F>& c, const float* in, size_t in_stride, size_t w_rt, float* h) {
  const size_t w = W ? W : w_rt, nv = w / 16, half = w / 2;
  __m256 e[W ? W / 16 : kMaxFaceRes / 16], od[W ? W / 16 : kMaxFaceRes / 16];
  for (size_t y = 0; y < w; ++y) {
    const float* row = in + y * in_stride;
#pragma GCC unroll 8
    for (size_t m = 0; m < nv; ++m) {
      const __m256 p = _mm256_loadu_ps(row + 16 * m), q = _mm256_loadu_ps(row + 16 * m + 8);
      // [x0 x2 x8 x10 | x4 x6 x12 x14] -> [x0 x2 x4 x6 | x8 x10 x12 x14], same for odd.
      const __m256 te = _mm256_shuffle_ps(p, q, _MM_SHUFFLE(2, 0, 2, 0));
      const __m256 to = _mm256_shuffle_ps(p, q, _MM_SHUFFLE(3, 1, 3, 1));
      e[m] = _mm256_castpd_ps(_mm256_permute4x64_pd(_mm256_castps_pd(te), _MM_SHUFFLE(3, 1, 2, 0)));
      od[m] = _mm256_castpd_ps(_mm256_permute4x64_pd(_mm256_castps_pd(to), _MM_SHUFFLE(3, 1, 2, 0)));
    }
    float* out = h + y * w;
#pragma GCC unroll 8
    for (size_t m = 0; m < nv; ++m) {
      __m256 a, d;
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
    if constexpr (J == 0) {
      a = _mm256_mul_ps(c.lo[J], x);
      d = _mm256_mul_ps(c.hi[J], x);
    } else {
      a = _mm256_add_ps(a, _mm256_mul_ps(c.lo[J], x));
      d = _mm256_add_ps(d, _mm256_mul_ps(c.hi[J], x));
    }
    AccumulateRow8<F, J + 1>(c, e, od, a, d);
  }
}

// Row step for w = 8: two rows per vector (one per 128-bit half), four even and four odd
// samples each, so the periodic shifts stay inside a half.
template <int F>
void RowStep8(const VecCoefs<F>& c, const float* in, size_t in_stride, float* h) {
#pragma GCC unroll 4
  for (size_t y = 0; y < 8; y += 2) {
    const __m256 r0 = _mm256_loadu_ps(in + y * in_stride), r1 = _mm256_loadu_ps(in + (y + 1) * in_stride);
    const __m256 p = _mm256_permute2f128_ps(r0, r1, 0x20), q = _mm256_permute2f128_ps(r0, r1, 0x31);
    const __m256 e = _mm256_shuffle_ps(p, q, _MM_SHUFFLE(2, 0, 2, 0));
    const __m256 od = _mm256_shuffle_ps(p, q, _MM_SHUFFLE(3, 1, 3, 1));
    __m256 a, d;
    AccumulateRow8<F>(c, e, od, a, d);
    _mm256_storeu_ps(h + y * 8, _mm256_permute2f128_ps(a, d, 0x20));
    _mm256_storeu_ps(h + (y + 1) * 8, _mm256_permute2f128_ps(a, d, 0x31));
  }
}

template <int F, int J = 0>
inline void AccumulateRow4(const VecCoefs<F>& c, __m256 e, __m256 e1, __m256 od, __m256 od1, __m256& a, __m256& d) {
  if constexpr (J < F) {
    constexpr bool kOdd = TapIsOdd(F, J), kShifted = (TapShift(F, J) & 1) != 0;
    const __m256 x = kOdd ? (kShifted ? od1 : od) : (kShifted ? e1 : e);
    if constexpr (J == 0) {
      a = _mm256_mul_ps(c.lo[J], x);
      d = _mm256_mul_ps(c.hi[J], x);
    } else {
      a = _mm256_add_ps(a, _mm256_mul_ps(c.lo[J], x));
      d = _mm256_add_ps(d, _mm256_mul_ps(c.hi[J], x));
    }
    AccumulateRow4<F, J + 1>(c, e, e1, od, od1, a, d);
  }
}

// Row step for w = 4 on a packed band (in_stride 4): two rows per vector, two even and two
// odd samples each (duplicated), so a periodic shift by one swaps them.
template <int F>
void RowStep4(const VecCoefs<F>& c, const float* in, float* h) {
#pragma GCC unroll 2
  for (size_t y = 0; y < 4; y += 2) {
    const __m256 v = _mm256_loadu_ps(in + y * 4);
    const __m256 e = _mm256_shuffle_ps(v, v, _MM_SHUFFLE(2, 0, 2, 0));
    const __m256 e1 = _mm256_shuffle_ps(v, v, _MM_SHUFFLE(0, 2, 0, 2));
    const __m256 od = _mm256_shuffle_ps(v, v, _MM_SHUFFLE(3, 1, 3, 1));
    const __m256 od1 = _mm256_shuffle_ps(v, v, _MM_SHUFFLE(1, 3, 1, 3));
    __m256 a, d;
    AccumulateRow4<F>(c, e, e1, od, od1, a, d);
    _mm256_storeu_ps(h + y * 4, _mm256_shuffle_ps(a, d, _MM_SHUFFLE(1, 0, 1, 0)));
  }
}

// Column step for w = 4: a band row is one 128-bit vector.
template <int F>
void ColumnStep4(const VecCoefs<F>& c, const float* h, float* ll, size_t ll_stride, float* dst, size_t dst_stride) {
#pragma GCC unroll 2
  for (size_t o = 0; o < 2; ++o) {
    __m128 a = _mm_setzero_ps(), d = _mm_setzero_ps();
    for (int j = 0; j < F; ++j) {
      const __m128 v = _mm_loadu_ps(h + ((2 * o + 16 + TapOffset(F, j)) & 3) * 4);
      a = _mm_add_ps(a, _mm_mul_ps(_mm256_castps256_ps128(c.lo[j]), v));
      d = _mm_add_ps(d, _mm_mul_ps(_mm256_castps256_ps128(c.hi[j]), v));
    }
    _mm_storel_pi(reinterpret_cast<__m64*>(ll + o * ll_stride), a);
    _mm_storeh_pi(reinterpret_cast<__m64*>(dst + o * dst_stride + 2), a);
    _mm_storeu_ps(dst + (2 + o) * dst_stride, d);
  }
}

// Column step for w >= 8: each output row pair is F whole rows of h, 8 columns at a time.
template <int F, size_t W>
void ColumnStepVec(const VecCoefs<F>& c, const float* h, size_t w_rt, float* ll, size_t ll_stride, float* dst,
                   size_t dst_stride) {
  const size_t w = W ? W : w_rt, half = w / 2, mask = w - 1;
  for (size_t o = 0; o < half; ++o) {
    const float* rows[F];
    for (int j = 0; j < F; ++j) rows[j] = h + ((2 * o + w * 4 + TapOffset(F, j)) & mask) * w;
    float* lo_row = dst + o * dst_stride;
    float* hi_row = dst + (half + o) * dst_stride;
#pragma GCC unroll 16
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
struct Kernel {
  Coefs<F> c;
#if defined(__AVX2__)
  VecCoefs<F> v;
  explicit Kernel(const Coefs<F>& coefs) : c(coefs), v(coefs) {}
#else
  explicit Kernel(const Coefs<F>& coefs) : c(coefs) {}
#endif
};

// One level on a w × w band (W compile-time, or 0 and w at run time).
template <int F, size_t W>
inline void Level(const Kernel<F>& k, const float* in, size_t in_stride, size_t w, float* h, float* ll,
                  size_t ll_stride, float* dst, size_t dst_stride) {
#if defined(__AVX2__)
  if constexpr (W == 0 || W >= 16) {
    if (w >= 16) {
      RowStepWide<F, W>(k.v, in, in_stride, w, h);
      ColumnStepVec<F, W>(k.v, h, w, ll, ll_stride, dst, dst_stride);
      return;
    }
  }
  if constexpr (W == 0 || W == 8) {
    if (w == 8) {
      RowStep8<F>(k.v, in, in_stride, h);
      ColumnStepVec<F, 8>(k.v, h, w, ll, ll_stride, dst, dst_stride);
      return;
    }
  }
  if constexpr (W == 0 || W == 4) {
    if (w == 4 && in_stride == 4) {
      RowStep4<F>(k.v, in, h);
      ColumnStep4<F>(k.v, h, ll, ll_stride, dst, dst_stride);
      return;
    }
  }
#endif
  RowStepScalar<F, W>(k.c, in, in_stride, w, h);
  ColumnStepScalar<F, W>(k.c, h, w, ll, ll_stride, dst, dst_stride);
}

// Levels from band side W (compile-time) down to 1; the input band is `in`.
template <int F, size_t R, size_t W>
inline void LevelsFrom(const Kernel<F>& k, const float* in, size_t in_stride, float* dst, float* h, float* low0,
                       float* low1) {
  if constexpr (W >= 2) {
    float* ll = W == 2 ? dst : low0;  // the last low band is the single value dst[0]
    constexpr size_t ll_stride = W == 2 ? R : W / 2;
    Level<F, W>(k, in, in_stride, W, h, ll, ll_stride, dst, R);
    LevelsFrom<F, R, W / 2>(k, ll, ll_stride, dst, h, low1, low0);
  }
}

// `count` consecutive r × r faces. Level 0 reads all of a source face into h before anything
// is written to its destination, and later levels read only scratch: src == dst is safe.
// Measured at R = 32 (bench/results/row_transform.md): 1, 2 and 4 faces ahead are alike, 8
// is slower; without the destination's lines a little slower.
constexpr size_t kPrefetchFaces = 2;

template <int F, size_t R>
void FacesT(const Kernel<F>& k, size_t r_rt, size_t count, const float* src, float* dst, float* scratch) {
  const size_t r = R ? R : r_rt, area = r * r;
  float* h = scratch;
  float* low0 = scratch + area;
  float* low1 = low0 + (r / 2) * (r / 2);
  for (size_t i = 0; i < count; ++i) {
    // Request the lines of the face kPrefetchFaces ahead, to read and to write: the
    // hardware prefetcher alone leaves the kernel waiting on memory, the destination's
    // write-allocate reads above all.
    if (i + kPrefetchFaces < count) {
      const float* next_in = src + (i + kPrefetchFaces) * area;
      float* next_out = dst + (i + kPrefetchFaces) * area;
#pragma GCC unroll 64
      for (size_t q = 0; q < area; q += 16) {
        __builtin_prefetch(next_in + q, 0, 3);
        __builtin_prefetch(next_out + q, 1, 3);
      }
    }
    const float* in = src + i * area;
    float* out = dst + i * area;
    if constexpr (R != 0) {
      LevelsFrom<F, R, R>(k, in, R, out, h, low0, low1);
    } else {
      if (r == 1) {
        out[0] = in[0];
      } else {
        size_t in_stride = r;
        float* low[2] = {low0, low1};
        int p = 0;
        for (size_t w = r; w >= 2; w /= 2, p ^= 1) {
          float* ll = w == 2 ? out : low[p];
          const size_t ll_stride = w == 2 ? r : w / 2;
          Level<F, 0>(k, in, in_stride, w, h, ll, ll_stride, out, r);
          in = ll;
          in_stride = ll_stride;
        }
      }
    }
  }
}

template <int F>
void FacesFor(std::span<const double> taps, size_t r, size_t count, const float* src, float* dst, float* scratch) {
  // One filter per tap count: the table is built once.
  static const Kernel<F> k(MakeCoefs<F>(taps));
  switch (r) {
    case 8:
      return FacesT<F, 8>(k, r, count, src, dst, scratch);
    case 16:
      return FacesT<F, 16>(k, r, count, src, dst, scratch);
    case 32:
      return FacesT<F, 32>(k, r, count, src, dst, scratch);
    case 64:
      return FacesT<F, 64>(k, r, count, src, dst, scratch);
    case 128:
      return FacesT<F, 128>(k, r, count, src, dst, scratch);
    default:
      return FacesT<F, 0>(k, r, count, src, dst, scratch);
  }
}

}  // namespace

bool HasFaceKernel(Filter f, size_t r) { return IsOrthonormal(f) && IsPowerOfTwo(r) && r <= kMaxFaceRes; }

void ForwardFaces(Filter f, size_t r, size_t count, const float* src, float* dst, float* scratch) {
  const auto taps = OrthoLowPass(f);
  switch (taps.size()) {
    case 2:
      return FacesFor<2>(taps, r, count, src, dst, scratch);
    case 4:
      return FacesFor<4>(taps, r, count, src, dst, scratch);
    case 6:
      return FacesFor<6>(taps, r, count, src, dst, scratch);
    case 8:
      return FacesFor<8>(taps, r, count, src, dst, scratch);
  }
}

void ForwardFace(Filter f, size_t r, const float* src, float* dst, float* scratch) {
  ForwardFaces(f, r, 1, src, dst, scratch);
}

}  // namespace ltb::wavelet
