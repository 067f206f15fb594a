#include "stages/cpca/cpca.h"

#include <Eigen/Dense>
#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <numeric>
#include <queue>

#include "format/io/container_reader.h"
#include "format/io/container_writer.h"
#include "format/io/file.h"
#include "format/io/file_lock.h"
#include "stages/common/basis.h"
#include "stages/common/parallel_for.h"
#include "stages/cpca/cpca_checkpoint.h"
#include "stages/cpca/cpca_model.h"

namespace ltb::stages {

using namespace ltb::format;
using Mat = Eigen::MatrixXd;
using RowMat = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;

std::string CpcaCheckpointPath(const std::string& output) { return output + ".cpca-state"; }

namespace {

// Rows per assignment GEMM. Fixed, and every pass partitions the rows the same way
// (blocks aligned at row 0), so a row's arithmetic never depends on --jobs, the input's
// chunking or where a run was interrupted.
constexpr uint64_t kSubRows = 256;

// Rows per pass block (the unit of streaming and of per-cluster accumulation): about
// 8 MiB of doubles, a multiple of kSubRows; depends only on D.
uint64_t PassBlockRows(uint64_t d) {
  uint64_t r = (8ull << 20) / (d * 8);
  return std::max(kSubRows, r / kSubRows * kSubRows);
}

uint64_t SplitMix64(uint64_t x) {
  x += 0x9E3779B97F4A7C15ull;
  x = (x ^ (x >> 30)) * 0xBF58476D1CE4E5B9ull;
  x = (x ^ (x >> 27)) * 0x94D049BB133111EBull;
  return x ^ (x >> 31);
}
double Unit(uint64_t h) { return static_cast<double>(h >> 11) * 0x1p-53; }  // [0, 1)

std::vector<uint64_t> Levels(uint64_t s, uint64_t step) {
  std::vector<uint64_t> l{0};
  while (l.back() < s) l.push_back(std::min(s, l.back() + std::max<uint64_t>(1, step)));
  return l;
}

// Reads rows [row0, row0 + n) of the f32 row-block matrix as doubles.
Status ReadRows(const io::ContainerReader& in, uint64_t row0, uint64_t n, double* out) {
  const ArraySpec& a = in.metadata().matrix();
  uint64_t r = row0;
  while (r < row0 + n) {
    const uint64_t c = r / a.block;
    LTB_ASSIGN_OR_RETURN(io::Chunk chunk, in.ReadChunk(0, c));
    const ChunkExtent e = chunk.extent();
    auto v = chunk.as<float>();
    const uint64_t end = std::min(row0 + n, e.row0 + e.rows);
    for (uint64_t i = r; i < end; ++i) {
      const float* src = v.data() + (i - e.row0) * a.cols;
      double* dst = out + (i - row0) * a.cols;
      for (uint64_t j = 0; j < a.cols; ++j) {
        if (!std::isfinite(src[j])) {
          return InvalidArgument(in.path() + ": row " + std::to_string(i) + ", column " + std::to_string(j) + " is " +
                                 std::to_string(src[j]) + "; cpca needs finite values");
        }
        dst[j] = src[j];
      }
    }
    r = end;
  }
  return Status::Ok();
}

// Top-p principal directions of C from Y = C·Q (Q: D×p orthonormal), by the stabilised
// Nyström approximation C ≈ Y (QᵀY)⁻¹ Yᵀ (Halko, Martinsson, Tropp 2011, §5.5; Tropp et al.
// 2017): exact when rank C ≤ p and QᵀCQ has C's rank. Returns D×p orthonormal columns,
// decreasing eigenvalue. Eigen does the QR, Cholesky and the p×p eigenproblem.
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

// The model: per cluster a mean and p tracked directions (the first n of which are the
// bases in use at growth level n).
struct Model {
  uint64_t k = 0, d = 0, p = 0;
  RowMat mean;           // K × D
  std::vector<Mat> dir;  // K × (D × p)
};

// Least-error assignment at basis dimension n for a fixed model:
//   err_c(x) = ‖x − mean_c‖² − Σ_i (b_ci·x − b_ci·mean_c)²,
// all dot products from one GEMM of a row block with the stacked means and directions.
// `single`: the GEMM in f32 (twice as fast; used while iterating, where a rounding-level
// error only matters between near-equal clusters); the final passes use f64 throughout.
class Assigner {
 public:
  Assigner(const Model& m, uint64_t n, bool single = false) : k_(m.k), n_(n), single_(single) {
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
  // x: rows × D (row-major). ids/err per row; weights (rows × n) when asked.
  void Assign(const double* x, uint64_t rows, uint64_t d, uint32_t* ids, double* err, double* weights) const {
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

 private:
  uint64_t k_, n_;
  bool single_;
  RowMat stack_;  // K(n+1) × D: mean, then n directions, per cluster
  Eigen::Matrix<float, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor> stack_f_;
  std::vector<double> mm_, bm_;
};

// Per-cluster sums of one pass, about the pass's starting mean.
struct Accum {
  uint64_t count = 0;
  Eigen::VectorXd sum;  // Σ (x − mean)
  Mat y;                // Σ (x − mean)(x − mean)ᵀ Q   (D × p)
};

struct Params {
  uint64_t k, s, p, n_rows, d, sample_rows;
  std::vector<uint64_t> levels;
};

class Cpca {
 public:
  Cpca(const CpcaOptions& o, const io::ContainerReader& in, const Params& pr, const Progress& progress)
      : o_(o), in_(in), pr_(pr), progress_(progress) {}

  Status Initialise(Model* m);
  // One assignment + refit pass at basis dimension n. Returns Σ squared error of the
  // assignment (against the model before the refit).
  Result<double> Pass(Model* m, uint64_t n, uint64_t pass_index);
  // The final assignment with the f32-rounded model: Σ squared error of what is stored,
  // Σ ‖x‖², and the cluster sizes.
  Status Evaluate(const Model& rounded, double* err, double* norm, std::vector<uint64_t>* sizes);
  // Assigns rows [row0, row0+n) (row0 a multiple of kSubRows) with the rounded model
  // (Assigner built from it at dimension S): ids, f32 weights and per-row squared error of
  // the decoded approximation. x receives the last sub-block's rows.
  Status Encode(const Assigner& a, const Model& rounded, uint64_t row0, uint64_t n, std::vector<double>* x,
                uint32_t* ids, float* weights, double* err) const;
  uint64_t rows_done() const { return rows_done_; }
  void set_rows_done(uint64_t v) { rows_done_ = v; }

 private:
  void ReportRows(uint64_t done) const { progress_.Report(done, (o_.max_iterations + 2) * pr_.n_rows, "rows"); }
  const CpcaOptions& o_;
  const io::ContainerReader& in_;
  const Params& pr_;
  const Progress& progress_;
  uint64_t rows_done_ = 0;
};

Status Cpca::Initialise(Model* m) {
  const uint64_t n = pr_.n_rows, d = pr_.d, k = pr_.k, p = pr_.p;
  // The sample: all rows, or the sample_rows rows of smallest hash(seed, row).
  std::vector<uint64_t> rows;
  if (pr_.sample_rows >= n) {
    rows.resize(n);
    std::iota(rows.begin(), rows.end(), 0);
  } else {
    std::priority_queue<std::pair<uint64_t, uint64_t>> heap;  // (hash, row), largest on top
    for (uint64_t r = 0; r < n; ++r) {
      uint64_t h = SplitMix64(o_.seed ^ SplitMix64(r));
      if (heap.size() < pr_.sample_rows) {
        heap.push({h, r});
      } else if (std::make_pair(h, r) < heap.top()) {
        heap.pop();
        heap.push({h, r});
      }
    }
    while (!heap.empty()) {
      rows.push_back(heap.top().second);
      heap.pop();
    }
    std::sort(rows.begin(), rows.end());
  }
  const uint64_t ns = rows.size();
  RowMat x(ns, d);
  for (uint64_t i = 0; i < ns;) {  // runs of consecutive rows
    uint64_t j = i + 1;
    while (j < ns && rows[j] == rows[j - 1] + 1 && j - i < 4096) ++j;
    LTB_RETURN_IF_ERROR(ReadRows(in_, rows[i], j - i, x.data() + i * d));
    i = j;
  }
  Eigen::VectorXd xx = x.rowwise().squaredNorm();

  // Greedy k-means++ (Arthur & Vassilvitskii 2007; 2 + ln K trials per centre, as
  // scikit-learn does), from a seeded generator.
  uint64_t state = SplitMix64(o_.seed ^ 0x6B6D65616E73ull);
  auto next = [&] { return Unit(state = SplitMix64(state)); };
  std::vector<uint64_t> centres;
  centres.push_back(std::min<uint64_t>(ns - 1, static_cast<uint64_t>(next() * ns)));
  Eigen::VectorXd dist = (x.rowwise() - x.row(centres[0])).rowwise().squaredNorm();
  const uint64_t trials = 2 + static_cast<uint64_t>(std::log(static_cast<double>(k)));
  while (centres.size() < k) {
    const double total = dist.sum();
    std::vector<uint64_t> cand;
    for (uint64_t t = 0; t < trials; ++t) {
      if (!(total > 0)) {
        cand.push_back(centres.size() % ns);  // every point is a centre already
        break;
      }
      double u = next() * total, acc = 0;
      uint64_t i = 0;
      for (; i + 1 < ns; ++i) {
        acc += dist[i];
        if (acc > u) break;
      }
      cand.push_back(i);
    }
    RowMat cm(cand.size(), d);
    for (size_t t = 0; t < cand.size(); ++t) cm.row(t) = x.row(cand[t]);
    RowMat g = x * cm.transpose();
    double best_pot = INFINITY;
    uint64_t best = 0;
    Eigen::VectorXd best_dist;
    for (size_t t = 0; t < cand.size(); ++t) {
      Eigen::VectorXd nd(ns);
      const double cc = xx[cand[t]];
      for (uint64_t i = 0; i < ns; ++i) nd[i] = std::min(dist[i], std::max(0.0, xx[i] - 2 * g(i, t) + cc));
      const double pot = nd.sum();
      if (pot < best_pot) {
        best_pot = pot;
        best = cand[t];
        best_dist = std::move(nd);
      }
    }
    centres.push_back(best);
    dist = std::move(best_dist);
  }
  m->k = k;
  m->d = d;
  m->p = p;
  m->mean.resize(k, d);
  for (uint64_t c = 0; c < k; ++c) m->mean.row(c) = x.row(centres[c]);

  // Lloyd iterations on the sample (in memory).
  std::vector<uint32_t> id(ns, UINT32_MAX);
  for (int it = 0; it < 20; ++it) {
    if (progress_.Cancelled()) return Cancelled("interrupted during initialisation; rerun the same command");
    RowMat g = x * m->mean.transpose();
    Eigen::VectorXd mm = m->mean.rowwise().squaredNorm();
    bool changed = false;
    for (uint64_t i = 0; i < ns; ++i) {
      double best = INFINITY;
      uint32_t arg = 0;
      for (uint64_t c = 0; c < k; ++c) {
        double e = mm[c] - 2 * g(i, c);
        if (e < best) {
          best = e;
          arg = static_cast<uint32_t>(c);
        }
      }
      changed = changed || arg != id[i];
      id[i] = arg;
    }
    if (!changed) break;
    RowMat sum = RowMat::Zero(k, d);
    std::vector<uint64_t> cnt(k, 0);
    for (uint64_t i = 0; i < ns; ++i) {
      sum.row(id[i]) += x.row(i);
      cnt[id[i]]++;
    }
    for (uint64_t c = 0; c < k; ++c)
      if (cnt[c]) m->mean.row(c) = sum.row(c) / static_cast<double>(cnt[c]);
  }

  // Directions: seeded random start, then subspace iterations on each cluster's sample rows.
  m->dir.assign(k, Mat());
  if (p == 0) return Status::Ok();
  std::vector<std::vector<uint64_t>> members(k);
  for (uint64_t i = 0; i < ns; ++i) members[id[i]].push_back(i);
  std::vector<uint64_t> clusters(k);
  std::iota(clusters.begin(), clusters.end(), 0);
  return ParallelFor(clusters, o_.jobs, Progress{}, "clusters", [&](uint64_t c) -> Status {
    Mat q(d, p);
    for (uint64_t j = 0; j < d; ++j)
      for (uint64_t i = 0; i < p; ++i)
        q(j, i) = 2 * Unit(SplitMix64(o_.seed ^ SplitMix64(c * 0x100000001B3ull ^ SplitMix64(j * p + i)))) - 1;
    Eigen::HouseholderQR<Mat> qr(q);
    q = qr.householderQ() * Mat::Identity(d, p);
    if (!members[c].empty()) {
      RowMat z(members[c].size(), d);
      for (size_t i = 0; i < members[c].size(); ++i) z.row(i) = x.row(members[c][i]) - m->mean.row(c);
      for (int step = 0; step < 4; ++step) {
        Mat y = z.transpose() * (z * q);
        q = NystromDirections(y, q);
      }
    }
    m->dir[c] = std::move(q);
    return Status::Ok();
  });
}

Result<double> Cpca::Pass(Model* m, uint64_t n, uint64_t pass_index) {
  const uint64_t d = pr_.d, k = pr_.k, p = pr_.p, nr = pr_.n_rows;
  const uint64_t block = PassBlockRows(d);
  Assigner assigner(*m, n, /*single=*/true);
  std::vector<Accum> acc(k);
  for (auto& a : acc) {
    a.sum = Eigen::VectorXd::Zero(d);
    a.y = Mat::Zero(d, p);
  }
  // The rows with the largest errors, to reseed clusters left empty.
  const uint64_t keep = std::min<uint64_t>(k, 16);
  std::vector<std::pair<double, uint64_t>> worst;  // (error, row), best first: larger error, then lower row
  std::vector<std::vector<double>> worst_rows;
  auto better = [](const std::pair<double, uint64_t>& a, const std::pair<double, uint64_t>& b) {
    return a.first > b.first || (a.first == b.first && a.second < b.second);
  };

  std::vector<double> x(block * d), err(block);
  std::vector<uint32_t> ids(block);
  double total = 0;
  for (uint64_t row0 = 0; row0 < nr; row0 += block) {
    if (progress_.Cancelled()) {
      return Cancelled("interrupted in pass " + std::to_string(pass_index + 1) +
                       "; passes before it are checkpointed, rerun the same command to resume");
    }
    const uint64_t rows = std::min(block, nr - row0);
    std::vector<uint64_t> subs;
    for (uint64_t s = 0; s < rows; s += kSubRows) subs.push_back(s);
    LTB_RETURN_IF_ERROR(ParallelFor(subs, o_.jobs, Progress{}, "rows", [&](uint64_t s) -> Status {
      const uint64_t m_rows = std::min(kSubRows, rows - s);
      LTB_RETURN_IF_ERROR(ReadRows(in_, row0 + s, m_rows, x.data() + s * d));
      assigner.Assign(x.data() + s * d, m_rows, d, ids.data() + s, err.data() + s, nullptr);
      return Status::Ok();
    }));
    std::vector<std::vector<uint32_t>> members(k);
    for (uint64_t r = 0; r < rows; ++r) {
      members[ids[r]].push_back(static_cast<uint32_t>(r));
      total += err[r];
      std::pair<double, uint64_t> e{err[r], row0 + r};
      if (worst.size() < keep || better(e, worst.back())) {
        auto pos = std::lower_bound(worst.begin(), worst.end(), e, better);
        size_t at = pos - worst.begin();
        worst.insert(pos, e);
        worst_rows.insert(worst_rows.begin() + at, std::vector<double>(x.data() + r * d, x.data() + (r + 1) * d));
        if (worst.size() > keep) {
          worst.pop_back();
          worst_rows.pop_back();
        }
      }
    }
    std::vector<uint64_t> busy;
    for (uint64_t c = 0; c < k; ++c)
      if (!members[c].empty()) busy.push_back(c);
    LTB_RETURN_IF_ERROR(ParallelFor(busy, o_.jobs, Progress{}, "clusters", [&](uint64_t c) -> Status {
      const auto& mem = members[c];
      RowMat z(mem.size(), d);
      for (size_t i = 0; i < mem.size(); ++i) {
        z.row(i) = Eigen::Map<const Eigen::RowVectorXd>(x.data() + mem[i] * d, d) - m->mean.row(c);
      }
      acc[c].count += mem.size();
      acc[c].sum += z.colwise().sum().transpose();
      if (p > 0) {
        Mat t = z * m->dir[c];
        acc[c].y.noalias() += z.transpose() * t;
      }
      return Status::Ok();
    }));
    rows_done_ += rows;
    ReportRows(rows_done_);
  }

  // Refit: means, then directions from the streamed products (corrected to the new mean:
  // Σ(z − δ)(z − δ)ᵀ = Σ zzᵀ − count·δδᵀ, δ the mean shift).
  size_t reseeded = 0;
  std::vector<uint64_t> clusters(k);
  std::iota(clusters.begin(), clusters.end(), 0);
  std::vector<bool> reseed(k, false);
  for (uint64_t c = 0; c < k; ++c) {
    if (acc[c].count == 0 && reseeded < worst.size()) {
      reseed[c] = true;
      m->mean.row(c) = Eigen::Map<const Eigen::RowVectorXd>(worst_rows[reseeded].data(), d);
      ++reseeded;
    }
  }
  LTB_RETURN_IF_ERROR(ParallelFor(clusters, o_.jobs, Progress{}, "clusters", [&](uint64_t c) -> Status {
    if (acc[c].count == 0) return Status::Ok();  // empty: reseeded above, or kept
    const double cnt = static_cast<double>(acc[c].count);
    Eigen::VectorXd delta = acc[c].sum / cnt;
    m->mean.row(c) += delta.transpose();
    if (p > 0) {
      Mat y = acc[c].y - cnt * delta * (delta.transpose() * m->dir[c]);
      m->dir[c] = NystromDirections(y, m->dir[c]);
    }
    return Status::Ok();
  }));
  return total;
}

Status Cpca::Encode(const Assigner& a, const Model& rounded, uint64_t row0, uint64_t n, std::vector<double>* x,
                    uint32_t* ids, float* weights, double* err) const {
  const uint64_t d = pr_.d, s = pr_.s;
  x->resize(kSubRows * d);
  std::vector<double> e(kSubRows), w(kSubRows * std::max<uint64_t>(s, 1)), rec(d);
  for (uint64_t s0 = 0; s0 < n; s0 += kSubRows) {
    const uint64_t rows = std::min(kSubRows, n - s0);
    LTB_RETURN_IF_ERROR(ReadRows(in_, row0 + s0, rows, x->data()));
    a.Assign(x->data(), rows, d, ids + s0, e.data(), w.data());
    for (uint64_t r = 0; r < rows; ++r) {
      const uint32_t c = ids[s0 + r];
      float* wf = weights + (s0 + r) * s;
      for (uint64_t i = 0; i < s; ++i) wf[i] = static_cast<float>(w[r * s + i]);
      // The error of exactly what a decoder computes from the stored values.
      for (uint64_t j = 0; j < d; ++j) rec[j] = rounded.mean(c, j);
      for (uint64_t i = 0; i < s; ++i) {
        const double wi = wf[i];
        const double* b = rounded.dir[c].col(i).data();
        for (uint64_t j = 0; j < d; ++j) rec[j] += wi * b[j];
      }
      const double* xr = x->data() + r * d;
      double sq = 0;
      for (uint64_t j = 0; j < d; ++j) sq += (xr[j] - rec[j]) * (xr[j] - rec[j]);
      err[s0 + r] = sq;
    }
  }
  return Status::Ok();
}

Status Cpca::Evaluate(const Model& rounded, double* err, double* norm, std::vector<uint64_t>* sizes) {
  const uint64_t nr = pr_.n_rows, d = pr_.d;
  const uint64_t block = PassBlockRows(d);
  Assigner a(rounded, pr_.s);
  std::vector<uint32_t> ids(block);
  std::vector<float> w(block * pr_.s);
  std::vector<double> e(block), xx(block);
  sizes->assign(pr_.k, 0);
  *err = 0;
  *norm = 0;
  for (uint64_t row0 = 0; row0 < nr; row0 += block) {
    if (progress_.Cancelled()) return Cancelled("interrupted in the final pass; rerun the same command to resume");
    const uint64_t rows = std::min(block, nr - row0);
    std::vector<uint64_t> subs;
    for (uint64_t s = 0; s < rows; s += kSubRows) subs.push_back(s);
    LTB_RETURN_IF_ERROR(ParallelFor(subs, o_.jobs, Progress{}, "rows", [&](uint64_t s) -> Status {
      thread_local std::vector<double> x;
      const uint64_t m = std::min(kSubRows, rows - s);
      LTB_RETURN_IF_ERROR(Encode(a, rounded, row0 + s, m, &x, ids.data() + s, w.data() + s * pr_.s, e.data() + s));
      for (uint64_t r = 0; r < m; ++r) {
        double q = 0;
        for (uint64_t j = 0; j < d; ++j) q += x[r * d + j] * x[r * d + j];
        xx[s + r] = q;
      }
      return Status::Ok();
    }));
    for (uint64_t r = 0; r < rows; ++r) {
      *err += e[r];
      *norm += xx[r];
      (*sizes)[ids[r]]++;
    }
    rows_done_ += rows;
    ReportRows(rows_done_);
  }
  return Status::Ok();
}

// Model <-> checkpoint values: means (K·D), directions (K·D·p, column-major), then extra.
std::vector<double> ModelValues(const Model& m) {
  std::vector<double> v(m.mean.data(), m.mean.data() + m.mean.size());
  for (const Mat& q : m.dir) v.insert(v.end(), q.data(), q.data() + q.size());
  return v;
}
bool LoadModel(const std::vector<double>& v, uint64_t k, uint64_t d, uint64_t p, Model* m) {
  if (v.size() < k * d * (p + 1)) return false;
  m->k = k;
  m->d = d;
  m->p = p;
  m->mean = Eigen::Map<const RowMat>(v.data(), k, d);
  m->dir.assign(k, Mat());
  for (uint64_t c = 0; c < k; ++c) m->dir[c] = Eigen::Map<const Mat>(v.data() + k * d + c * d * p, d, p);
  return true;
}

// The model as stored: every value rounded to f32 (and held in double).
Model Rounded(const Model& m) {
  Model r = m;
  r.mean = m.mean.cast<float>().cast<double>();
  for (Mat& q : r.dir) q = q.cast<float>().cast<double>();
  return r;
}

Status WriteCheckpoint(const std::string& path, const nlohmann::json& identity, const std::string& phase,
                       uint64_t level, uint64_t level_passes, uint64_t passes, double last_error, const Model& m,
                       const nlohmann::json& extra = nullptr, const std::vector<double>& extra_values = {}) {
  CpcaCheckpoint cp;
  cp.header = {{"identity", identity},         {"phase", phase},   {"level", level},
               {"level_passes", level_passes}, {"passes", passes}, {"extra", extra}};
  cp.values = ModelValues(m);
  cp.values.push_back(last_error);
  cp.values.insert(cp.values.end(), extra_values.begin(), extra_values.end());
  return WriteCpcaCheckpoint(path, cp);
}

uint64_t StoredBytes(const io::ContainerReader& r, uint32_t array) {
  uint64_t b = 0;
  for (const auto& e : r.chunk_frames())
    if (e.header.array == array) b += e.header.payload_length;
  return b;
}

Result<CpcaResult> Summarize(const std::string& path, CpcaResult result) {
  LTB_ASSIGN_OR_RETURN(io::ContainerReader r, io::ContainerReader::Open(path));
  const auto& c = r.metadata().json["cpca"];
  result.iterations = c.value("iterations", uint64_t{0});
  result.relative_rms_error = c.value("relative_rms_error", 0.0);
  result.squared_error = c.value("squared_error", 0.0);
  result.squared_norm = c.value("squared_norm", 0.0);
  result.empty_clusters = c.value("empty_clusters", uint64_t{0});
  result.model_bytes = StoredBytes(r, 0);
  for (uint32_t a = 1; a < r.metadata().arrays.size(); ++a) result.row_bytes += StoredBytes(r, a);
  return result;
}

}  // namespace

Result<CpcaResult> RunCpca(const CpcaOptions& o, const Progress& progress) {
  if (o.clusters == 0) return InvalidArgument("--clusters 0: need at least one cluster");
  if (o.growth_step == 0) return InvalidArgument("--growth-step 0: need at least 1");
  if (o.max_iterations == 0) return InvalidArgument("--max-iterations 0: need at least 1");
  if (!(o.tolerance >= 0) || !std::isfinite(o.tolerance)) {
    return InvalidArgument("--tolerance " + std::to_string(o.tolerance) + ": need a finite value >= 0");
  }
  LTB_ASSIGN_OR_RETURN(io::ContainerReader in, io::ContainerReader::Open(o.input));
  const Metadata& meta = in.metadata();
  const ArraySpec& a = meta.matrix();
  if (CpcaModel::IsCpca(meta)) {
    return FailedPrecondition(o.input +
                              ": is already a cpca output; cpca takes a row-block matrix (rows.ltm from "
                              "`ltbake row-transform`, or raw.ltm from `ltbake sample`)");
  }
  if (a.layout != Layout::kRows) {
    return FailedPrecondition(o.input +
                              ": is stored in column blocks (layout cols); cpca streams rows: give it the "
                              "row-block matrix (rows.ltm from `ltbake row-transform`, or raw.ltm), not the output "
                              "of transpose or column-transform");
  }
  LTB_RETURN_IF_ERROR(RequireCompleteF32Matrix(in));
  const uint64_t n = a.rows, d = a.cols, k = o.clusters, s = o.basis;
  if (k > n) {
    return InvalidArgument(o.input + ": --clusters " + std::to_string(k) + " exceeds its " + std::to_string(n) +
                           " rows; use at most " + std::to_string(n) + " clusters");
  }
  if (s > d) {
    return InvalidArgument(o.input + ": --basis " + std::to_string(s) + " exceeds the " + std::to_string(d) +
                           " dimensions of its rows; use at most " + std::to_string(d));
  }
  const uint64_t p = s == 0 ? 0 : std::min(d, s + o.oversample);
  const uint64_t jobs = static_cast<uint64_t>(std::max(1, o.jobs));
  const uint64_t block = PassBlockRows(d);

  // Memory: everything but the k-means++ sample is independent of the row count.
  const uint64_t model = k * d * 8 * (1 + p);
  const uint64_t fixed = 2 * model                         // model and the rounded copy
                         + k * d * 8 * (1 + p)             // per-pass sums and Σ z zᵀ Q
                         + k * (s + 1) * d * 8             // the assignment's stacked vectors
                         + block * d * 8 * 2 + block * 24  // pass block and its ids/errors
                         + jobs * (block * d * 8 + block * p * 8 + kSubRows * (k * (s + 1) + d) * 8) + 16 * d * 8 +
                         (16ull << 20);  // reseed rows, output chunk buffers
  const uint64_t per_sample_row = d * 8 + k * 8 + 64;
  const uint64_t min_sample = std::min(n, std::max<uint64_t>(k, 256));
  if (fixed + min_sample * per_sample_row > o.mem_limit) {
    const uint64_t need = fixed + min_sample * per_sample_row;
    return FailedPrecondition(o.input + ": cpca with K = " + std::to_string(k) + ", S = " + std::to_string(s) + " on " +
                              std::to_string(d) + "-dimensional rows needs about " + std::to_string((need >> 20) + 1) +
                              " MiB, more than --mem-limit (" + std::to_string(o.mem_limit >> 20) +
                              " MiB); rerun with --mem-limit " + std::to_string((need >> 20) + 1) +
                              "MiB, or fewer clusters or basis vectors");
  }
  Params pr;
  pr.k = k;
  pr.s = s;
  pr.p = p;
  pr.n_rows = n;
  pr.d = d;
  pr.sample_rows = std::min({n, o.sample_rows, (o.mem_limit - fixed) / per_sample_row});
  pr.sample_rows = std::max(pr.sample_rows, min_sample);
  pr.levels = Levels(s, o.growth_step);

  const nlohmann::json params = {{"clusters", k},
                                 {"basis", s},
                                 {"growth_step", o.growth_step},
                                 {"level_iterations", o.level_iterations},
                                 {"max_iterations", o.max_iterations},
                                 {"tolerance", o.tolerance},
                                 {"oversample", o.oversample},
                                 {"sample_rows", pr.sample_rows},
                                 {"seed", o.seed}};
  const nlohmann::json provenance = Provenance("cpca", params, {&in});
  const std::string cp_path = CpcaCheckpointPath(o.output);

  CpcaResult result;
  result.rows = n;
  result.dims = d;
  result.clusters = k;
  result.basis = s;
  result.memory_bytes = fixed + pr.sample_rows * per_sample_row;

  // One writer per output, before the output or its checkpoint is touched (held to the end;
  // the container writer shares it).
  LTB_ASSIGN_OR_RETURN(io::FileLock output_lock, io::LockOutput(o.output));
  // An existing output: done already, resumable, or another run's.
  if (io::PathExists(o.output)) {
    auto prev = io::ContainerReader::Open(o.output);
    const bool same = prev.ok() && prev->metadata().json.value("provenance", nlohmann::json()) == provenance &&
                      CpcaModel::IsCpca(prev->metadata());
    if (same && prev->complete()) {
      // A run killed between sealing the output and removing its checkpoint left one.
      std::remove(cp_path.c_str());
      result.already_complete = true;
      return Summarize(o.output, result);
    }
    if (!same) {
      if (!o.overwrite) {
        return FailedPrecondition(o.output +
                                  ": exists and was not written by this cpca run (other input, "
                                  "parameters, or not a cpca output); remove it, or rerun with --overwrite to "
                                  "replace it");
      }
      std::remove(o.output.c_str());
      std::remove(cp_path.c_str());
    }
  }

  Cpca cpca(o, in, pr, progress);
  Model m;
  uint64_t level = 0, level_passes = 0, passes = 0;
  double last_error = -1;
  std::string phase = "iterate";
  double final_err = 0, final_norm = 0;
  std::vector<uint64_t> sizes;
  const nlohmann::json identity = {{"provenance", provenance}, {"k", k}, {"d", d}, {"p", p}, {"s", s}};
  {
    auto cp = ReadCpcaCheckpoint(cp_path, k * d * (p + 1) + 16);
    if (!cp.ok()) return cp.status();
    bool loaded = false;
    if (cp->has_value() && (**cp).header.value("identity", nlohmann::json()) == identity) {
      const CpcaCheckpoint& c = **cp;
      const uint64_t base = k * d * (p + 1);
      if (LoadModel(c.values, k, d, p, &m) && c.values.size() >= base + 1) {
        level = c.header.value("level", uint64_t{0});
        level_passes = c.header.value("level_passes", uint64_t{0});
        passes = c.header.value("passes", uint64_t{0});
        phase = c.header.value("phase", std::string("iterate"));
        last_error = c.values[base];
        loaded = level < pr.levels.size();
        if (phase == "encode") {
          const auto& extra = c.header["extra"];
          loaded = loaded && c.values.size() == base + 3 && extra.is_object() && extra.contains("sizes") &&
                   extra["sizes"].is_array() && extra["sizes"].size() == k;
          if (loaded) {
            final_err = c.values[base + 1];
            final_norm = c.values[base + 2];
            sizes = extra["sizes"].get<std::vector<uint64_t>>();
          }
        }
      }
    }
    if (loaded) {
      result.resumed = true;
    } else {
      phase = "iterate";
      level = level_passes = passes = 0;
      last_error = -1;
      LTB_RETURN_IF_ERROR(cpca.Initialise(&m));
      LTB_RETURN_IF_ERROR(WriteCheckpoint(cp_path, identity, phase, level, level_passes, passes, last_error, m));
    }
  }
  cpca.set_rows_done(passes * n);

  // Alternate assignment and refit, growing the basis dimension level by level.
  while (phase == "iterate") {
    const uint64_t dim = pr.levels[level];
    const bool last_level = level + 1 == pr.levels.size();
    LTB_ASSIGN_OR_RETURN(double e, cpca.Pass(&m, dim, passes));
    ++passes;
    ++level_passes;
    const bool converged = last_error >= 0 && last_error - e <= o.tolerance * last_error;
    last_error = e;
    if (passes >= o.max_iterations || (last_level && converged)) {
      phase = "evaluate";
    } else if (!last_level && (converged || level_passes >= o.level_iterations)) {
      ++level;
      level_passes = 0;
      last_error = -1;
    }
    LTB_RETURN_IF_ERROR(WriteCheckpoint(cp_path, identity, phase, level, level_passes, passes, last_error, m));
    if (phase == "evaluate") break;
  }
  const Model rounded = Rounded(m);
  if (phase != "encode") {
    LTB_RETURN_IF_ERROR(cpca.Evaluate(rounded, &final_err, &final_norm, &sizes));
    phase = "encode";
    LTB_RETURN_IF_ERROR(WriteCheckpoint(cp_path, identity, phase, level, level_passes, passes, last_error, m,
                                        {{"sizes", sizes}}, {final_err, final_norm}));
  }
  uint64_t empty = 0;
  for (uint64_t c : sizes) empty += c == 0;

  // The output container.
  ArraySpec vec;
  vec.name = kCpcaVectorsArray;
  vec.dtype = DType::kF32;
  vec.rows = k * (s + 1);
  vec.cols = d;
  vec.layout = Layout::kRows;
  vec.block = BlockForTargetBytes(vec.rows, d, DType::kF32, Layout::kRows, 4ull << 20);
  ArraySpec ids;
  ids.name = kCpcaIdArray;
  ids.dtype = DType::kU32;
  ids.rows = n;
  ids.cols = 1;
  ids.layout = Layout::kRows;
  ids.block =
      std::min(n, std::max<uint64_t>(kSubRows, (4ull << 20) / (std::max<uint64_t>(s, 1) * 4) / kSubRows * kSubRows));
  ArraySpec wts = ids;
  wts.name = kCpcaWeightsArray;
  wts.dtype = DType::kF32;
  wts.cols = s;
  nlohmann::json arrays = {vec.ToJson(), ids.ToJson()};
  if (s > 0) arrays.push_back(wts.ToJson());
  nlohmann::json basis = meta.json.value("basis", nlohmann::json::object());
  const double rel = final_norm > 0 ? std::sqrt(final_err / final_norm) : std::sqrt(final_err);
  nlohmann::json out_meta = {
      {"arrays", arrays},
      {"basis", basis},
      {"cpca",
       {{"clusters", k},
        {"basis_dim", s},
        {"rows", n},
        {"dims", d},
        {"iterations", passes},
        {"growth_levels", pr.levels},
        {"seed", o.seed},
        {"relative_rms_error", rel},
        {"squared_error", final_err},
        {"squared_norm", final_norm},
        {"empty_clusters", empty},
        {"vectors_array", kCpcaVectorsArray},
        {"id_array", kCpcaIdArray},
        {"weights_array", s > 0 ? nlohmann::json(kCpcaWeightsArray) : nlohmann::json(nullptr)},
        {"decode",
         "row r = v[c·(S+1)] + Σ_i w[r,i]·v[c·(S+1)+1+i], c = cluster_id[r], v = cluster_vectors "
         "(docs/CPCA.md)"}}},
      {"provenance", provenance}};
  io::WriterOptions wo;
  wo.overwrite_mismatch = o.overwrite;
  LTB_ASSIGN_OR_RETURN(io::ContainerWriter out, io::ContainerWriter::Open(o.output, out_meta, wo));
  result.resumed = result.resumed || out.resume_info().resumed;
  result.chunks_already_committed = out.resume_info().committed_chunks;

  for (uint64_t c : out.Missing(0)) {
    const ChunkExtent e = vec.Extent(c);
    std::vector<float> v(e.rows * d);
    for (uint64_t r = 0; r < e.rows; ++r) {
      const uint64_t cl = (e.row0 + r) / (s + 1), i = (e.row0 + r) % (s + 1);
      for (uint64_t j = 0; j < d; ++j) {
        v[r * d + j] = static_cast<float>(i == 0 ? rounded.mean(cl, j) : rounded.dir[cl](j, i - 1));
      }
    }
    LTB_RETURN_IF_ERROR(out.Put(0, c, BytesOf(v)));
    result.chunks_written++;
  }
  std::vector<uint64_t> row_chunks = out.Missing(1);
  if (s > 0) {
    for (uint64_t c : out.Missing(2)) row_chunks.push_back(c);
    std::sort(row_chunks.begin(), row_chunks.end());
    row_chunks.erase(std::unique(row_chunks.begin(), row_chunks.end()), row_chunks.end());
  }
  const Assigner final_assigner(rounded, s);
  std::atomic<uint64_t> written{0};
  const uint64_t base_done = cpca.rows_done();
  std::atomic<uint64_t> encoded{0};
  Status st = ParallelFor(row_chunks, o.jobs, Progress{}, "chunks", [&](uint64_t c) -> Status {
    if (progress.Cancelled()) return Cancelled("interrupted while writing; rerun the same command to resume");
    const ChunkExtent e = ids.Extent(c);
    std::vector<uint32_t> id(e.rows);
    std::vector<float> w(e.rows * s);
    std::vector<double> err(e.rows), x;
    LTB_RETURN_IF_ERROR(cpca.Encode(final_assigner, rounded, e.row0, e.rows, &x, id.data(), w.data(), err.data()));
    if (!out.Has(1, c)) {
      LTB_RETURN_IF_ERROR(out.Put(1, c, BytesOf(id)));
      written++;
    }
    if (s > 0 && !out.Has(2, c)) {
      LTB_RETURN_IF_ERROR(out.Put(2, c, BytesOf(w)));
      written++;
    }
    progress.Report(base_done + (encoded += e.rows), (o.max_iterations + 2) * n, "rows");
    return Status::Ok();
  });
  result.chunks_written += written;
  LTB_RETURN_IF_ERROR(st);
  LTB_RETURN_IF_ERROR(out.Finish());
  std::remove(cp_path.c_str());
  return Summarize(o.output, result);
}

}  // namespace ltb::stages
