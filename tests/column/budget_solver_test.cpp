// BudgetSolver on hand-made histograms: the threshold a budget or a target error lands on,
// the depth each column picks there, and the fill from the bin below. Expected values are
// worked out by hand from the cost Σ dropped energy + λ · kept count, λ = 2^(bin/8).
#include "stages/column_transform/budget_solver.h"

#include <gtest/gtest.h>

#include <cmath>
#include <vector>

namespace ltb::stages {
namespace {

EnergyHistogram Hist(std::vector<int32_t> bin, std::vector<uint64_t> count, std::vector<double> energy) {
  return EnergyHistogram{std::move(bin), std::move(count), std::move(energy)};
}

TEST(BudgetSolver, EveryColumnEmptyKeepsNothing) {
  BudgetSolver solver(3);
  const EnergyHistogram empty[2] = {};
  for (uint64_t c = 0; c < 3; ++c) solver.AddColumn(c, empty, 2);
  for (const BudgetAllocation& a : {solver.ForBudget(10, 1), solver.ForTargetError(0.1, 1)}) {
    EXPECT_EQ(a.threshold_bin, 0);
    EXPECT_EQ(a.lambda, 1.0);
    EXPECT_EQ(a.depth, std::vector<int8_t>(3, -1));
    EXPECT_EQ(a.extra, std::vector<uint64_t>(3, 0));
    EXPECT_EQ(a.estimated_error, 0.0);
  }
  EXPECT_EQ(solver.ForBudget(10, 1).budget, 10u);
  EXPECT_EQ(solver.ForTargetError(0.1, 1).budget, 0u);
}

TEST(BudgetSolver, BudgetKeepsTheLargestBinsAndFillsFromTheBinBelow) {
  // One column, one depth: 3 coefficients in bin 0, 1 in bin 8. A budget of 2: bin 8 alone
  // fits (threshold 1), and one of bin 0's three fills the rest.
  BudgetSolver solver(1);
  const EnergyHistogram h[1] = {Hist({0, 8}, {3, 1}, {3.0, 2.0})};
  EXPECT_GT(solver.AddColumn(0, h, 1), 0u);
  BudgetAllocation a = solver.ForBudget(2, 4);
  EXPECT_EQ(a.threshold_bin, 1);
  EXPECT_DOUBLE_EQ(a.lambda, BinLowerEdge(1));
  EXPECT_EQ(a.depth, std::vector<int8_t>{4});  // min_depth + 0
  EXPECT_EQ(a.extra, std::vector<uint64_t>{1});
  EXPECT_EQ(a.budget, 2u);
  // A budget over every coefficient: the lowest bin, nothing to fill.
  a = solver.ForBudget(100, 0);
  EXPECT_EQ(a.threshold_bin, 0);
  EXPECT_EQ(a.extra, std::vector<uint64_t>{0});
}

TEST(BudgetSolver, PicksTheDepthThatConcentratesTheEnergy) {
  // Depth 0: energy 4 spread over 4 coefficients of bin 0. Depth 1: 3.5 of it in one
  // coefficient of bin 16. At threshold 1 depth 1 costs 0.5 + λ < 4 = depth 0's.
  BudgetSolver solver(2);
  const EnergyHistogram h[2] = {Hist({0}, {4}, {4.0}), Hist({0, 16}, {3, 1}, {0.5, 3.5})};
  solver.AddColumn(1, h, 2);  // column 0 stays empty
  BudgetAllocation a = solver.ForBudget(1, 2);
  EXPECT_EQ(a.threshold_bin, 1);
  EXPECT_EQ(a.depth, (std::vector<int8_t>{-1, 3}));
  EXPECT_EQ(a.extra, (std::vector<uint64_t>{0, 0}));

  // Target error 0.5: depth 1 keeps its one coefficient up to λ < 3.5 (bin 14); the error
  // there is sqrt(0.5 / 4). From bin 15 on depth 0 drops everything (error 1).
  a = solver.ForTargetError(0.5, 2);
  EXPECT_EQ(a.threshold_bin, 14);
  EXPECT_EQ(a.budget, 1u);
  EXPECT_NEAR(a.estimated_error, std::sqrt(0.5 / 4.0), 1e-12);
  EXPECT_EQ(a.depth, (std::vector<int8_t>{-1, 3}));
  EXPECT_EQ(a.extra, (std::vector<uint64_t>{0, 0}));
}

}  // namespace
}  // namespace ltb::stages
