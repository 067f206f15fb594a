// The global selection of `column-transform --budget B` and `--target-error E`
// (docs/COLUMN-TRANSFORM.md "Global budget"): from every column's energy histograms at
// every depth (ColumnCompressor::Histograms, the first pass), one threshold bin for the
// whole matrix, bisected so the count of kept coefficients meets the budget (or the
// estimated relative error meets the target), and each column's depth at that threshold.
// Pure arithmetic on the histograms: the passes over the input stay in column_transform.cpp.
#pragma once

#include <cstdint>
#include <vector>

#include "stages/column_transform/column_compressor.h"

namespace ltb::stages {

// What the second pass needs: the threshold and, per column, its depth and the terms it
// takes from the bin below the threshold.
struct BudgetAllocation {
  int threshold_bin = 0;
  double lambda = 0;            // BinLowerEdge(threshold_bin)
  std::vector<int8_t> depth;    // per column: min_depth + the depth picked; −1 for an empty column
  std::vector<uint64_t> extra;  // terms each column takes from the bin below the threshold
  // The budget met: the one given, or (--target-error) the count the threshold keeps.
  uint64_t budget = 0;
  double estimated_error = 0;  // --target-error: the histograms' estimate at the threshold
};

class BudgetSolver {
 public:
  explicit BudgetSolver(uint64_t cols);

  // Records column `col`'s histograms at its `depths` depths (h[0 .. depths), the shallowest
  // first); returns the bytes now held for it. Thread-safe for distinct columns.
  uint64_t AddColumn(uint64_t col, const EnergyHistogram* h, int depths);

  // --budget: the lowest threshold that keeps at most `budget` coefficients, the rest of the
  // budget filled from the next bin down. `min_depth` is added to every depth.
  BudgetAllocation ForBudget(uint64_t budget, int min_depth) const;
  // --target-error: the largest threshold (fewest terms) whose estimated relative RMS error
  // is at most `target`.
  BudgetAllocation ForTargetError(double target, int min_depth) const;

  // Per-column energy histograms of every depth, for the budget search (compact: one set of
  // flat vectors per column).
  struct ColumnCurves {
    std::vector<uint32_t> offset;             // depths + 1 entries into the flat vectors
    std::vector<int32_t> bin;                 // ascending within a depth
    std::vector<uint64_t> count_at_or_above;  // Σ counts of bins >= this one
    std::vector<double> energy_below;         // Σ energy of bins < this one
    std::vector<double> depth_total;          // Σ energy of all bins, per depth
  };

 private:
  // The range of bins over every column; lo > hi when every column is empty.
  void BinRange(int* lo, int* hi) const;
  // Coefficients kept at threshold bin g, each column at its depth.
  uint64_t Total(int g) const;
  // --target-error: the relative error at threshold bin g, each column at its depth.
  double ErrorAt(int g) const;
  // Each column's depth at `threshold_bin`, then the fill from the bin below up to `budget`.
  BudgetAllocation Allocate(int threshold_bin, uint64_t budget, int min_depth) const;

  std::vector<ColumnCurves> curves_;
};

}  // namespace ltb::stages
