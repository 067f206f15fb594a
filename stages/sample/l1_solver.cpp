#include "stages/sample/l1_solver.h"

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstring>

namespace ltb::sample {
// Named, so that a unity build of the sample stage sees no clash with other files' helpers.
namespace l1_internal {
namespace {

// Four doubles; lane-wise arithmetic (GCC/Clang vector extension), one AVX register or two
// SSE ones. Each lane's sum is its own, so the results do not depend on the instruction set.
typedef double V4 __attribute__((vector_size(4 * sizeof(double))));

// (Through a pointer: a V4 returned by value warns of an ABI change where AVX is off.)
inline void Load(V4* v, const double* p) { std::memcpy(v, p, sizeof *v); }

// x·y_d for K vectors y_d at once, each summed in the same fixed order: lane j adds the
// terms i ≡ j (mod 4) in increasing i (the last m mod 4 terms into lanes 0, 1, 2), then
// (lane0 + lane1) + (lane2 + lane3). So a dot product has the same bits whatever K it was
// computed with.
template <int K>
void Dots(const double* __restrict x, const double* const* y, ptrdiff_t m, double* out) {
  V4 acc[K];
  for (int d = 0; d < K; ++d) acc[d] = V4{0, 0, 0, 0};
  const ptrdiff_t m4 = m & ~ptrdiff_t{3};
  for (ptrdiff_t i = 0; i < m4; i += 4) {
    V4 xv, yv;
    Load(&xv, x + i);
    for (int d = 0; d < K; ++d) {
      Load(&yv, y[d] + i);
      acc[d] += xv * yv;
    }
  }
  for (int d = 0; d < K; ++d) {
    double lane[4];
    std::memcpy(lane, &acc[d], sizeof lane);
    for (ptrdiff_t i = m4; i < m; ++i) lane[i - m4] += x[i] * y[d][i];
    out[d] = (lane[0] + lane[1]) + (lane[2] + lane[3]);
  }
}

// G = AᵀA (both triangles) and c = Aᵀb: for each column k, its products with columns
// k..n-1 and with b, four at a time.
void GramAndCorrelation(const double* A, ptrdiff_t m, int n, const double* b, double* G, double* c) {
  auto target = [&](int t) { return t < n ? A + t * m : b; };
  auto store = [&](int k, int t, double v) {
    if (t < n) {
      G[ptrdiff_t{k} * n + t] = v;
      G[ptrdiff_t{t} * n + k] = v;
    } else {
      c[k] = v;
    }
  };
  for (int k = 0; k < n; ++k) {
    const double* x = A + k * m;
    int t = k;
    for (; t + 4 <= n + 1; t += 4) {
      const double* y[4] = {target(t), target(t + 1), target(t + 2), target(t + 3)};
      double v[4];
      Dots<4>(x, y, m, v);
      for (int d = 0; d < 4; ++d) store(k, t + d, v[d]);
    }
    for (; t <= n; ++t) {
      const double* y[1] = {target(t)};
      double v;
      Dots<1>(x, y, m, &v);
      store(k, t, v);
    }
  }
}

// The minimiser over α_k of ½G_kk α_k² − zα_k + λ|α_k| is Threshold(z, λ)/G_kk: the soft threshold,
// or with α_k ≥ 0 its positive half.
template <bool kNonnegative>
double Threshold(double z, double lambda) {
  if constexpr (kNonnegative) return z > lambda ? z - lambda : 0.0;
  return z > lambda ? z - lambda : z < -lambda ? z + lambda : 0.0;
}

double Sign(double x) { return x > 0 ? 1.0 : -1.0; }

// g = Gα − c, summed over the nonzero α_l in increasing l.
void ExactGradient(const double* G, const double* c, const double* alpha, int n, double* __restrict g) {
  for (int k = 0; k < n; ++k) g[k] = -c[k];
  for (int l = 0; l < n; ++l) {
    const double a = alpha[l];
    if (a == 0) continue;
    const double* __restrict col = G + ptrdiff_t{l} * n;
#pragma omp simd
    for (int k = 0; k < n; ++k) g[k] += a * col[k];
  }
}

// (With α ≥ 0 a zero coordinate violates only when g_k + λ < 0: increasing it lowers F.)
template <bool kNonnegative>
double KktViolation(const double* g, const double* alpha, int n, double lambda) {
  double v = 0;
  for (int k = 0; k < n; ++k) {
    const double e = alpha[k] > 0   ? std::abs(g[k] + lambda)
                     : alpha[k] < 0 ? std::abs(g[k] - lambda)
                     : kNonnegative ? -(g[k] + lambda)
                                    : std::abs(g[k]) - lambda;
    v = std::max(v, e);
  }
  return v;
}

// One coordinate-descent sweep in index order, updating g. Returns whether any coordinate
// changed.
template <bool kNonnegative>
bool Sweep(const double* G, int n, double lambda, double* alpha, double* __restrict g) {
  bool changed = false;
  for (int k = 0; k < n; ++k) {
    const double* __restrict col = G + ptrdiff_t{k} * n;
    const double gkk = col[k];
    if (!(gkk > 0)) continue;
    const double old = alpha[k];
    // c_k − Σ_{l≠k} G_kl α_l = G_kk α_k − g_k.
    const double updated = Threshold<kNonnegative>(gkk * old - g[k], lambda) / gkk;
    if (updated == old) continue;
    const double delta = updated - old;
    alpha[k] = updated;
#pragma omp simd
    for (int l = 0; l < n; ++l) g[l] += delta * col[l];
    changed = true;
  }
  return changed;
}

// A column whose Cholesky pivot is below this fraction of its G_kk is taken as a linear
// combination of the support's earlier columns (sin² of its angle to their span).
constexpr double kDependent = 1e-12;

// Scratch areas after G (n×n): the support's Cholesky factor R (upper, row stride n), then
// n-vectors, compact over the support (position j: its j-th nonzero coordinate).
struct Work {
  double* G;
  double* R;
  double* diag;   // G_kk
  double* a;      // the current point
  double* x;      // right-hand side, then the face's minimiser or a null direction
  double* cand;   // the candidate α (all n)
  double* gcand;  // its gradient (all n)
};

// G_SS = RᵀR for the support S of w.cand, right-looking (the inner loops are vector
// updates). Returns −1, or the first position whose column depends on the earlier ones
// (R is then complete above it only).
int Factor(int n, int p, const Work& w) {
  double* const R = w.R;
  for (int k = 0, j = 0; k < n; ++k) {
    if (w.cand[k] == 0) continue;
    const double* row = w.G + ptrdiff_t{k} * n;
    double* rj = R + ptrdiff_t{j} * n;
    for (int l = k, i = j; l < n; ++l) {
      if (w.cand[l] != 0) rj[i++] = row[l];
    }
    w.diag[j++] = row[k];
  }
  for (int j = 0; j < p; ++j) {
    double* __restrict rj = R + ptrdiff_t{j} * n;
    if (!(rj[j] > kDependent * w.diag[j])) return j;
    const double pivot = std::sqrt(rj[j]);
    rj[j] = pivot;
    for (int q = j + 1; q < p; ++q) rj[q] /= pivot;
    for (int i = j + 1; i < p; ++i) {
      double* __restrict ri = R + ptrdiff_t{i} * n;
      const double f = rj[i];
#pragma omp simd
      for (int q = i; q < p; ++q) ri[q] -= f * rj[q];
    }
  }
  return -1;
}

// R of S without its position h: the columns after h move left, and Givens rotations of
// rows (q, q+1) clear the subdiagonal this leaves. O((p − h)²) instead of a new factor.
void DeleteColumn(int n, int p, int h, const Work& w) {
  double* const R = w.R;
  for (int q = h; q < p - 1; ++q) {
    for (int r = 0; r <= q + 1; ++r) R[ptrdiff_t{r} * n + q] = R[ptrdiff_t{r} * n + q + 1];
  }
  for (int q = h; q < p - 1; ++q) {
    double* __restrict r0 = R + ptrdiff_t{q} * n;
    double* __restrict r1 = R + ptrdiff_t{q + 1} * n;
    const double a = r0[q], b = r1[q], r = std::sqrt(a * a + b * b), cs = a / r, sn = b / r;
    r0[q] = r;
    r1[q] = 0;
#pragma omp simd
    for (int col = q + 1; col < p - 1; ++col) {
      const double u = r0[col], v = r1[col];
      r0[col] = cs * u + sn * v;
      r1[col] = cs * v - sn * u;
    }
  }
}

// The candidate into w.cand: steps on the face of the support S = {k : α_k ≠ 0} and signs s
// until one ends at its face's minimiser x = G_SS⁻¹(c_S − λ s) with the signs kept. When a
// sign of x differs from s, the step goes to the point of the segment α → x where the first
// coordinate reaches 0 (the objective is a convex quadratic on the face, so it decreases
// along the segment), and that coordinate leaves S. When a column j of S depends on the
// earlier ones, the null direction d (d_S<j = G⁻¹G_S<j,j, d_j = −1) leaves Aα as it is; the
// step goes along ±d, whichever lowers sᵀα, until a coordinate reaches 0. So at most |S| + 1
// steps. Returns false when α = 0.
// With α ≥ 0 every s_k is +1 and the same steps keep α ≥ 0; a coordinate that a step's
// rounding leaves below 0 (one that reaches 0 at the same t as the hit one) is set to 0.
template <bool kNonnegative>
bool FaceCandidate(const double* c, int n, double lambda, const double* alpha, const Work& w) {
  std::copy(alpha, alpha + n, w.cand);
  int p = 0;
  for (int k = 0; k < n; ++k) p += alpha[k] != 0;
  if (p == 0) return false;
  const double* const R = w.R;
  auto r = [&](int i, int j) { return R[ptrdiff_t{i} * n + j]; };
  bool factored = false;
  while (true) {
    for (int k = 0, j = 0; k < n; ++k) {
      if (w.cand[k] == 0) continue;
      w.a[j] = w.cand[k];
      w.x[j++] = c[k] - lambda * Sign(w.cand[k]);
    }
    const int dependent = factored ? -1 : Factor(n, p, w);
    double t = 1;
    int hit = -1;  // the position that reaches 0
    if (dependent < 0) {
      // Rᵀ y = rhs by rows of R, then R x = y (x holds rhs, then y, then x).
      for (int j = 0; j < p; ++j) {
        const double* __restrict rj = R + ptrdiff_t{j} * n;
        double* __restrict x = w.x;
        const double yj = x[j] / rj[j];
        x[j] = yj;
#pragma omp simd
        for (int q = j + 1; q < p; ++q) x[q] -= rj[q] * yj;
      }
      for (int j = p - 1; j >= 0; --j) {
        double s = w.x[j];
        for (int q = j + 1; q < p; ++q) s -= r(j, q) * w.x[q];
        w.x[j] = s / r(j, j);
      }
      for (int j = 0; j < p; ++j) {
        if (w.x[j] * w.a[j] > 0) continue;
        const double tj = w.a[j] / (w.a[j] - w.x[j]);
        if (hit < 0 || tj < t) t = tj, hit = j;
      }
      for (int j = 0; j < p; ++j) w.a[j] = hit < 0 ? w.x[j] : w.a[j] + t * (w.x[j] - w.a[j]);
    } else {
      // R_<j d_<j = R_<j,j (column j above the pivot), then d_j = −1.
      const int j = dependent;
      for (int i = j - 1; i >= 0; --i) {
        double s = r(i, j);
        for (int q = i + 1; q < j; ++q) s -= r(i, q) * w.x[q];
        w.x[i] = s / r(i, i);
      }
      w.x[j] = -1;
      double slope = 0;
      for (int i = 0; i <= j; ++i) slope += Sign(w.a[i]) * w.x[i];
      const double dir = slope <= 0 ? 1.0 : -1.0;
      for (int i = 0; i <= j; ++i) {
        const double di = dir * w.x[i];
        if (di * w.a[i] >= 0) continue;
        const double ti = -w.a[i] / di;
        if (hit < 0 || ti < t) t = ti, hit = i;
      }
      if (hit < 0) return true;  // only by rounding (d_j = ±1 always moves one): no step
      for (int i = 0; i <= j; ++i) w.a[i] += t * dir * w.x[i];
    }
    if (hit < 0) {
      for (int k = 0, j = 0; k < n; ++k) {
        if (w.cand[k] != 0) w.cand[k] = w.a[j++];
      }
      return true;
    }
    w.a[hit] = 0;
    if constexpr (kNonnegative) {
      for (int j = 0; j < p; ++j) {
        if (!(w.a[j] > 0)) w.a[j] = 0;
      }
    }
    int zeros = 0;  // more than one only when another coordinate reaches 0 at the same t
    for (int j = 0; j < p; ++j) zeros += w.a[j] == 0;
    for (int k = 0, j = 0; k < n; ++k) {
      if (w.cand[k] != 0) w.cand[k] = w.a[j++];
    }
    factored = dependent < 0 && zeros == 1;
    if (factored) DeleteColumn(n, p, hit, w);
    p -= zeros;
    if (p == 0) return true;
  }
}

// ‖Aα − b‖², row blocks of Aα − b accumulated on the stack, columns with α_k = 0 skipped.
double SquaredResidual(const double* A, ptrdiff_t m, int n, const double* b, const double* alpha) {
  constexpr ptrdiff_t kBlock = 128;
  double r[kBlock];
  double sum = 0;
  for (ptrdiff_t i0 = 0; i0 < m; i0 += kBlock) {
    const ptrdiff_t len = std::min(kBlock, m - i0);
    for (ptrdiff_t i = 0; i < len; ++i) r[i] = -b[i0 + i];
    for (int k = 0; k < n; ++k) {
      const double a = alpha[k];
      if (a == 0) continue;
      const double* __restrict col = A + k * m + i0;
#pragma omp simd
      for (ptrdiff_t i = 0; i < len; ++i) r[i] += a * col[i];
    }
    for (ptrdiff_t i = 0; i < len; ++i) sum += r[i] * r[i];
  }
  return sum;
}

template <bool kNonnegative>
L1Result Solve(const double* A, int m, int n, const double* b, const L1Options& options, L1Scratch& scratch,
               double* alpha) {
  L1Result result;
  if (n <= 0) n = 0;
  if (m <= 0) m = 0;
  std::fill(alpha, alpha + n, 0.0);
  const ptrdiff_t rows = m;
  if (m == 0) {
    result.converged = true;
    return result;
  }
  if (n == 0) {
    const double bb = SquaredResidual(A, rows, 0, b, alpha);
    result.converged = true;
    result.residual = std::sqrt(bb);
    result.objective = 0.5 * bb;
    return result;
  }

  const size_t nn = size_t(n) * size_t(n);
  if (scratch.gram.size() < 2 * nn + 5 * size_t(n)) scratch.gram.resize(2 * nn + 5 * size_t(n));
  if (scratch.atb.size() < size_t(n)) scratch.atb.resize(n);
  if (scratch.grad.size() < size_t(n)) scratch.grad.resize(n);
  double* const G = scratch.gram.data();
  double* const vecs = G + 2 * nn;
  const Work w{G, G + nn, vecs, vecs + n, vecs + 2 * n, vecs + 3 * n, vecs + 4 * n};
  double* const c = scratch.atb.data();
  double* const g = scratch.grad.data();
  GramAndCorrelation(A, rows, n, b, G, c);

  // The smallest λ with α = 0: max_k |c_k|, or with α ≥ 0 max(0, max_k c_k).
  double lambda_max = 0;
  for (int k = 0; k < n; ++k) lambda_max = std::max(lambda_max, kNonnegative ? c[k] : std::abs(c[k]));
  for (int k = 0; k < n; ++k) {
    if (!std::isfinite(c[k])) lambda_max = c[k];  // NaN or ±inf: no meaningful fit
  }
  const double rel = options.lambda_rel > 0 ? options.lambda_rel : 0.0;
  const double lambda = std::isfinite(lambda_max) ? rel * lambda_max : 0.0;
  result.lambda = lambda;
  if (!std::isfinite(lambda_max)) {
    result.kkt_violation = std::abs(lambda_max);
  } else {
    const double stop = options.tolerance * lambda_max;
    ExactGradient(G, c, alpha, n, g);
    double v = KktViolation<kNonnegative>(g, alpha, n, lambda);
    result.converged = v <= stop;
    while (!result.converged && result.sweeps < options.max_sweeps) {
      const bool changed = Sweep<kNonnegative>(G, n, lambda, alpha, g);
      ++result.sweeps;
      ExactGradient(G, c, alpha, n, g);
      v = KktViolation<kNonnegative>(g, alpha, n, lambda);
      if (v <= stop) {
        result.converged = true;
        break;
      }
      // The support's step, kept when it meets the tolerance or lowers the objective:
      // ΔF = δᵀg + ½δᵀGδ + λΔ‖α‖₁, with Gδ = g' − g.
      bool moved = false;
      if (FaceCandidate<kNonnegative>(c, n, lambda, alpha, w)) {
        ExactGradient(G, c, w.cand, n, w.gcand);
        const double v_cand = KktViolation<kNonnegative>(w.gcand, w.cand, n, lambda);
        double change = 0, l1_change = 0;
        for (int k = 0; k < n; ++k) {
          change += (w.cand[k] - alpha[k]) * (g[k] + w.gcand[k]);
          l1_change += std::abs(w.cand[k]) - std::abs(alpha[k]);
        }
        if (v_cand <= stop || 0.5 * change + lambda * l1_change < 0) {
          for (int k = 0; k < n; ++k) moved = moved || w.cand[k] != alpha[k];
          std::copy(w.cand, w.cand + n, alpha);
          std::copy(w.gcand, w.gcand + n, g);
          v = v_cand;
          result.converged = v <= stop;
        }
      }
      if (!changed && !moved) break;  // a fixed point short of the tolerance: more sweeps repeat it
    }
    result.kkt_violation = v;
  }

  double l1 = 0;
  for (int k = 0; k < n; ++k) l1 += std::abs(alpha[k]);
  const double rr = SquaredResidual(A, rows, n, b, alpha);
  result.residual = std::sqrt(rr);
  result.objective = 0.5 * rr + lambda * l1;
  return result;
}

}  // namespace
}  // namespace l1_internal

L1Result SolveL1LeastSquares(const double* A, int m, int n, const double* b, const L1Options& options,
                             L1Scratch& scratch, double* alpha) {
  return options.nonnegative ? l1_internal::Solve<true>(A, m, n, b, options, scratch, alpha)
                             : l1_internal::Solve<false>(A, m, n, b, options, scratch, alpha);
}

}  // namespace ltb::sample
