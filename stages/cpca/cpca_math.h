// Internal to `ltbake cpca` (stages/cpca/cpca.h): the model in memory and the linear
// algebra of one fit, free of I/O — the least-error assignment of rows to clusters and the
// principal directions from a streamed product. Eigen does the dense work.
#pragma once

#include <Eigen/Dense>
#include <cstdint>
#include <vector>

namespace ltb::stages::cpca_internal {

using Mat = Eigen::MatrixXd;
using RowMat = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;

uint64_t SplitMix64(uint64_t x);
double Unit(uint64_t h);  // [0, 1) from a hash

// Top-p principal directions of C from Y = C·Q (Q: D×p orthonormal), by the stabilised
// Nyström approximation C ≈ Y (QᵀY)⁻¹ Yᵀ (Halko, Martinsson, Tropp 2011, §5.5; Tropp et al.
// 2017): exact when rank C ≤ p and QᵀCQ has C's rank. Returns D×p orthonormal columns,
// decreasing eigenvalue. Eigen does the QR, Cholesky and the p×p eigenproblem.
Mat NystromDirections(const Mat& y, const Mat& q);

// The model: per cluster a mean and p tracked directions (the first n of which are the
// bases in use at growth level n).
struct Model {
  uint64_t k = 0, d = 0, p = 0;
  RowMat mean;           // K × D
  std::vector<Mat> dir;  // K × (D × p)
};

// The model as stored: every value rounded to f32 (and held in double).
Model Rounded(const Model& m);

// Least-error assignment at basis dimension n for a fixed model:
//   err_c(x) = ‖x − mean_c‖² − Σ_i (b_ci·x − b_ci·mean_c)²,
// all dot products from one GEMM of a row block with the stacked means and directions.
// `single`: the GEMM in f32 (twice as fast; used while iterating, where a rounding-level
// error only matters between near-equal clusters); the final passes use f64 throughout.
class Assigner {
 public:
  Assigner(const Model& m, uint64_t n, bool single = false);
  // x: rows × D (row-major). ids/err per row; weights (rows × n) when asked.
  void Assign(const double* x, uint64_t rows, uint64_t d, uint32_t* ids, double* err, double* weights) const;

 private:
  uint64_t k_, n_;
  bool single_;
  RowMat stack_;  // K(n+1) × D: mean, then n directions, per cluster
  Eigen::Matrix<float, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor> stack_f_;
  std::vector<double> mm_, bm_;
};

}  // namespace ltb::stages::cpca_internal
