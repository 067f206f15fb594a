// The lasso of sparse precomputation (stages/sample/l1_solver.h) against independent
// oracles: every support and sign pattern enumerated (small problems), the closed form of a
// planted sparse solution, and the KKT conditions recomputed here in long double.
//
// Tolerances come from the solver's contract and rounding bounds, not from tuning:
// - The stop leaves a subgradient s of F(α) = ½‖Aα − b‖² + λ‖α‖₁ with ‖s‖_∞ = v, the KKT
//   violation (computed here exactly, in long double). Convexity gives
//   F(α) − F* ≤ v·(‖α‖₁ + ‖α*‖₁); strong convexity (G positive definite, λ_min(G) ≥ 1/‖G⁻¹‖_F)
//   gives ‖α − α*‖₂ ≤ ‖s‖₂/λ_min ≤ √n·v·‖G⁻¹‖_F.
// - The solver computes G, c and g in double: |g_solver − g| ≤ γ_{m+n+4}·(|A|ᵀ(|A||α| + |b|))_k
//   (γ_j = j·u/(1 − j·u), u = 2⁻⁵³; m for the dot products, n + 1 for Gα − c, one each for
//   ±λ and τ·λ_max, one spare), so the true violation may exceed τ·λ_max by that much.
// - The returned objective is evaluated in double: its error is ≤ γ_{m+n+2}·(Σ_i t_i² + λ‖α‖₁),
//   t_i = |b_i| + Σ_k |A_ik α_k| (n + 1 terms per residual, m squares summed).
#include "stages/sample/l1_solver.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <limits>
#include <new>
#include <random>
#include <vector>

// Counts allocations (ReusedScratchDoesNotAllocate).
namespace {
std::atomic<int64_t> g_allocations{0};
void* Counted(size_t n) {
  g_allocations.fetch_add(1);
  void* p = std::malloc(n == 0 ? 1 : n);
  if (p == nullptr) throw std::bad_alloc();
  return p;
}
}  // namespace

void* operator new(size_t n) { return Counted(n); }
void* operator new[](size_t n) { return Counted(n); }
void operator delete(void* p) noexcept { std::free(p); }
void operator delete[](void* p) noexcept { std::free(p); }
void operator delete(void* p, size_t) noexcept { std::free(p); }
void operator delete[](void* p, size_t) noexcept { std::free(p); }

