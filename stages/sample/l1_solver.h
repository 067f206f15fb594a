// Internal to the sample stage: the L1-regularised least-squares fit ("lasso") of sparse
// precomputation (Huang & Ramamoorthi 2010, §5.1). A sparse row of T is reconstructed as
// Σ_k α_k T(x_k) of its dense neighbours; α solves min_α ½‖Aα − b‖² + λ‖α‖₁ on the sampled
// columns. Small problems (m ≲ 2000 sampled columns, n ≲ 64 neighbours), solved per row.
//
// Algorithm: G = AᵀA and c = Aᵀb (dot products in a fixed summation order), then rounds of
// (1) one cyclic coordinate-descent sweep in index order, the gradient g = Gα − c updated
// in O(n) per changed coordinate, and (2) a step on the support S = {k : α_k ≠ 0}: the
// minimiser G_SS⁻¹(c_S − λ sign α_S) of the objective on S's sign pattern, by Cholesky;
// where it would flip a sign, the point where the first coordinate reaches 0, that
// coordinate dropped (Givens downdate of the factor) and the step repeated (feature-sign
// search); a column dependent on the others is dropped along a null direction of G_SS. The
// step is kept when it meets the tolerance or lowers the objective. CD alone needs
// thousands of sweeps when the columns are strongly correlated, as neighbouring rows of T
// are; with the step, 2–6 rounds. L1Result::sweeps counts the rounds.
//
// Tolerance: after every sweep and step g is recomputed from G and α (not the running
// updates) and the KKT violation of coordinate k is |g_k + λ·sign α_k| when α_k ≠ 0,
// max(0, |g_k| − λ) when α_k = 0. The solve stops, converged, when max_k of it ≤
// tolerance · λ_max; λ_max and the violation scale alike with A and b, so the test is
// scale-free. Then some subgradient s of the objective at α has ‖s‖_∞ ≤ tolerance·λ_max, so
// objective − optimum ≤ tolerance·λ_max·(‖α‖₁ + ‖α_opt‖₁), and ‖α − α_opt‖₂ ≤
// √n·tolerance·λ_max / λ_min(G) when G is positive definite. It stops unconverged after
// max_sweeps rounds, or earlier when a round changes nothing (a fixed point: the tolerance
// is below the rounding of g, about 1e-16 · max_k Σ_l |G_kl α_l|).
//
// Non-negative mode (L1Options::nonnegative): the same with α ≥ 0, i.e. min ½‖Aα − b‖² + λΣα_k
// over α ≥ 0; it rules out the large cancelling weights a signed fit to few samples can
// overfit with. Sweep: α_k ← max(0, c_k − Σ_{l≠k} G_kl α_l − λ)/G_kk; the support step is
// the one above with every sign +1. λ_max = max(0, max_k c_k) (0: α = 0, converged). KKT
// violation: |g_k + λ| when α_k > 0, max(0, −(g_k + λ)) when α_k = 0. Stop, bounds (α_opt the
// constrained minimiser) and determinism as above.
//
// No output but the result; no exceptions; no allocation once the scratch has grown (to
// 2n² + 5n doubles in gram, n in atb and grad). Deterministic: the same inputs give the
// same bits, and the order of every sum is fixed in the code, so they do not depend on the
// instruction set either.
#pragma once

#include <cstdint>
#include <vector>

namespace ltb::sample {

struct L1Options {
  double lambda_rel = 1e-3;  // λ = lambda_rel · λ_max, λ_max = max_k |A_kᵀ b| (the smallest λ with α = 0;
                             // max(0, max_k A_kᵀ b) when nonnegative); negative or NaN counts as 0
  double tolerance = 1e-6;   // stop when the KKT violation ≤ tolerance · λ_max (see above)
  int max_sweeps = 2000;     // cap on coordinate-descent sweeps (rounds of a sweep and a support step)
  bool nonnegative = false;  // constrain α ≥ 0 (see "Non-negative mode" above)
};

struct L1Result {
  int sweeps = 0;
  bool converged = false;
  double lambda = 0;         // the λ used
  double kkt_violation = 0;  // max_k of the KKT violation at the returned α (absolute)
  double residual = 0;       // ‖Aα − b‖₂
  double objective = 0;      // ½‖Aα − b‖² + λ‖α‖₁
};

// Scratch reused across calls (one per thread) so repeated solves do not allocate.
struct L1Scratch {
  std::vector<double> gram, atb, grad;
};

// min_α ½‖Aα − b‖² + λ‖α‖₁, subject to α ≥ 0 when options.nonnegative. A is m×n,
// column-major (column k = A + k·m: the k-th neighbour's values at the m sampled columns), b
// has m values, alpha receives n values. m, n ≥ 0 (n = 0 or b = 0 or A = 0 → α = 0,
// converged; A may be null when m = 0 or n = 0, b when m = 0, alpha when n = 0).
// λ ≥ λ_max → α = 0, converged after 0 sweeps. Non-finite A_kᵀb → α = 0, not converged.
// Deterministic (fixed sweep order), no allocation after the scratch has grown. Cyclic
// coordinate descent on the Gram form G = AᵀA, c = Aᵀb:
// α_k ← S(c_k − Σ_{l≠k} G_kl α_l, λ) / G_kk, S the soft threshold; columns with G_kk = 0 stay 0;
// each sweep followed by the support step described above. Nonnegative: S replaced by
// max(0, z − λ), and λ_max = 0 → α = 0, converged after 0 sweeps.
L1Result SolveL1LeastSquares(const double* A, int m, int n, const double* b, const L1Options& options,
                             L1Scratch& scratch, double* alpha);

}  // namespace ltb::sample
