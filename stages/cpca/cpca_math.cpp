#include "stages/cpca/cpca_math.h"

#include <algorithm>
#include <cmath>
#include <limits>

namespace ltb::stages::cpca_internal {

uint64_t SplitMix64(uint64_t x) {
  x += 0x9E3779B97F4A7C15ull;
  x = (x ^ (x >> 30)) * 0xBF58476D1CE4E5B9ull;
  x = (x ^ (x >> 27)) * 0x94D049BB133111EBull;
  return x ^ (x >> 31);
}
double Unit(uint64_t h) { return static_cast<double>(h >> 11) * 0x1p-53; }  // [0, 1)

Mat NystromDirections(const Mat& y, const Mat& q) {
  const Eigen::Index d = q.rows(), p = q.cols();
  const double norm = y.norm();
  if (!(norm > 0)) return q;  // no variance: keep the directions
  const double nu = std::numeric_limits<double>::epsilon() * std::sqrt(static_cast<double>(d)) * norm;
  Mat yn = y + nu * q;
  Mat b = q.transpose() * yn;
  b = 0.5 * (b + b.transpose()).eval();
  Eigen::HouseholderQR<Mat> qr(yn);
  Mat qy = qr.householderQ() * Mat::Identity(d, p);
  Mat r = qy.transpose() * yn;
  Eigen::LLT<Mat> llt(b);
  Mat h;
  if (llt.info() == Eigen::Success) {
    Mat g = llt.matrixL().solve(r.transpose());
    h = g.transpose() * g;
  } else {
    // Not numerically positive definite: Rayleigh–Ritz on span(Q) instead.
    Eigen::SelfAdjointEigenSolver<Mat> es(b);
    return q * es.eigenvectors().rowwise().reverse();
  }
  Eigen::SelfAdjointEigenSolver<Mat> es(0.5 * (h + h.transpose()));
  return qy * es.eigenvectors().rowwise().reverse();
}

Model Rounded(const Model& m) {
  Model r = m;
  r.mean = m.mean.cast<float>().cast<double>();
  for (Mat& q : r.dir) q = q.cast<float>().cast<double>();
  return r;
}

Assigner::Assigner(const Model& m, uint64_t n, bool single) : k_(m.k), n_(n), single_(single) {
  stack_.resize(m.k * (n + 1), m.d);
  mm_.resize(m.k);
  bm_.resize(m.k * n);
  for (uint64_t c = 0; c < m.k; ++c) {
    stack_.row(c * (n + 1)) = m.mean.row(c);
    mm_[c] = m.mean.row(c).squaredNorm();
    for (uint64_t i = 0; i < n; ++i) {
      stack_.row(c * (n + 1) + 1 + i) = m.dir[c].col(i).transpose();
      bm_[c * n + i] = m.dir[c].col(i).dot(m.mean.row(c).transpose());
    }
  }
  if (single_) {
    stack_f_ = stack_.cast<float>();
    stack_.resize(0, 0);
  }
}

void Assigner::Assign(const double* x, uint64_t rows, uint64_t d, uint32_t* ids, double* err, double* weights) const {
  Eigen::Map<const RowMat> xm(x, rows, d);
  RowMat g;
  if (single_) {
    Eigen::Matrix<float, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor> xf = xm.cast<float>();
    g = (xf * stack_f_.transpose()).cast<double>();
  } else {
    g = xm * stack_.transpose();
  }
  for (uint64_t r = 0; r < rows; ++r) {
    const double xx = xm.row(r).squaredNorm();
    double best = INFINITY;
    uint32_t arg = 0;
    for (uint64_t c = 0; c < k_; ++c) {
      const double* gc = g.data() + r * g.cols() + c * (n_ + 1);
      double e = xx - 2 * gc[0] + mm_[c];
      for (uint64_t i = 0; i < n_; ++i) {
        const double t = gc[1 + i] - bm_[c * n_ + i];
        e -= t * t;
      }
      if (e < best) {
        best = e;
        arg = static_cast<uint32_t>(c);
      }
    }
    ids[r] = arg;
    err[r] = std::max(0.0, best);
    if (weights) {
      const double* gc = g.data() + r * g.cols() + arg * (n_ + 1);
      for (uint64_t i = 0; i < n_; ++i) weights[r * n_ + i] = gc[1 + i] - bm_[arg * n_ + i];
    }
  }
}

}  // namespace ltb::stages::cpca_internal
