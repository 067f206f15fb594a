#include "stages/column_transform/budget_solver.h"

#include <algorithm>
#include <cmath>

namespace ltb::stages {

namespace {

using ColumnCurves = BudgetSolver::ColumnCurves;

// Cost of column c at depth d for threshold bin g: dropped energy + λ · kept count.
struct Point {
  double cost;
  uint64_t count;
};
Point Evaluate(const ColumnCurves& cc, int d, int g, double lambda) {
  uint32_t a = cc.offset[d], b = cc.offset[d + 1];
  auto first = std::lower_bound(cc.bin.begin() + a, cc.bin.begin() + b, g) - cc.bin.begin();
  if (static_cast<uint32_t>(first) == b) return {cc.depth_total[d], 0};
  return {cc.energy_below[first] + lambda * static_cast<double>(cc.count_at_or_above[first]),
          cc.count_at_or_above[first]};
}

// The depth a column picks at threshold bin g (least cost; then fewer terms; then shallower).
int PickDepth(const ColumnCurves& cc, int g, double lambda, uint64_t* count) {
  int best = -1;
  Point bp{0, 0};
  for (int d = 0; d + 1 < static_cast<int>(cc.offset.size()); ++d) {
    Point p = Evaluate(cc, d, g, lambda);
    if (best < 0 || p.cost < bp.cost || (p.cost == bp.cost && p.count < bp.count)) {
      best = d;
      bp = p;
    }
  }
  *count = bp.count;
  return best;
}

}  // namespace

BudgetSolver::BudgetSolver(uint64_t cols) : curves_(cols) {}

uint64_t BudgetSolver::AddColumn(uint64_t col, const EnergyHistogram* h, int depths) {
  ColumnCurves& cc = curves_[col];
  cc.offset.push_back(0);
  for (int d = 0; d < depths; ++d) {
    const EnergyHistogram& hd = h[d];
    size_t base = cc.bin.size();
    double below = 0;
    for (size_t i = 0; i < hd.bin.size(); ++i) {
      cc.bin.push_back(hd.bin[i]);
      cc.energy_below.push_back(below);
      below += hd.energy[i];
    }
    cc.depth_total.push_back(below);
    cc.count_at_or_above.resize(cc.bin.size());
    uint64_t above = 0;
    for (size_t i = hd.bin.size(); i-- > 0;) {
      above += hd.count[i];
      cc.count_at_or_above[base + i] = above;
    }
    cc.offset.push_back(static_cast<uint32_t>(cc.bin.size()));
  }
  return cc.bin.size() * (4 + 8 + 8) + cc.offset.size() * 4 + cc.depth_total.size() * 8 + 128;
}

void BudgetSolver::BinRange(int* lo, int* hi) const {
  *lo = INT32_MAX;
  *hi = INT32_MIN;
  for (const ColumnCurves& cc : curves_)
    if (!cc.bin.empty()) {
      *lo = std::min(*lo, *std::min_element(cc.bin.begin(), cc.bin.end()));
      *hi = std::max(*hi, *std::max_element(cc.bin.begin(), cc.bin.end()));
    }
}

uint64_t BudgetSolver::Total(int g) const {
  double lambda = BinLowerEdge(g);
  uint64_t sum = 0;
  for (const ColumnCurves& cc : curves_) {
    if (cc.bin.empty()) continue;
    uint64_t n = 0;
    PickDepth(cc, g, lambda, &n);
    sum += n;
  }
  return sum;
}

double BudgetSolver::ErrorAt(int g) const {
  double lambda = BinLowerEdge(g), dropped = 0, energy = 0;
  for (const ColumnCurves& cc : curves_) {
    if (cc.bin.empty()) continue;
    uint64_t n = 0;
    int d = PickDepth(cc, g, lambda, &n);
    Point p = Evaluate(cc, d, g, lambda);
    dropped += p.cost - lambda * static_cast<double>(p.count);
    energy += cc.depth_total[d];
  }
  return energy > 0 ? std::sqrt(std::max(0.0, dropped) / energy) : 0.0;
}

BudgetAllocation BudgetSolver::ForBudget(uint64_t budget, int min_depth) const {
  int lo = 0, hi = 0;
  BinRange(&lo, &hi);
  int threshold_bin = 0;
  if (lo > hi) {
    threshold_bin = 0;  // every column is empty
  } else if (Total(lo) <= budget) {
    threshold_bin = lo;
  } else {
    int l = lo, h = hi + 1;  // Total(l) > budget >= Total(h)
    while (h - l > 1) {
      int mid = l + (h - l) / 2;
      (Total(mid) <= budget ? h : l) = mid;
    }
    threshold_bin = h;
  }
  return Allocate(threshold_bin, budget, min_depth);
}

BudgetAllocation BudgetSolver::ForTargetError(double target, int min_depth) const {
  int lo = 0, hi = 0;
  BinRange(&lo, &hi);
  if (lo > hi) return Allocate(0, 0, min_depth);  // every column is empty
  // The largest threshold (fewest terms) within the target; bins are 1/8 octave apart.
  const double t = target;
  int threshold_bin = 0;
  if (ErrorAt(hi + 1) <= t) {
    threshold_bin = hi + 1;
  } else {
    int l = lo, h = hi + 1;  // ErrorAt(l) ≤ t (every term kept) < ErrorAt(h)
    while (h - l > 1) {
      int mid = l + (h - l) / 2;
      (ErrorAt(mid) <= t ? l : h) = mid;
    }
    threshold_bin = l;
  }
  // Met exactly: nothing to fill from the bin below.
  BudgetAllocation alloc = Allocate(threshold_bin, Total(threshold_bin), min_depth);
  alloc.estimated_error = ErrorAt(threshold_bin);
  return alloc;
}

BudgetAllocation BudgetSolver::Allocate(int threshold_bin, uint64_t budget, int min_depth) const {
  const uint64_t cols = curves_.size();
  BudgetAllocation alloc;
  alloc.threshold_bin = threshold_bin;
  alloc.budget = budget;
  alloc.depth.assign(cols, -1);
  alloc.extra.assign(cols, 0);
  double lambda = BinLowerEdge(threshold_bin);
  uint64_t used = 0;
  std::vector<uint64_t> in_next_bin(cols, 0);  // terms of bin threshold_bin − 1 at the chosen depth
  for (uint64_t c = 0; c < cols; ++c) {
    if (curves_[c].bin.empty()) continue;
    uint64_t n = 0;
    int d = PickDepth(curves_[c], threshold_bin, lambda, &n);
    alloc.depth[c] = static_cast<int8_t>(min_depth + d);
    used += n;
    Point below = Evaluate(curves_[c], d, threshold_bin - 1, BinLowerEdge(threshold_bin - 1));
    in_next_bin[c] = below.count - n;
  }
  // The bins are 1/8 octave wide, and many equal values (a lit floor) can share one: fill
  // what is left of the budget from the next bin down, at each column's chosen depth,
  // in column order (each extra term lowers the error by at least λ/2^(1/8)).
  for (uint64_t c = 0; c < cols && used < budget; ++c) {
    uint64_t take = std::min(in_next_bin[c], budget - used);
    alloc.extra[c] = take;
    used += take;
  }
  alloc.lambda = lambda;
  return alloc;
}

}  // namespace ltb::stages