namespace ltb::sample {
namespace {

using Ld = long double;
constexpr double kU = std::numeric_limits<double>::epsilon() / 2;

double Gamma(int j) { return j * kU / (1 - j * kU); }

struct Problem {
  int m = 0, n = 0;
  std::vector<double> A, b;  // A column-major
  double a(int i, int k) const { return A[size_t(k) * m + i]; }
};

Problem Gaussian(uint64_t seed, int m, int n) {
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> nd;
  Problem p;
  p.m = m;
  p.n = n;
  p.A.resize(size_t(m) * n);
  p.b.resize(m);
  for (double& x : p.A) x = nd(rng);
  for (double& x : p.b) x = nd(rng);
  return p;
}

// Neighbouring rows of a transport matrix are alike: every column is a common positive
// profile plus a little of its own.
Problem Correlated(uint64_t seed, int m, int n, double own) {
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> nd;
  std::uniform_real_distribution<double> ud(0.5, 1.5);
  Problem p;
  p.m = m;
  p.n = n;
  p.A.resize(size_t(m) * n);
  p.b.resize(m);
  std::vector<double> base(m);
  for (double& x : base) x = ud(rng);
  for (int k = 0; k < n; ++k)
    for (int i = 0; i < m; ++i) p.A[size_t(k) * m + i] = base[i] * (1 + own * nd(rng));
  for (int i = 0; i < m; ++i) p.b[i] = base[i] * (1 + own * nd(rng));
  return p;
}

struct Solved {
  L1Result r;
  std::vector<double> alpha;
};

Solved Solve(const Problem& p, const L1Options& o) {
  L1Scratch scratch;
  Solved s;
  s.alpha.assign(p.n, -7.0);  // output only: overwritten
  s.r = SolveL1LeastSquares(p.A.data(), p.m, p.n, p.b.data(), o, scratch, s.alpha.data());
  return s;
}

L1Options WithLambda(double lambda_rel, double tolerance = 1e-6, bool nonnegative = false) {
  L1Options o;
  o.lambda_rel = lambda_rel;
  o.tolerance = tolerance;
  o.nonnegative = nonnegative;
  return o;
}

// The oracle's own arithmetic: G = AᵀA, c = Aᵀb in long double, row by row.
struct Normal {
  int n = 0;
  std::vector<Ld> G, c;
  Ld lambda_max = 0;         // max_k |c_k|
  Ld lambda_max_nonneg = 0;  // max(0, max_k c_k)
  Ld LambdaMax(bool nonnegative) const { return nonnegative ? lambda_max_nonneg : lambda_max; }
};

Normal NormalEquations(const Problem& p) {
  Normal q;
  q.n = p.n;
  q.G.assign(size_t(p.n) * p.n, 0);
  q.c.assign(p.n, 0);
  for (int i = 0; i < p.m; ++i) {
    for (int k = 0; k < p.n; ++k) {
      q.c[k] += Ld(p.a(i, k)) * p.b[i];
      for (int l = 0; l < p.n; ++l) q.G[size_t(k) * p.n + l] += Ld(p.a(i, k)) * p.a(i, l);
    }
  }
  for (Ld v : q.c) q.lambda_max = std::max(q.lambda_max, std::fabs(v));
  for (Ld v : q.c) q.lambda_max_nonneg = std::max(q.lambda_max_nonneg, v);
  return q;
}

std::vector<Ld> Gradient(const Normal& q, const std::vector<double>& alpha) {
  std::vector<Ld> g(q.n);
  for (int k = 0; k < q.n; ++k) {
    Ld s = -q.c[k];
    for (int l = 0; l < q.n; ++l) s += q.G[size_t(k) * q.n + l] * alpha[l];
    g[k] = s;
  }
  return g;
}

// max_k of the KKT violation at α (the header's definition), in long double. Non-negative
// mode: α_k < 0 is infeasible (infinite violation), α_k = 0 violates by max(0, −(g_k + λ)).
Ld Violation(const Normal& q, const std::vector<double>& alpha, double lambda, bool nonnegative = false) {
  std::vector<Ld> g = Gradient(q, alpha);
  Ld v = 0;
  for (int k = 0; k < q.n; ++k) {
    if (nonnegative && alpha[k] < 0) {
      v = std::numeric_limits<Ld>::infinity();
    } else if (nonnegative && alpha[k] == 0) {
      v = std::max(v, -(g[k] + lambda));
    } else if (alpha[k] != 0) {
      v = std::max(v, std::fabs(g[k] + (alpha[k] > 0 ? lambda : -lambda)));
    } else {
      v = std::max(v, std::fabs(g[k]) - lambda);
    }
  }
  return v;
}

// How much the solver's double-precision g may differ from the exact one (header comment).
Ld GradientRounding(const Problem& p, const std::vector<double>& alpha) {
  std::vector<Ld> t(p.m);
  for (int i = 0; i < p.m; ++i) {
    t[i] = std::fabs(Ld(p.b[i]));
    for (int k = 0; k < p.n; ++k) t[i] += std::fabs(Ld(p.a(i, k)) * alpha[k]);
  }
  Ld worst = 0;
  for (int k = 0; k < p.n; ++k) {
    Ld s = 0;
    for (int i = 0; i < p.m; ++i) s += std::fabs(Ld(p.a(i, k))) * t[i];
    worst = std::max(worst, s);
  }
  return Gamma(p.m + p.n + 4) * worst;
}

// How much the solver's λ_max = max_k |c_k| (or max(0, max_k c_k), equally 1-Lipschitz in c)
// may differ from the exact one: the dot products' γ_m·(|A|ᵀ|b|)_k, one more rounding for
// λ = lambda_rel·λ_max.
Ld LambdaMaxRounding(const Problem& p) {
  Ld worst = 0;
  for (int k = 0; k < p.n; ++k) {
    Ld s = 0;
    for (int i = 0; i < p.m; ++i) s += std::fabs(Ld(p.a(i, k)) * p.b[i]);
    worst = std::max(worst, s);
  }
  return Gamma(p.m + 1) * worst;
}

Ld Objective(const Problem& p, const std::vector<double>& alpha, double lambda) {
  Ld rr = 0, l1 = 0;
  for (int i = 0; i < p.m; ++i) {
    Ld r = -Ld(p.b[i]);
    for (int k = 0; k < p.n; ++k) r += Ld(p.a(i, k)) * alpha[k];
    rr += r * r;
  }
  for (double x : alpha) l1 += std::fabs(Ld(x));
  return rr / 2 + lambda * l1;
}

// Error bound of the solver's double-precision objective at α (header comment).
Ld ObjectiveRounding(const Problem& p, const std::vector<double>& alpha, double lambda) {
  Ld tt = 0, l1 = 0;
  for (int i = 0; i < p.m; ++i) {
    Ld t = std::fabs(Ld(p.b[i]));
    for (int k = 0; k < p.n; ++k) t += std::fabs(Ld(p.a(i, k)) * alpha[k]);
    tt += t * t;
  }
  for (double x : alpha) l1 += std::fabs(Ld(x));
  return Gamma(p.m + p.n + 2) * (tt + lambda * l1);
}

Ld L1Norm(const std::vector<double>& x) {
  Ld s = 0;
  for (double v : x) s += std::fabs(Ld(v));
  return s;
}

Ld Distance(const std::vector<double>& x, const std::vector<double>& y) {
  Ld s = 0;
  for (size_t i = 0; i < x.size(); ++i) s += (Ld(x[i]) - y[i]) * (Ld(x[i]) - y[i]);
  return std::sqrt(s);
}

// Solves M x = rhs (k×k, row-major) by Gaussian elimination with partial pivoting; false
// when a pivot is below 1e-13 of the largest entry (numerically singular).
bool SolveLinear(std::vector<Ld> M, std::vector<Ld> rhs, int k, std::vector<Ld>* x) {
  Ld scale = 0;
  for (Ld v : M) scale = std::max(scale, std::fabs(v));
  for (int col = 0; col < k; ++col) {
    int piv = col;
    for (int r = col + 1; r < k; ++r)
      if (std::fabs(M[r * k + col]) > std::fabs(M[piv * k + col])) piv = r;
    if (!(std::fabs(M[piv * k + col]) > 1e-13L * scale)) return false;
    for (int j = 0; j < k; ++j) std::swap(M[col * k + j], M[piv * k + j]);
    std::swap(rhs[col], rhs[piv]);
    for (int r = col + 1; r < k; ++r) {
      const Ld f = M[r * k + col] / M[col * k + col];
      for (int j = col; j < k; ++j) M[r * k + j] -= f * M[col * k + j];
      rhs[r] -= f * rhs[col];
    }
  }
  x->assign(k, 0);
  for (int r = k - 1; r >= 0; --r) {
    Ld s = rhs[r];
    for (int j = r + 1; j < k; ++j) s -= M[r * k + j] * (*x)[j];
    (*x)[r] = s / M[r * k + r];
  }
  return true;
}

// ‖G⁻¹‖_F ≥ 1/λ_min(G); infinity when G is singular.
Ld InverseFrobenius(const Normal& q) {
  Ld s = 0;
  for (int j = 0; j < q.n; ++j) {
    std::vector<Ld> e(q.n, 0), x;
    e[j] = 1;
    if (!SolveLinear(q.G, e, q.n, &x)) return std::numeric_limits<Ld>::infinity();
    for (Ld v : x) s += v * v;
  }
  return std::sqrt(s);
}

// The distance bound of the header comment, ‖α − α*‖₂ ≤ √n·v·‖G⁻¹‖_F, plus the rounding of
// the oracle's own α*: its long double solve (n·cond·2⁻⁶³ relative, 100× spare) and its
// rounding to double (u relative). It holds in non-negative mode too: with h = Gα − c + λ·1
// and α* optimal (h*ᵀ(α − α*) ≥ 0), (α − α*)ᵀG(α − α*) ≤ hᵀ(α − α*) ≤ v·‖α − α*‖₁, since
// where α_k = 0, h_k ≥ −v and α*_k ≥ 0.
Ld DistanceBound(const Normal& q, const std::vector<double>& alpha, double lambda, Ld optimum_norm,
                 bool nonnegative = false) {
  Ld g_norm = 0;
  for (Ld v : q.G) g_norm += v * v;
  const Ld inv = InverseFrobenius(q);
  const Ld cond = std::sqrt(g_norm) * inv;
  return std::sqrt(Ld(q.n)) * Violation(q, alpha, lambda, nonnegative) * inv +
         (100 * q.n * cond * std::numeric_limits<Ld>::epsilon() + kU) * optimum_norm;
}

// Brute force: for every support S and sign pattern s on it, α_S = G_SS⁻¹(c_S − λ s); keep
// the candidates whose signs are s and whose off-support |g_k| ≤ λ (1e-9 λ_max slack for
// rounding); the least objective wins. Each kept candidate is a feasible point evaluated
// exactly, and the lasso always has a minimiser with linearly independent active columns,
// so the winner is a minimiser.
struct Oracle {
  std::vector<double> alpha;
  Ld objective = std::numeric_limits<Ld>::infinity();
};

Oracle BruteForce(const Problem& p, const Normal& q, double lambda) {
  const int n = p.n;
  Oracle best;
  for (int mask = 0; mask < (1 << n); ++mask) {
    std::vector<int> S;
    for (int k = 0; k < n; ++k)
      if (mask >> k & 1) S.push_back(k);
    const int s = static_cast<int>(S.size());
    std::vector<Ld> Gss(size_t(s) * s);
    for (int i = 0; i < s; ++i)
      for (int j = 0; j < s; ++j) Gss[i * s + j] = q.G[size_t(S[i]) * n + S[j]];
    for (int signs = 0; signs < (1 << s); ++signs) {
      std::vector<Ld> rhs(s), x;
      for (int i = 0; i < s; ++i) rhs[i] = q.c[S[i]] - ((signs >> i & 1) ? -lambda : Ld(lambda));
      if (!SolveLinear(Gss, rhs, s, &x)) continue;
      std::vector<double> alpha(n, 0.0);
      bool ok = true;
      for (int i = 0; i < s; ++i) {
        const bool negative = signs >> i & 1;
        ok = ok && (negative ? x[i] < 0 : x[i] > 0);
        alpha[S[i]] = static_cast<double>(x[i]);
      }
      if (!ok) continue;
      std::vector<Ld> g = Gradient(q, alpha);
      for (int k = 0; k < n; ++k)
        if (!(mask >> k & 1)) ok = ok && std::fabs(g[k]) <= lambda + 1e-9L * q.lambda_max;
      if (!ok) continue;
      const Ld f = Objective(p, alpha, lambda);
      if (f < best.objective) best = {alpha, f};
    }
  }
  return best;
}

// The same for α ≥ 0, an independent formulation: for every support S, α_S = G_SS⁻¹(c_S − λ·1);
// keep the candidates with α_S > 0 and g_k + λ ≥ 0 off the support (the same slack); the least
// objective wins. A minimiser with linearly independent active columns exists here too (along
// a null direction of dependent active columns, the one that does not raise Σα, until a
// coordinate reaches 0, Aα and so the objective do not rise). The objective bound of the file
// comment holds as well: F(α) − F* ≤ Σ_k (g_k + λ)(α_k − α*_k) ≤ v·(‖α‖₁ + ‖α*‖₁), because
// where α_k = 0 the term is −(g_k + λ)α*_k ≤ v·α*_k.
Oracle BruteForceNonnegative(const Problem& p, const Normal& q, double lambda) {
  const int n = p.n;
  Oracle best;
  for (int mask = 0; mask < (1 << n); ++mask) {
    std::vector<int> S;
    for (int k = 0; k < n; ++k)
      if (mask >> k & 1) S.push_back(k);
    const int s = static_cast<int>(S.size());
    std::vector<Ld> Gss(size_t(s) * s), rhs(s), x;
    for (int i = 0; i < s; ++i) {
      for (int j = 0; j < s; ++j) Gss[i * s + j] = q.G[size_t(S[i]) * n + S[j]];
      rhs[i] = q.c[S[i]] - lambda;
    }
    if (!SolveLinear(Gss, rhs, s, &x)) continue;
    std::vector<double> alpha(n, 0.0);
    bool ok = true;
    for (int i = 0; i < s; ++i) {
      ok = ok && x[i] > 0;
      alpha[S[i]] = static_cast<double>(x[i]);
    }
    if (!ok) continue;
    const std::vector<Ld> g = Gradient(q, alpha);
    for (int k = 0; k < n; ++k)
      if (!(mask >> k & 1)) ok = ok && g[k] + lambda >= -1e-9L * q.lambda_max;
    if (!ok) continue;
    const Ld f = Objective(p, alpha, lambda);
    if (f < best.objective) best = {alpha, f};
  }
  return best;
}

// α ≥ 0, and no −0 either (a caller may test the sign bit).
void ExpectNonnegative(const std::vector<double>& alpha) {
  for (size_t k = 0; k < alpha.size(); ++k) EXPECT_FALSE(std::signbit(alpha[k])) << "k " << k << ": " << alpha[k];
}

TEST(L1Solver, MatchesBruteForceOnSmallProblems) {
  int compared_alpha = 0, underdetermined = 0;
  for (uint64_t seed = 1; seed <= 4; ++seed) {
    for (int n = 1; n <= 5; ++n) {
      for (int m : {3, 4, 7, 12, 20}) {
        for (double rel : {0.5, 0.1, 1e-2, 1e-3}) {
          SCOPED_TRACE(testing::Message() << "seed " << seed << " m " << m << " n " << n << " lambda_rel " << rel);
          const Problem p = Gaussian(seed * 1000 + m * 10 + n, m, n);
          const Solved s = Solve(p, WithLambda(rel));
          ASSERT_TRUE(s.r.converged) << s.r.sweeps << " sweeps, violation " << s.r.kkt_violation;
          const Normal q = NormalEquations(p);
          EXPECT_NEAR(s.r.lambda, rel * double(q.lambda_max), rel * double(LambdaMaxRounding(p)));
          const Oracle o = BruteForce(p, q, s.r.lambda);
          ASSERT_TRUE(std::isfinite(double(o.objective)));
          const Ld v = Violation(q, s.alpha, s.r.lambda);
          const Ld gap = v * (L1Norm(s.alpha) + L1Norm(o.alpha));
          const Ld round = ObjectiveRounding(p, s.alpha, s.r.lambda) + ObjectiveRounding(p, o.alpha, s.r.lambda);
          EXPECT_LE(std::fabs(Ld(s.r.objective) - o.objective), gap + round)
              << "solver " << s.r.objective << " oracle " << double(o.objective);
          // The exact objective at the solver's α is above the optimum by at most the gap.
          EXPECT_LE(Objective(p, s.alpha, s.r.lambda) - o.objective, gap + ObjectiveRounding(p, o.alpha, s.r.lambda));
          if (m < n) ++underdetermined;
          if (m >= n) {  // G positive definite: the minimiser is unique
            const Ld bound = DistanceBound(q, s.alpha, s.r.lambda, L1Norm(o.alpha));
            EXPECT_LE(Distance(s.alpha, o.alpha), bound);
            ++compared_alpha;
          }
        }
      }
    }
  }
  EXPECT_GT(compared_alpha, 300);
  EXPECT_GT(underdetermined, 30);
}

// The KKT conditions at the returned α, recomputed from A and b in long double.
TEST(L1Solver, KktConditionsHoldAtTheDocumentedTolerance) {
  uint64_t seed = 77;
  for (int m : {10, 60, 350}) {
    for (int n : {4, 16, 32, 64}) {
      for (double rel : {0.3, 1e-2, 1e-3, 1e-5}) {
        for (int kind = 0; kind < 2; ++kind) {
          SCOPED_TRACE(testing::Message() << "m " << m << " n " << n << " lambda_rel " << rel << " kind " << kind);
          const Problem p = kind == 0 ? Gaussian(++seed, m, n) : Correlated(++seed, m, n, 0.2);
          const L1Options o = WithLambda(rel);
          const Solved s = Solve(p, o);
          ASSERT_TRUE(s.r.converged) << s.r.sweeps << " sweeps, violation " << s.r.kkt_violation;
          const Normal q = NormalEquations(p);
          const Ld v = Violation(q, s.alpha, s.r.lambda);
          const Ld rounding = GradientRounding(p, s.alpha);
          EXPECT_LE(v, o.tolerance * q.lambda_max + rounding);
          EXPECT_LE(s.r.kkt_violation, o.tolerance * (q.lambda_max + LambdaMaxRounding(p)) * (1 + kU));
          // The reported violation is the true one, up to the rounding of g.
          EXPECT_NEAR(double(s.r.kkt_violation), double(v), double(rounding));
          EXPECT_NEAR(s.r.objective, double(Objective(p, s.alpha, s.r.lambda)),
                      double(ObjectiveRounding(p, s.alpha, s.r.lambda)));
          EXPECT_NEAR(s.r.residual * s.r.residual / 2,
                      double(Objective(p, s.alpha, s.r.lambda) - s.r.lambda * L1Norm(s.alpha)),
                      double(ObjectiveRounding(p, s.alpha, s.r.lambda)));
        }
      }
    }
  }
}

// A planted sparse α*, b = Aα* (noiseless). For λ small enough to keep the signs, the lasso's
// minimiser is known in closed form: on the support S, α_S = α_LS − λ (G_SS)⁻¹ sign(α*_S)
// (α_LS = G_SS⁻¹ c_S, which is α* up to the rounding of b), and 0 off it, valid when the
// signs hold and off the support |g_k| = λ |G_kS G_SS⁻¹ s| ≤ η λ with η < 1 (checked here).
struct Planted {
  Problem p;
  std::vector<double> star;
  std::vector<int> support;
};

Planted MakePlanted(const std::vector<double>& values = {1.5, -0.8, 2.0, -1.2}) {
  Planted pl;
  pl.p = Gaussian(2010, 300, 32);
  pl.support = {3, 11, 20, 27};
  pl.star.assign(32, 0.0);
  for (int i = 0; i < 4; ++i) pl.star[pl.support[i]] = values[i];
  for (int i = 0; i < pl.p.m; ++i) {
    double s = 0;
    for (int k = 0; k < pl.p.n; ++k) s += pl.p.a(i, k) * pl.star[k];
    pl.p.b[i] = s;
  }
  return pl;
}

// Solves the planted problem at lambda_rel and checks it against the closed form; returns
// the solver's α and how far the closed form is from α*. Non-negative mode (α* ≥ 0): the
// same closed form with s = 1, valid when off the support g_k + λ ≥ (1 − η)λ, η < 1, i.e.
// −g_k ≤ ηλ (one-sided: the argument below needs only g_k + λ's distance from 0).
std::vector<double> CheckPlanted(const Planted& pl, double lambda_rel, double* shrinkage, bool nonnegative = false) {
  const Problem& p = pl.p;
  const Normal q = NormalEquations(p);
  // The tolerance: a nonzero off-support α_k at the stop would have violation
  // v ≥ (1 − η)λ − ‖G_k‖₂·‖α − α_opt‖₂ ≥ (1 − η)λ − ‖G_k‖₂·√n·v·‖G⁻¹‖_F, so the support is
  // exact once τ·λ_max·(1 + max_k ‖G_k‖₂·√n·‖G⁻¹‖_F) < (1 − η)λ (asserted below with a
  // factor 2 to spare). The default τ = 1e-6 is above (1 − η)·lambda_rel for lambda_rel = 1e-6.
  const double tolerance = 1e-12;
  const Solved s = Solve(p, WithLambda(lambda_rel, tolerance, nonnegative));
  EXPECT_TRUE(s.r.converged) << s.r.sweeps << " sweeps";
  if (nonnegative) ExpectNonnegative(s.alpha);
  const double lambda = s.r.lambda;

  const int k = static_cast<int>(pl.support.size());
  std::vector<Ld> Gss(k * k), cs(k), rhs(k), sign(k), x, ls, shrink;
  for (int i = 0; i < k; ++i) {
    for (int j = 0; j < k; ++j) Gss[i * k + j] = q.G[size_t(pl.support[i]) * p.n + pl.support[j]];
    sign[i] = pl.star[pl.support[i]] > 0 ? 1 : -1;
    cs[i] = q.c[pl.support[i]];
    rhs[i] = cs[i] - lambda * sign[i];
  }
  EXPECT_TRUE(SolveLinear(Gss, rhs, k, &x));
  EXPECT_TRUE(SolveLinear(Gss, cs, k, &ls));
  EXPECT_TRUE(SolveLinear(Gss, sign, k, &shrink));
  std::vector<double> closed(p.n, 0.0);
  Ld ls_error = 0;  // α_LS − α*: b = Aα* rounded
  for (int i = 0; i < k; ++i) {
    closed[pl.support[i]] = double(x[i]);
    EXPECT_GT(x[i] * sign[i], 0) << "λ too large for the closed form: a sign flips";
    ls_error = std::max(ls_error, std::fabs(ls[i] - pl.star[pl.support[i]]));
  }
  const std::vector<Ld> g = Gradient(q, closed);
  Ld eta = 0, col_norm = 0;
  for (int c = 0; c < p.n; ++c) {
    if (pl.star[c] == 0) eta = std::max(eta, (nonnegative ? -g[c] : std::fabs(g[c])) / lambda);
    Ld s2 = 0;
    for (int l = 0; l < p.n; ++l) s2 += q.G[size_t(c) * p.n + l] * q.G[size_t(c) * p.n + l];
    col_norm = std::max(col_norm, std::sqrt(s2));
  }
  EXPECT_LT(eta, 0.9) << "off-support correlation too strong for the closed form";
  const Ld inv = InverseFrobenius(q);
  EXPECT_LT(tolerance * q.lambda_max * (1 + col_norm * std::sqrt(Ld(p.n)) * inv), (1 - eta) * lambda / 2);

  for (int c = 0; c < p.n; ++c) {
    if (pl.star[c] == 0) {
      EXPECT_EQ(s.alpha[c], 0.0) << "column " << c;
    } else {
      EXPECT_NE(s.alpha[c], 0.0) << "column " << c;
    }
  }
  const Ld bound = DistanceBound(q, s.alpha, lambda, L1Norm(closed), nonnegative);
  EXPECT_LE(Distance(s.alpha, closed), bound);
  // The shrinkage α* − α = λ·G_SS⁻¹·sign(α*_S), up to the distance bound and α_LS − α*.
  for (int i = 0; i < k; ++i) {
    const int c = pl.support[i];
    EXPECT_NEAR(pl.star[c] - s.alpha[c], double(lambda * shrink[i]), double(bound + ls_error)) << "column " << c;
  }
  *shrinkage = double(Distance(closed, pl.star));
  return s.alpha;
}

TEST(L1Solver, RecoversPlantedSparseSolution) {
  const Planted pl = MakePlanted();
  double shrinkage = 0;
  const std::vector<double> alpha = CheckPlanted(pl, 1e-6, &shrinkage);
  for (int c : pl.support) EXPECT_NEAR(alpha[c], pl.star[c], 1e-4 * std::fabs(pl.star[c]));
}

TEST(L1Solver, ShrinksPlantedSupportByTheClosedForm) {
  const Planted pl = MakePlanted();
  double shrinkage = 0;
  CheckPlanted(pl, 0.1, &shrinkage);
  EXPECT_GT(shrinkage, 0.05);  // λ visibly moves α away from α*: the closed form is what is checked
}

TEST(L1Solver, EmptyProblemsGiveZero) {
  for (bool nonnegative : {false, true}) {
    SCOPED_TRACE(testing::Message() << "nonnegative " << nonnegative);
    L1Scratch scratch;
    L1Options o;
    o.nonnegative = nonnegative;
    {  // n = 0: nothing to fit, the residual is b
      const double b[3] = {3, 0, 4};
      const L1Result r = SolveL1LeastSquares(nullptr, 3, 0, b, o, scratch, nullptr);
      EXPECT_TRUE(r.converged);
      EXPECT_EQ(r.sweeps, 0);
      EXPECT_EQ(r.lambda, 0);
      EXPECT_EQ(r.residual, 5);
      EXPECT_EQ(r.objective, 12.5);
    }
    {  // m = 0: no constraint
      double alpha[3] = {1, 2, 3};
      const L1Result r = SolveL1LeastSquares(nullptr, 0, 3, nullptr, o, scratch, alpha);
      EXPECT_TRUE(r.converged);
      EXPECT_EQ(r.sweeps, 0);
      EXPECT_EQ(r.residual, 0);
      EXPECT_EQ(r.objective, 0);
      for (double a : alpha) EXPECT_EQ(a, 0);
    }
    {  // b = 0
      Problem p = Gaussian(5, 20, 6);
      std::fill(p.b.begin(), p.b.end(), 0.0);
      const Solved s = Solve(p, o);
      EXPECT_TRUE(s.r.converged);
      EXPECT_EQ(s.r.sweeps, 0);
      EXPECT_EQ(s.r.residual, 0);
      EXPECT_EQ(s.r.objective, 0);
      for (double a : s.alpha) EXPECT_EQ(a, 0);
    }
    {  // A = 0
      Problem p = Gaussian(6, 20, 6);
      std::fill(p.A.begin(), p.A.end(), 0.0);
      const Solved s = Solve(p, o);
      EXPECT_TRUE(s.r.converged);
      EXPECT_EQ(s.r.lambda, 0);
      for (double a : s.alpha) EXPECT_EQ(a, 0);
      double bb = 0;
      for (double v : p.b) bb += v * v;
      EXPECT_NEAR(s.r.residual, std::sqrt(bb), Gamma(p.m + 1) * std::sqrt(bb));
    }
  }
}

TEST(L1Solver, LambdaAtLeastLambdaMaxGivesZeroWithoutSweeping) {
  const Problem p = Gaussian(8, 40, 10);
  const Solved at = Solve(p, WithLambda(1.0));
  EXPECT_TRUE(at.r.converged);
  EXPECT_EQ(at.r.sweeps, 0);
  for (double a : at.alpha) EXPECT_EQ(a, 0);
}

// Just below λ_max only the most correlated column k enters, with the closed form
// α_k = sign(c_k)(|c_k| − λ)/G_kk, valid while every other |c_j − G_jk α_k| ≤ λ (checked).
TEST(L1Solver, JustBelowLambdaMaxOnlyTheMostCorrelatedColumnEnters) {
  const Problem p = Gaussian(8, 40, 10);
  const double rel = 1 - 1e-6;
  const Solved s = Solve(p, WithLambda(rel, 1e-12));  // 1e-12 ≪ 1 − rel: α = 0 would not pass
  ASSERT_TRUE(s.r.converged);
  const Normal q = NormalEquations(p);
  int k = 0;
  for (int j = 1; j < p.n; ++j)
    if (std::fabs(q.c[j]) > std::fabs(q.c[k])) k = j;
  const Ld lambda = s.r.lambda;
  std::vector<double> closed(p.n, 0.0);
  closed[k] = double((q.c[k] > 0 ? 1 : -1) * (std::fabs(q.c[k]) - lambda) / q.G[size_t(k) * p.n + k]);
  for (int j = 0; j < p.n; ++j) {
    if (j == k) continue;
    ASSERT_LT(std::fabs(q.c[j] - q.G[size_t(j) * p.n + k] * closed[k]), lambda) << "column " << j;
    EXPECT_EQ(s.alpha[j], 0.0) << "column " << j;
  }
  EXPECT_NE(s.alpha[k], 0.0);
  EXPECT_LE(Distance(s.alpha, closed), DistanceBound(q, s.alpha, s.r.lambda, L1Norm(closed)));
}

TEST(L1Solver, ZeroColumnStaysZeroAndLeavesTheRestUnchanged) {
  const Problem p = Gaussian(9, 30, 6);
  Problem z = p;  // column 2 zeroed
  std::fill(z.A.begin() + 2 * z.m, z.A.begin() + 3 * z.m, 0.0);
  Problem reduced = p;  // column 2 removed
  reduced.n = 5;
  reduced.A.erase(reduced.A.begin() + 2 * p.m, reduced.A.begin() + 3 * p.m);
  for (double rel : {0.1, 1e-3}) {
    const Solved sz = Solve(z, WithLambda(rel));
    const Solved sr = Solve(reduced, WithLambda(rel));
    ASSERT_TRUE(sz.r.converged);
    ASSERT_TRUE(sr.r.converged);
    EXPECT_EQ(sz.alpha[2], 0.0);
    EXPECT_EQ(sz.r.lambda, sr.r.lambda);
    // Both are within the distance bound of the reduced problem's unique minimiser.
    std::vector<double> without = sz.alpha;
    without.erase(without.begin() + 2);
    const Normal q = NormalEquations(reduced);
    const Ld norm = L1Norm(sr.alpha);
    EXPECT_LE(Distance(without, sr.alpha),
              DistanceBound(q, without, sr.r.lambda, norm) + DistanceBound(q, sr.alpha, sr.r.lambda, norm));
  }
}

TEST(L1Solver, DuplicateColumnsGiveADeterministicMinimiser) {
  Problem p = Gaussian(10, 12, 5);
  std::copy(p.A.begin() + 1 * p.m, p.A.begin() + 2 * p.m, p.A.begin() + 3 * p.m);  // column 3 = column 1
  const Normal q = NormalEquations(p);
  for (double rel : {0.2, 1e-2}) {
    const Solved a = Solve(p, WithLambda(rel));
    ASSERT_TRUE(a.r.converged);
    // Same bits from a fresh call and from a scratch already used for another problem.
    L1Scratch used;
    std::vector<double> other(40), ob(20), alpha(p.n);
    for (int i = 0; i < 40; ++i) other[i] = std::sin(i + 1.0);
    for (int i = 0; i < 20; ++i) ob[i] = std::cos(i + 1.0);
    SolveL1LeastSquares(other.data(), 20, 2, ob.data(), L1Options{}, used, alpha.data());
    const L1Result r = SolveL1LeastSquares(p.A.data(), p.m, p.n, p.b.data(), WithLambda(rel), used, alpha.data());
    EXPECT_EQ(alpha, a.alpha);
    EXPECT_EQ(r.sweeps, a.r.sweeps);
    EXPECT_EQ(r.objective, a.r.objective);
    // A minimiser: the objective of the brute force (which skips the singular supports).
    const Oracle o = BruteForce(p, q, a.r.lambda);
    const Ld gap = Violation(q, a.alpha, a.r.lambda) * (L1Norm(a.alpha) + L1Norm(o.alpha));
    EXPECT_LE(std::fabs(Ld(a.r.objective) - o.objective),
              gap + ObjectiveRounding(p, a.alpha, a.r.lambda) + ObjectiveRounding(p, o.alpha, a.r.lambda));
    // The duplicates' weights never oppose (that would cost λ‖α‖₁ for nothing).
    EXPECT_GE(a.alpha[1] * a.alpha[3], 0.0);
  }
}

// The run capped one round before the uncapped run converges follows the same path and
// stops there, unconverged, reporting its true violation.
TEST(L1Solver, StopsUnconvergedAtMaxSweeps) {
  for (bool nonnegative : {false, true}) {
    SCOPED_TRACE(testing::Message() << "nonnegative " << nonnegative);
    const Problem p = Correlated(11, 200, 32, 0.05);
    L1Options o = WithLambda(1e-4, 1e-12, nonnegative);
    const Solved full = Solve(p, o);
    ASSERT_TRUE(full.r.converged);
    ASSERT_GE(full.r.sweeps, 2);
    o.max_sweeps = full.r.sweeps - 1;
    const Solved s = Solve(p, o);
    EXPECT_FALSE(s.r.converged);
    EXPECT_EQ(s.r.sweeps, o.max_sweeps);
    const Normal q = NormalEquations(p);
    EXPECT_GT(s.r.kkt_violation, o.tolerance * q.LambdaMax(nonnegative));
    EXPECT_NEAR(double(s.r.kkt_violation), double(Violation(q, s.alpha, s.r.lambda, nonnegative)),
                double(GradientRounding(p, s.alpha)));
    o.max_sweeps = 0;
    const Solved none = Solve(p, o);
    EXPECT_FALSE(none.r.converged);
    EXPECT_EQ(none.r.sweeps, 0);
    for (double a : none.alpha) EXPECT_EQ(a, 0);
    // At α = 0 the violation is λ_max − λ.
    EXPECT_NEAR(none.r.kkt_violation, double((1 - 1e-4L) * q.LambdaMax(nonnegative)), 2 * double(LambdaMaxRounding(p)));
  }
}

TEST(L1Solver, NonFiniteInputStopsAtOnce) {
  for (bool nonnegative : {false, true}) {
    SCOPED_TRACE(testing::Message() << "nonnegative " << nonnegative);
    Problem p = Gaussian(12, 20, 4);
    p.b[3] = std::numeric_limits<double>::quiet_NaN();
    const Solved s = Solve(p, WithLambda(1e-3, 1e-6, nonnegative));
    EXPECT_FALSE(s.r.converged);
    EXPECT_EQ(s.r.sweeps, 0);
    for (double a : s.alpha) EXPECT_EQ(a, 0);
    // Every c_k = −inf (positive columns, b = −1e308: the sum overflows): no positive
    // correlation, but no meaningful fit either.
    Problem q = Correlated(12, 20, 4, 0.1);
    std::fill(q.b.begin(), q.b.end(), -1e308);
    const Solved t = Solve(q, WithLambda(1e-3, 1e-6, nonnegative));
    EXPECT_FALSE(t.r.converged);
    EXPECT_EQ(t.r.sweeps, 0);
    for (double a : t.alpha) EXPECT_EQ(a, 0);
  }
}

// λ is relative to λ_max and the stop to τ·λ_max, so scaling A by σ scales the minimiser by
// 1/σ and nothing else changes.
TEST(L1Solver, ScaleOfATimesAlphaIsInvariant) {
  for (bool nonnegative : {false, true}) {
    SCOPED_TRACE(testing::Message() << "nonnegative " << nonnegative);
    const Problem p = Correlated(13, 120, 24, 0.3);
    const Solved ref = Solve(p, WithLambda(1e-3, 1e-6, nonnegative));
    ASSERT_TRUE(ref.r.converged);
    const Normal q = NormalEquations(p);
    const Ld ref_bound = DistanceBound(q, ref.alpha, ref.r.lambda, L1Norm(ref.alpha), nonnegative);
    for (double sigma : {1e-20, 1e20}) {
      SCOPED_TRACE(testing::Message() << "sigma " << sigma);
      Problem sp = p;
      for (double& a : sp.A) a *= sigma;
      const Solved s = Solve(sp, WithLambda(1e-3, 1e-6, nonnegative));
      ASSERT_TRUE(s.r.converged);
      std::vector<double> unscaled(s.alpha);
      for (double& a : unscaled) a *= sigma;
      // σ·α and α are each within their problem's distance bound of the one minimiser (σ·A is
      // rounded, which moves the minimiser by ~cond·u, far below the bounds: 2× covers it).
      const Normal sq = NormalEquations(sp);
      const Ld bound = sigma * DistanceBound(sq, s.alpha, s.r.lambda, L1Norm(s.alpha), nonnegative) + ref_bound;
      EXPECT_LE(Distance(unscaled, ref.alpha), 2 * bound);
      EXPECT_GT(Distance(unscaled, ref.alpha), 0);  // σ·A rounds: not the same bits
    }
    // Powers of two scale every operation exactly: the same bits, divided by σ.
    for (int e : {-66, 66}) {
      Problem sp = p;
      for (double& a : sp.A) a = std::ldexp(a, e);
      const Solved s = Solve(sp, WithLambda(1e-3, 1e-6, nonnegative));
      EXPECT_EQ(s.r.sweeps, ref.r.sweeps);
      for (int k = 0; k < p.n; ++k) EXPECT_EQ(std::ldexp(s.alpha[k], e), ref.alpha[k]) << "k " << k << " 2^" << e;
      EXPECT_EQ(s.r.residual, ref.r.residual);
    }
  }
}

// ---- Non-negative mode (L1Options::nonnegative) ----

TEST(L1SolverNonnegative, IsOffByDefault) { EXPECT_FALSE(L1Options{}.nonnegative); }

// Against BruteForceNonnegative, on Gaussian and correlated columns, m < n included. Counts the
// problems where the constraint binds (the signed fit has a negative weight).
TEST(L1SolverNonnegative, MatchesBruteForceOnSmallProblems) {
  int compared_alpha = 0, underdetermined = 0, constraint_binds = 0;
  for (uint64_t seed = 1; seed <= 4; ++seed) {
    for (int n = 1; n <= 6; ++n) {
      for (int m : {3, 4, 7, 12, 20}) {
        for (int kind = 0; kind < 2; ++kind) {
          for (double rel : {0.5, 0.1, 1e-2, 1e-3}) {
            SCOPED_TRACE(testing::Message()
                         << "seed " << seed << " m " << m << " n " << n << " kind " << kind << " lambda_rel " << rel);
            const uint64_t problem_seed = seed * 1000 + m * 10 + n;
            const Problem p = kind == 0 ? Gaussian(problem_seed, m, n) : Correlated(problem_seed, m, n, 0.2);
            const Solved s = Solve(p, WithLambda(rel, 1e-6, true));
            ASSERT_TRUE(s.r.converged) << s.r.sweeps << " sweeps, violation " << s.r.kkt_violation;
            ExpectNonnegative(s.alpha);
            const Normal q = NormalEquations(p);
            EXPECT_NEAR(s.r.lambda, rel * double(q.lambda_max_nonneg), rel * double(LambdaMaxRounding(p)));
            const Oracle o = BruteForceNonnegative(p, q, s.r.lambda);
            ASSERT_TRUE(std::isfinite(double(o.objective)));
            const Ld v = Violation(q, s.alpha, s.r.lambda, true);
            const Ld gap = v * (L1Norm(s.alpha) + L1Norm(o.alpha));
            const Ld round = ObjectiveRounding(p, s.alpha, s.r.lambda) + ObjectiveRounding(p, o.alpha, s.r.lambda);
            EXPECT_LE(std::fabs(Ld(s.r.objective) - o.objective), gap + round)
                << "solver " << s.r.objective << " oracle " << double(o.objective);
            EXPECT_LE(Objective(p, s.alpha, s.r.lambda) - o.objective, gap + ObjectiveRounding(p, o.alpha, s.r.lambda));
            if (m < n) ++underdetermined;
            if (m >= n) {
              EXPECT_LE(Distance(s.alpha, o.alpha), DistanceBound(q, s.alpha, s.r.lambda, L1Norm(o.alpha), true));
              ++compared_alpha;
            }
            const Solved signed_fit = Solve(p, WithLambda(rel));
            constraint_binds +=
                std::any_of(signed_fit.alpha.begin(), signed_fit.alpha.end(), [](double a) { return a < 0; });
          }
        }
      }
    }
  }
  EXPECT_GT(compared_alpha, 600);
  EXPECT_GT(underdetermined, 100);
  EXPECT_GT(constraint_binds, 300);
}

// The KKT conditions of the constrained problem at the returned α, in long double.
TEST(L1SolverNonnegative, KktConditionsHoldAtTheDocumentedTolerance) {
  uint64_t seed = 177;
  for (int m : {10, 60, 350}) {
    for (int n : {4, 16, 32, 64}) {
      for (double rel : {0.3, 1e-2, 1e-3, 1e-5}) {
        for (int kind = 0; kind < 3; ++kind) {
          SCOPED_TRACE(testing::Message() << "m " << m << " n " << n << " lambda_rel " << rel << " kind " << kind);
          const Problem p = kind == 0 ? Gaussian(++seed, m, n) : Correlated(++seed, m, n, kind == 1 ? 0.2 : 0.02);
          const L1Options o = WithLambda(rel, 1e-6, true);
          const Solved s = Solve(p, o);
          ASSERT_TRUE(s.r.converged) << s.r.sweeps << " sweeps, violation " << s.r.kkt_violation;
          ExpectNonnegative(s.alpha);
          const Normal q = NormalEquations(p);
          const Ld v = Violation(q, s.alpha, s.r.lambda, true);
          const Ld rounding = GradientRounding(p, s.alpha);
          EXPECT_LE(v, o.tolerance * q.lambda_max_nonneg + rounding);
          EXPECT_LE(s.r.kkt_violation, o.tolerance * (q.lambda_max_nonneg + LambdaMaxRounding(p)) * (1 + kU));
          EXPECT_NEAR(double(s.r.kkt_violation), double(v), double(rounding));
          EXPECT_NEAR(s.r.objective, double(Objective(p, s.alpha, s.r.lambda)),
                      double(ObjectiveRounding(p, s.alpha, s.r.lambda)));
        }
      }
    }
  }
}

TEST(L1SolverNonnegative, RecoversPlantedNonnegativeSolution) {
  const Planted pl = MakePlanted({1.5, 0.8, 2.0, 1.2});
  double shrinkage = 0;
  const std::vector<double> alpha = CheckPlanted(pl, 1e-6, &shrinkage, true);
  for (int c : pl.support) EXPECT_NEAR(alpha[c], pl.star[c], 1e-4 * std::fabs(pl.star[c]));
}

TEST(L1SolverNonnegative, ShrinksPlantedSupportByTheClosedForm) {
  const Planted pl = MakePlanted({1.5, 0.8, 2.0, 1.2});
  double shrinkage = 0;
  CheckPlanted(pl, 0.1, &shrinkage, true);
  EXPECT_GT(shrinkage, 0.05);
}

// The case the mode is for: strongly correlated neighbours, few samples, little λ. The signed
// fit cancels large positive and negative weights; the non-negative one is the constrained
// minimiser (brute force), and costs more objective than the signed optimum.
TEST(L1SolverNonnegative, ExcludesTheSignedFitsCancellingWeights) {
  const Problem p = Correlated(31, 16, 10, 0.1);
  const Normal q = NormalEquations(p);
  for (Ld c : q.c) ASSERT_GT(c, 0);  // so both modes have the same λ_max
  const double rel = 1e-4;
  const Solved signed_fit = Solve(p, WithLambda(rel));
  const Solved s = Solve(p, WithLambda(rel, 1e-6, true));
  ASSERT_TRUE(signed_fit.r.converged);
  ASSERT_TRUE(s.r.converged);
  ASSERT_EQ(signed_fit.r.lambda, s.r.lambda);
  const double lambda = s.r.lambda;
  double negative = 0, total = 0;
  for (double a : signed_fit.alpha) {
    negative += std::max(0.0, -a);
    total += std::fabs(a);
  }
  ASSERT_GT(negative, 0.2 * total) << "the example should cancel: signed weights' negative share";

  ExpectNonnegative(s.alpha);
  const Oracle o = BruteForceNonnegative(p, q, lambda);
  ASSERT_TRUE(std::isfinite(double(o.objective)));
  const Ld gap = Violation(q, s.alpha, lambda, true) * (L1Norm(s.alpha) + L1Norm(o.alpha));
  EXPECT_LE(std::fabs(Ld(s.r.objective) - o.objective),
            gap + ObjectiveRounding(p, s.alpha, lambda) + ObjectiveRounding(p, o.alpha, lambda));
  const Ld bound = DistanceBound(q, s.alpha, lambda, L1Norm(o.alpha), true);
  ASSERT_TRUE(std::isfinite(double(bound)));  // G positive definite: a real comparison
  EXPECT_LE(Distance(s.alpha, o.alpha), bound);
  int zeros = 0;
  for (double a : s.alpha) zeros += a == 0;
  EXPECT_GT(zeros, 0);  // the constraint binds

  // The signed optimum is lower: the unconstrained minimiser is unique (G positive definite)
  // and infeasible.
  const Ld signed_gap = Violation(q, signed_fit.alpha, lambda) * (L1Norm(signed_fit.alpha) + L1Norm(s.alpha));
  EXPECT_GT(Objective(p, s.alpha, lambda) - Objective(p, signed_fit.alpha, lambda), signed_gap);
}

// λ_max is max(0, max_k c_k), not max_k |c_k|: here the column with the largest |c_k| is
// anti-correlated with b. At and above λ_max, α = 0 without a sweep; just below, only the most
// positively correlated column k enters, α_k = (c_k − λ)/G_kk, valid while every other
// c_j − G_jk α_k ≤ λ (checked).
TEST(L1SolverNonnegative, LambdaMaxIsTheLargestPositiveCorrelation) {
  Problem p = Gaussian(8, 40, 10);
  {
    const Normal q0 = NormalEquations(p);
    int k = 0;
    for (int j = 1; j < p.n; ++j)
      if (std::fabs(q0.c[j]) > std::fabs(q0.c[k])) k = j;
    if (q0.c[k] > 0)
      for (int i = 0; i < p.m; ++i) p.A[size_t(k) * p.m + i] = -p.A[size_t(k) * p.m + i];
  }
  const Normal q = NormalEquations(p);
  ASSERT_GT(q.lambda_max_nonneg, 0);
  ASSERT_LT(q.lambda_max_nonneg, q.lambda_max);
  for (double rel : {1.0, 2.0}) {
    const Solved s = Solve(p, WithLambda(rel, 1e-6, true));
    EXPECT_TRUE(s.r.converged);
    EXPECT_EQ(s.r.sweeps, 0);
    EXPECT_EQ(s.r.kkt_violation, 0);  // max(0, c_k − λ) with λ ≥ the computed max c_k
    EXPECT_NEAR(s.r.lambda, rel * double(q.lambda_max_nonneg), rel * double(LambdaMaxRounding(p)));
    for (double a : s.alpha) EXPECT_EQ(a, 0);
    ExpectNonnegative(s.alpha);
  }
  const double rel = 1 - 1e-6;
  const Solved s = Solve(p, WithLambda(rel, 1e-12, true));
  ASSERT_TRUE(s.r.converged);
  ExpectNonnegative(s.alpha);
  int k = 0;
  for (int j = 1; j < p.n; ++j)
    if (q.c[j] > q.c[k]) k = j;
  const Ld lambda = s.r.lambda;
  std::vector<double> closed(p.n, 0.0);
  closed[k] = double((q.c[k] - lambda) / q.G[size_t(k) * p.n + k]);
  for (int j = 0; j < p.n; ++j) {
    if (j == k) continue;
    ASSERT_LT(q.c[j] - q.G[size_t(j) * p.n + k] * closed[k], lambda) << "column " << j;
    EXPECT_EQ(s.alpha[j], 0.0) << "column " << j;
  }
  EXPECT_GT(s.alpha[k], 0.0);
  EXPECT_LE(Distance(s.alpha, closed), DistanceBound(q, s.alpha, s.r.lambda, L1Norm(closed), true));
}

// b correlates negatively with every column (positive columns, negative b): λ_max = 0 and
// α = 0 is the constrained minimiser (g_k + λ = −c_k > 0), converged without a sweep, even with
// fewer samples than columns. The signed fit of the same problem is not zero.
TEST(L1SolverNonnegative, OnlyNegativeCorrelationsGiveZero) {
  for (int m : {60, 5}) {
    SCOPED_TRACE(testing::Message() << "m " << m);
    Problem p = Correlated(21, m, 12, 0.2);
    for (double& v : p.b) v = -v;
    const Normal q = NormalEquations(p);
    for (Ld c : q.c) ASSERT_LT(c, 0);
    for (double rel : {1e-3, 0.0}) {
      const Solved s = Solve(p, WithLambda(rel, 1e-6, true));
      EXPECT_TRUE(s.r.converged);
      EXPECT_EQ(s.r.sweeps, 0);
      EXPECT_EQ(s.r.lambda, 0);
      EXPECT_EQ(s.r.kkt_violation, 0);
      for (double a : s.alpha) EXPECT_EQ(a, 0);
      ExpectNonnegative(s.alpha);
      double bb = 0;
      for (double v : p.b) bb += v * v;
      EXPECT_NEAR(s.r.residual, std::sqrt(bb), Gamma(p.m + 1) * std::sqrt(bb));
      EXPECT_NEAR(s.r.objective, 0.5 * bb, Gamma(p.m + 1) * bb);
    }
    const Solved signed_fit = Solve(p, WithLambda(1e-3));
    EXPECT_TRUE(std::any_of(signed_fit.alpha.begin(), signed_fit.alpha.end(), [](double a) { return a != 0; }));
  }
}

TEST(L1SolverNonnegative, DuplicateColumnsGiveADeterministicMinimiser) {
  Problem p = Gaussian(10, 12, 5);
  std::copy(p.A.begin() + 1 * p.m, p.A.begin() + 2 * p.m, p.A.begin() + 3 * p.m);  // column 3 = column 1
  const Normal q = NormalEquations(p);
  for (double rel : {0.2, 1e-2}) {
    SCOPED_TRACE(testing::Message() << "lambda_rel " << rel);
    const L1Options o = WithLambda(rel, 1e-6, true);
    const Solved a = Solve(p, o);
    ASSERT_TRUE(a.r.converged);
    ExpectNonnegative(a.alpha);
    L1Scratch used;
    std::vector<double> other(40), ob(20), alpha(p.n);
    for (int i = 0; i < 40; ++i) other[i] = std::sin(i + 1.0);
    for (int i = 0; i < 20; ++i) ob[i] = std::cos(i + 1.0);
    SolveL1LeastSquares(other.data(), 20, 2, ob.data(), L1Options{}, used, alpha.data());
    const L1Result r = SolveL1LeastSquares(p.A.data(), p.m, p.n, p.b.data(), o, used, alpha.data());
    EXPECT_EQ(alpha, a.alpha);
    EXPECT_EQ(r.sweeps, a.r.sweeps);
    EXPECT_EQ(r.objective, a.r.objective);
    const Oracle o2 = BruteForceNonnegative(p, q, a.r.lambda);
    const Ld gap = Violation(q, a.alpha, a.r.lambda, true) * (L1Norm(a.alpha) + L1Norm(o2.alpha));
    EXPECT_LE(std::fabs(Ld(a.r.objective) - o2.objective),
              gap + ObjectiveRounding(p, a.alpha, a.r.lambda) + ObjectiveRounding(p, o2.alpha, a.r.lambda));
  }
}

TEST(L1Solver, ReusedScratchDoesNotAllocate) {
  const Problem big = Gaussian(14, 350, 32), small = Gaussian(15, 100, 12);
  L1Scratch scratch;
  std::vector<double> alpha(32);
  SolveL1LeastSquares(big.A.data(), big.m, big.n, big.b.data(), L1Options{}, scratch, alpha.data());
  const int64_t before = g_allocations.load();
  const L1Options nonneg = WithLambda(1e-3, 1e-6, true);
  for (int rep = 0; rep < 3; ++rep) {
    SolveL1LeastSquares(big.A.data(), big.m, big.n, big.b.data(), L1Options{}, scratch, alpha.data());
    SolveL1LeastSquares(small.A.data(), small.m, small.n, small.b.data(), L1Options{}, scratch, alpha.data());
    SolveL1LeastSquares(big.A.data(), big.m, big.n, big.b.data(), nonneg, scratch, alpha.data());
    SolveL1LeastSquares(small.A.data(), small.m, small.n, small.b.data(), nonneg, scratch, alpha.data());
  }
  EXPECT_EQ(g_allocations.load(), before);
}

}  // namespace
}  // namespace ltb::sample
