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

inline V4 Load(const double* p) {
  V4 v;
  std::memcpy(&v, p, sizeof v);
  return v;
}

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
    const V4 xv = Load(x + i);
    for (int d = 0; d < K; ++d) acc[d] += xv * Load(y[d] + i);
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

double SoftThreshold(double z, double lambda) { return z > lambda ? z - lambda : z < -lambda ? z + lambda : 0.0; }

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

double KktViolation(const double* g, const double* alpha, int n, double lambda) {
  double v = 0;
  for (int k = 0; k < n; ++k) {
    const double e = alpha[k] > 0   ? std::abs(g[k] + lambda)
                     : alpha[k] < 0 ? std::abs(g[k] - lambda)
                                    : std::abs(g[k]) - lambda;
    v = std::max(v, e);
  }
  return v;
}

// One coordinate-descent sweep in index order, updating g. Returns whether any coordinate
// changed.
bool Sweep(const double* G, int n, double lambda, double* alpha, double* __restrict g) {
  bool changed = false;
  for (int k = 0; k < n; ++k) {
    const double* __restrict col = G + ptrdiff_t{k} * n;
    const double gkk = col[k];
    if (!(gkk > 0)) continue;
    const double old = alpha[k];
    // c_k − Σ_{l≠k} G_kl α_l = G_kk α_k − g_k.
    const double updated = SoftThreshold(gkk * old - g[k], lambda) / gkk;
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

// Scratch areas: G (n×n), then the support's Cholesky factor (p×p, compact), then four
// n-vectors.
struct Work {
  double* G;
  double* L;
  double* a;      // α on the support (compact), then the candidate there
  double* x;      // the Newton solution or null direction (compact)
  double* cand;   // the candidate α (all n)
  double* gcand;  // its gradient
};

// One step on the face of α's support S = {k : α_k ≠ 0} and signs s, into a (compact over
// S; zeroed coordinates stay in place). Cholesky of G_SS in index order; when it completes,
// the face's minimiser x = G_SS⁻¹(c_S − λ s), or, when some sign of x differs from s, the
// point of the segment a → x where the first coordinate reaches 0 (the objective is a
// convex quadratic on the face, so it decreases along the segment). When a column j is
// dependent on the earlier ones, the null direction d (d_S<j = G⁻¹G_S<j,j, d_j = −1)
// leaves Aα as it is; moving along ±d, whichever lowers sᵀα, until a coordinate reaches 0
// shrinks the support without raising the objective. Returns whether a coordinate was
// zeroed (then the step is to be repeated on the smaller support).
bool FaceStep(const double* c, int n, double lambda, const double* support, const Work& w) {
  int p = 0;
  for (int k = 0; k < n; ++k) p += support[k] != 0;
  double* L = w.L;
  for (int k = 0, j = 0; k < n; ++k) {
    if (support[k] == 0) continue;
    const double* row = w.G + ptrdiff_t{k} * n;
    for (int l = 0, i = 0; l <= k; ++l) {
      if (support[l] != 0) L[ptrdiff_t{j} * p + i++] = row[l];
    }
    w.a[j] = support[k];
    w.x[j] = c[k] - lambda * Sign(support[k]);
    ++j;
  }
  int dependent = -1;
  for (int j = 0; j < p && dependent < 0; ++j) {
    double* lj = L + ptrdiff_t{j} * p;
    const double diag = lj[j];
    for (int i = 0; i < j; ++i) {
      const double* li = L + ptrdiff_t{i} * p;
      double s = lj[i];
      for (int q = 0; q < i; ++q) s -= lj[q] * li[q];
      lj[i] = s / li[i];
    }
    double s = diag;
    for (int q = 0; q < j; ++q) s -= lj[q] * lj[q];
    if (s > kDependent * diag) {
      lj[j] = std::sqrt(s);
    } else {
      dependent = j;
    }
  }
  double t = 1;
  int hit = -1;  // the coordinate that reaches 0
  if (dependent < 0) {
    // L y = rhs, then Lᵀ x = y (x holds rhs, then y, then x).
    for (int j = 0; j < p; ++j) {
      double s = w.x[j];
      for (int q = 0; q < j; ++q) s -= L[ptrdiff_t{j} * p + q] * w.x[q];
      w.x[j] = s / L[ptrdiff_t{j} * p + j];
    }
    for (int j = p - 1; j >= 0; --j) {
      double s = w.x[j];
      for (int q = j + 1; q < p; ++q) s -= L[ptrdiff_t{q} * p + j] * w.x[q];
      w.x[j] = s / L[ptrdiff_t{j} * p + j];
    }
    for (int j = 0; j < p; ++j) {
      if (w.x[j] * w.a[j] > 0) continue;
      const double tj = w.a[j] / (w.a[j] - w.x[j]);
      if (hit < 0 || tj < t) t = tj, hit = j;
    }
    for (int j = 0; j < p; ++j) w.a[j] = hit < 0 ? w.x[j] : w.a[j] + t * (w.x[j] - w.a[j]);
  } else {
    // Lᵀ_<j d = L_j,<j, then d_j = −1.
    const int j = dependent;
    const double* lj = L + ptrdiff_t{j} * p;
    for (int i = j - 1; i >= 0; --i) {
      double s = lj[i];
      for (int q = i + 1; q < j; ++q) s -= L[ptrdiff_t{q} * p + i] * w.x[q];
      w.x[i] = s / L[ptrdiff_t{i} * p + i];
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
    for (int i = 0; i <= j; ++i) w.a[i] += t * dir * w.x[i];
  }
  if (hit >= 0) w.a[hit] = 0;
  return hit >= 0;
}

// The candidate into w.cand: face steps from α until one ends at its face's minimiser with
// the signs kept (at most |S| + 1 steps: each other step zeroes a coordinate). Returns false
// when α = 0.
bool FaceCandidate(const double* c, int n, double lambda, const double* alpha, const Work& w) {
  std::copy(alpha, alpha + n, w.cand);
  bool any = false;
  for (int k = 0; k < n; ++k) any = any || alpha[k] != 0;
  if (!any) return false;
  for (bool again = true; again;) {
    again = FaceStep(c, n, lambda, w.cand, w);
    for (int k = 0, j = 0; k < n; ++k) {
      if (w.cand[k] != 0) w.cand[k] = w.a[j++];
    }
  }
  return true;
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
  if (scratch.gram.size() < 2 * nn + 4 * size_t(n)) scratch.gram.resize(2 * nn + 4 * size_t(n));
  if (scratch.atb.size() < size_t(n)) scratch.atb.resize(n);
  if (scratch.grad.size() < size_t(n)) scratch.grad.resize(n);
  double* const G = scratch.gram.data();
  const Work w{G, G + nn, G + 2 * nn, G + 2 * nn + n, G + 2 * nn + 2 * n, G + 2 * nn + 3 * n};
  double* const c = scratch.atb.data();
  double* const g = scratch.grad.data();
  GramAndCorrelation(A, rows, n, b, G, c);

  double lambda_max = 0;
  for (int k = 0; k < n; ++k) lambda_max = std::max(lambda_max, std::abs(c[k]));
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
    double v = KktViolation(g, alpha, n, lambda);
    result.converged = v <= stop;
    while (!result.converged && result.sweeps < options.max_sweeps) {
      const bool changed = Sweep(G, n, lambda, alpha, g);
      ++result.sweeps;
      ExactGradient(G, c, alpha, n, g);
      v = KktViolation(g, alpha, n, lambda);
      if (v <= stop) {
        result.converged = true;
        break;
      }
      // The support's step, kept when it meets the tolerance or lowers the objective:
      // ΔF = δᵀg + ½δᵀGδ + λΔ‖α‖₁, with Gδ = g' − g.
      bool moved = false;
      if (FaceCandidate(c, n, lambda, alpha, w)) {
        ExactGradient(G, c, w.cand, n, w.gcand);
        const double v_cand = KktViolation(w.gcand, w.cand, n, lambda);
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
  return l1_internal::Solve(A, m, n, b, options, scratch, alpha);
}

}  // namespace ltb::sample
