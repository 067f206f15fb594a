// Over 700 lines: one fitter (seeding, passes, growth, encoding) whose steps share its state;
// the maths without state is cpca_math.cpp, the checkpoint cpca_checkpoint.cpp.
#include "stages/cpca/cpca_fit.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <numeric>
#include <optional>
#include <queue>

#include "stages/common/parallel_for.h"
#include "stages/cpca/cpca_checkpoint.h"

namespace ltb::stages::cpca_internal {

using namespace ltb::format;

uint64_t PassBlockRows(uint64_t d) {
  uint64_t r = (8ull << 20) / (d * 8);
  return std::max(kSubRows, r / kSubRows * kSubRows);
}

uint64_t PassGroupBlocks(uint64_t d, int jobs) {
  const uint64_t subs = PassBlockRows(d) / kSubRows;
  const uint64_t threads = static_cast<uint64_t>(std::max(1, jobs));
  return std::max<uint64_t>(1, (threads + subs - 1) / subs);
}

std::vector<uint64_t> Levels(uint64_t s, uint64_t step) {
  std::vector<uint64_t> l{0};
  while (l.back() < s) l.push_back(std::min(s, l.back() + std::max<uint64_t>(1, step)));
  return l;
}

namespace {

// Copies row i (of the matrix) from its chunk as doubles (or f32, for the dense-row cache),
// refusing non-finite values.
template <typename T>
Status CopyRow(const io::ContainerReader& in, const io::Chunk& chunk, uint64_t i, T* dst) {
  const uint64_t cols = in.metadata().matrix().cols;
  const float* src = chunk.as<float>().data() + (i - chunk.extent().row0) * cols;
  for (uint64_t j = 0; j < cols; ++j) {
    if (!std::isfinite(src[j])) {
      return InvalidArgument(in.path() + ": row " + std::to_string(i) + ", column " + std::to_string(j) + " is " +
                             std::to_string(src[j]) + "; cpca needs finite values");
    }
    dst[j] = src[j];
  }
  return Status::Ok();
}

// Reads rows [row0, row0 + n) of the f32 row-block matrix as doubles.
Status ReadRows(const io::ContainerReader& in, uint64_t row0, uint64_t n, double* out) {
  const ArraySpec& a = in.metadata().matrix();
  uint64_t r = row0;
  while (r < row0 + n) {
    const uint64_t c = r / a.block;
    LTB_ASSIGN_OR_RETURN(io::Chunk chunk, in.ReadChunk(0, c));
    const ChunkExtent e = chunk.extent();
    const uint64_t end = std::min(row0 + n, e.row0 + e.rows);
    for (uint64_t i = r; i < end; ++i) LTB_RETURN_IF_ERROR(CopyRow(in, chunk, i, out + (i - row0) * a.cols));
    r = end;
  }
  return Status::Ok();
}

// Reads the rows rows[0..n) (ascending) as doubles into consecutive rows of out, each
// input chunk once.
Status ReadRowList(const io::ContainerReader& in, const uint64_t* rows, uint64_t n, double* out) {
  const ArraySpec& a = in.metadata().matrix();
  for (uint64_t i = 0; i < n;) {
    const uint64_t c = rows[i] / a.block;
    LTB_ASSIGN_OR_RETURN(io::Chunk chunk, in.ReadChunk(0, c));
    for (; i < n && rows[i] / a.block == c; ++i) LTB_RETURN_IF_ERROR(CopyRow(in, chunk, rows[i], out + i * a.cols));
  }
  return Status::Ok();
}

// ReadRowList on `jobs` threads, one input chunk's rows per task (the same values).
Status ReadRowListParallel(const io::ContainerReader& in, const uint64_t* rows, uint64_t n, double* out, int jobs) {
  const ArraySpec& a = in.metadata().matrix();
  std::vector<std::pair<uint64_t, uint64_t>> runs;  // (first index, count) per chunk
  for (uint64_t i = 0; i < n; ++i) {
    if (runs.empty() || rows[i] / a.block != rows[runs.back().first] / a.block) runs.push_back({i, 0});
    ++runs.back().second;
  }
  return ParallelFor(runs, jobs, Progress{}, "chunks", [&](const std::pair<uint64_t, uint64_t>& r) -> Status {
    return ReadRowList(in, rows + r.first, r.second, out + r.first * a.cols);
  });
}

// The dense rows (sparse_kind == kSparseKindDense) in row order, streamed from the side
// array a chunk at a time (its values were checked when the run started).
class DenseRows {
 public:
  DenseRows(const io::ContainerReader& in, int array) : in_(in), array_(static_cast<uint32_t>(array)) {}
  // The next (up to) max dense rows; fewer only at the end, none after it.
  Status Next(uint64_t max, std::vector<uint64_t>* rows) {
    rows->clear();
    const ArraySpec& spec = in_.metadata().arrays[array_];
    while (rows->size() < max) {
      if (pos_ == kinds_.size()) {
        if (next_chunk_ == spec.ChunkCount()) break;
        LTB_ASSIGN_OR_RETURN(io::Chunk chunk, in_.ReadChunk(array_, next_chunk_++));
        auto v = chunk.as<uint8_t>();
        kinds_.assign(v.begin(), v.end());
        row0_ = chunk.extent().row0;
        pos_ = 0;
        continue;
      }
      if (kinds_[pos_] == kSparseKindDense) rows->push_back(row0_ + pos_);
      ++pos_;
    }
    return Status::Ok();
  }

 private:
  const io::ContainerReader& in_;
  uint32_t array_;
  uint64_t next_chunk_ = 0, row0_ = 0, pos_ = 0;
  std::vector<uint8_t> kinds_;
};

// Per-cluster sums of one pass, about the pass's starting mean.
struct Accum {
  uint64_t count = 0;
  Eigen::VectorXd sum;  // Σ (x − mean)
  Mat y;                // Σ (x − mean)(x − mean)ᵀ Q   (D × p)
};

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

Status WriteCheckpoint(const std::string& path, const nlohmann::json& identity, const std::string& phase,
                       uint64_t level, uint64_t level_passes, uint64_t passes, uint64_t final_passes, double last_error,
                       const Model& m, const nlohmann::json& extra = nullptr,
                       const std::vector<double>& extra_values = {}) {
  CpcaCheckpoint cp;
  cp.header = {{"identity", identity}, {"phase", phase},
               {"level", level},       {"level_passes", level_passes},
               {"passes", passes},     {"final_passes", final_passes},
               {"extra", extra}};
  cp.values = ModelValues(m);
  cp.values.push_back(last_error);
  cp.values.insert(cp.values.end(), extra_values.begin(), extra_values.end());
  return WriteCpcaCheckpoint(path, cp);
}

}  // namespace

// The fit's position, as the checkpoint records it. Phases: "iterate" (the growth levels;
// on the dense rows in dense-first mode), "final" (dense-first: passes on all rows at
// dimension S), "evaluate", "encode".
struct CpcaFitter::FitState {
  std::string phase = "iterate";
  uint64_t level = 0, level_passes = 0, passes = 0;
  uint64_t final_passes = 0;  // of `passes`, those made in phase "final"
  double last_error = -1;
  double final_err = 0, final_norm = 0;  // phase "encode": the final assignment's totals
  std::vector<uint64_t> sizes;
};

Result<std::vector<uint64_t>> CpcaFitter::SampleRows() const {
  const uint64_t n = pr_.n_rows;
  // The sample: all (dense) rows, or the sample_rows (dense) rows of smallest hash(seed, row).
  std::vector<uint64_t> rows;
  if (!pr_.dense_first && pr_.sample_rows >= n) {
    rows.resize(n);
    std::iota(rows.begin(), rows.end(), 0);
    return rows;
  }
  std::priority_queue<std::pair<uint64_t, uint64_t>> heap;  // (hash, row), largest on top
  auto offer = [&](uint64_t r) {
    uint64_t h = SplitMix64(o_.seed ^ SplitMix64(r));
    if (heap.size() < pr_.sample_rows) {
      heap.push({h, r});
    } else if (std::make_pair(h, r) < heap.top()) {
      heap.pop();
      heap.push({h, r});
    }
  };
  if (cache_.filled) {
    for (uint64_t r : cache_.rows) offer(r);
  } else if (pr_.dense_first) {
    DenseRows dense(in_, pr_.kind_array);
    std::vector<uint64_t> batch;
    do {
      LTB_RETURN_IF_ERROR(dense.Next(1 << 16, &batch));
      for (uint64_t r : batch) offer(r);
    } while (!batch.empty());
  } else {
    for (uint64_t r = 0; r < n; ++r) offer(r);
  }
  while (!heap.empty()) {
    rows.push_back(heap.top().second);
    heap.pop();
  }
  std::sort(rows.begin(), rows.end());
  return rows;
}

// Greedy k-means++ (Arthur & Vassilvitskii 2007; 2 + ln K trials per centre, as
// scikit-learn does), from a seeded generator: the sample rows chosen as the K centres.
std::vector<uint64_t> CpcaFitter::SeedCentres(const RowMat& x) const {
  const uint64_t ns = static_cast<uint64_t>(x.rows()), d = pr_.d, k = pr_.k;
  Eigen::VectorXd xx = x.rowwise().squaredNorm();
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
  return centres;
}

// Lloyd iterations on the sample (in memory): m's means move, id holds each sample row's
// cluster.
Status CpcaFitter::Lloyd(const RowMat& x, Model* m, std::vector<uint32_t>* id) const {
  const uint64_t ns = static_cast<uint64_t>(x.rows()), d = pr_.d, k = pr_.k;
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
      changed = changed || arg != (*id)[i];
      (*id)[i] = arg;
    }
    if (!changed) break;
    RowMat sum = RowMat::Zero(k, d);
    std::vector<uint64_t> cnt(k, 0);
    for (uint64_t i = 0; i < ns; ++i) {
      sum.row((*id)[i]) += x.row(i);
      cnt[(*id)[i]]++;
    }
    for (uint64_t c = 0; c < k; ++c)
      if (cnt[c]) m->mean.row(c) = sum.row(c) / static_cast<double>(cnt[c]);
  }
  return Status::Ok();
}

// Directions: seeded random start, then subspace iterations on each cluster's sample rows.
Status CpcaFitter::InitialDirections(const RowMat& x, const std::vector<uint32_t>& id, Model* m) const {
  const uint64_t ns = static_cast<uint64_t>(x.rows()), d = pr_.d, k = pr_.k, p = pr_.p;
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

Status CpcaFitter::GatherDense() {
  if (cache_.filled) return Status::Ok();
  const uint64_t d = pr_.d;
  const ArraySpec& a = in_.metadata().matrix();
  DenseCache cache;
  cache.rows.reserve(pr_.n_dense);
  DenseRows dense(in_, pr_.kind_array);
  LTB_RETURN_IF_ERROR(dense.Next(pr_.n_dense + 1, &cache.rows));
  if (cache.rows.size() != pr_.n_dense) {
    return DataLoss(in_.path() + ": \"" + kSparseKindArray + "\" now marks " + std::to_string(cache.rows.size()) +
                    " rows dense, " + std::to_string(pr_.n_dense) + " when the run started; was the file replaced?");
  }
  cache.values.resize(pr_.n_dense * d);
  // The input chunks holding dense rows, each read once; a chunk's dense rows are a
  // contiguous range of the cache.
  std::vector<uint64_t> chunks;
  for (uint64_t r : cache.rows)
    if (chunks.empty() || chunks.back() != r / a.block) chunks.push_back(r / a.block);
  LTB_RETURN_IF_ERROR(ParallelFor(chunks, o_.jobs, Progress{}, "chunks", [&](uint64_t c) -> Status {
    if (progress_.Cancelled()) return Cancelled("interrupted while reading the dense rows; rerun the same command");
    LTB_ASSIGN_OR_RETURN(io::Chunk chunk, in_.ReadChunk(0, c));
    auto it = std::lower_bound(cache.rows.begin(), cache.rows.end(), c * a.block);
    for (; it != cache.rows.end() && *it / a.block == c; ++it) {
      const uint64_t i = static_cast<uint64_t>(it - cache.rows.begin());
      LTB_RETURN_IF_ERROR(CopyRow(in_, chunk, *it, cache.values.data() + i * d));
    }
    return Status::Ok();
  }));
  cache.filled = true;
  cache_ = std::move(cache);
  return Status::Ok();
}

void CpcaFitter::CachedRows(uint64_t i, uint64_t n, double* out) const {
  const float* src = cache_.values.data() + i * pr_.d;
  std::copy(src, src + n * pr_.d, out);
}

Status CpcaFitter::Initialise(Model* m) {
  const uint64_t d = pr_.d, k = pr_.k, p = pr_.p;
  if (pr_.sample_from_cache) LTB_RETURN_IF_ERROR(GatherDense());
  LTB_ASSIGN_OR_RETURN(const std::vector<uint64_t> rows, SampleRows());
  const uint64_t ns = rows.size();
  RowMat x(ns, d);
  if (cache_.filled) {
    // The sample's rows are dense rows; both lists ascend.
    uint64_t j = 0;
    for (uint64_t i = 0; i < ns; ++i) {
      while (cache_.rows[j] != rows[i]) ++j;
      CachedRows(j, 1, x.data() + i * d);
    }
  } else {
    LTB_RETURN_IF_ERROR(ReadRowListParallel(in_, rows.data(), ns, x.data(), o_.jobs));
  }
  const std::vector<uint64_t> centres = SeedCentres(x);
  m->k = k;
  m->d = d;
  m->p = p;
  m->mean.resize(k, d);
  for (uint64_t c = 0; c < k; ++c) m->mean.row(c) = x.row(centres[c]);
  std::vector<uint32_t> id(ns, UINT32_MAX);
  LTB_RETURN_IF_ERROR(Lloyd(x, m, &id));
  return InitialDirections(x, id, m);
}

// Over 120 lines: one streaming pass over the rows (assign, accumulate, keep the worst rows)
// whose lambdas share the per-cluster accumulators.
Result<double> CpcaFitter::Pass(Model* m, uint64_t n, uint64_t pass_index, bool dense_only) {
  const uint64_t d = pr_.d, k = pr_.k, p = pr_.p;
  const uint64_t block = PassBlockRows(d), group = std::max<uint64_t>(1, pr_.group_blocks);
  if (dense_only && pr_.dense_cache) LTB_RETURN_IF_ERROR(GatherDense());
  const bool cached = dense_only && cache_.filled;
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

  // Pass blocks: `block` consecutive rows from row 0, or (dense_only) the next `block` dense
  // rows — from the cache, or streamed with the side array; either way fixed by the data
  // alone, as are their kSubRows sub-blocks. `group` blocks at a time are read and assigned
  // in parallel, then accumulated block after block in row order (the arithmetic of one
  // block at a time).
  std::optional<DenseRows> dense;  // dense_only and not cached: the side array, streamed
  if (dense_only && !cached) dense.emplace(in_, pr_.kind_array);
  struct Block {
    uint64_t first = 0, rows = 0;  // first: its first row, or (dense_only) dense row index
    std::vector<uint64_t> list;    // streamed dense_only: its rows
  };
  std::vector<Block> blocks(group);
  auto row_of = [&](const Block& b, uint64_t r) {
    return dense ? b.list[r] : cached ? cache_.rows[b.first + r] : b.first + r;
  };
  const uint64_t end = dense_only ? pr_.n_dense : pr_.n_rows;
  std::vector<double> x(group * block * d), err(group * block);
  std::vector<uint32_t> ids(group * block);
  double total = 0;
  for (uint64_t next = 0;;) {
    if (progress_.Cancelled()) {
      return Cancelled("interrupted in pass " + std::to_string(pass_index + 1) +
                       "; passes before it are checkpointed, rerun the same command to resume");
    }
    uint64_t nb = 0;  // blocks in this group
    for (; nb < group; ++nb) {
      Block& b = blocks[nb];
      b.first = next;
      if (dense) {
        LTB_RETURN_IF_ERROR(dense->Next(block, &b.list));
        b.rows = b.list.size();
      } else {
        b.rows = std::min(block, end - next);
      }
      if (b.rows == 0) break;
      next += b.rows;
    }
    if (nb == 0) break;
    std::vector<std::pair<uint64_t, uint64_t>> subs;  // (block, its first row of the sub-block)
    for (uint64_t bi = 0; bi < nb; ++bi)
      for (uint64_t s = 0; s < blocks[bi].rows; s += kSubRows) subs.push_back({bi, s});
    LTB_RETURN_IF_ERROR(ParallelFor(subs, o_.jobs, Progress{}, "rows", [&](const auto& sub) -> Status {
      const Block& b = blocks[sub.first];
      const uint64_t s = sub.second, at = sub.first * block + s;
      const uint64_t m_rows = std::min(kSubRows, b.rows - s);
      double* xs = x.data() + at * d;
      if (cached) {
        CachedRows(b.first + s, m_rows, xs);
      } else {
        LTB_RETURN_IF_ERROR(dense ? ReadRowList(in_, b.list.data() + s, m_rows, xs)
                                  : ReadRows(in_, b.first + s, m_rows, xs));
      }
      assigner.Assign(xs, m_rows, d, ids.data() + at, err.data() + at, nullptr);
      return Status::Ok();
    }));
    // members[bi][c]: the rows (offsets in x) of block bi assigned to cluster c.
    std::vector<std::vector<std::vector<uint32_t>>> members(nb, std::vector<std::vector<uint32_t>>(k));
    std::vector<bool> busy_mask(k, false);
    for (uint64_t bi = 0; bi < nb; ++bi) {
      for (uint64_t r = 0; r < blocks[bi].rows; ++r) {
        const uint64_t at = bi * block + r;
        members[bi][ids[at]].push_back(static_cast<uint32_t>(at));
        busy_mask[ids[at]] = true;
        total += err[at];
        std::pair<double, uint64_t> e{err[at], row_of(blocks[bi], r)};
        if (worst.size() < keep || better(e, worst.back())) {
          auto pos = std::lower_bound(worst.begin(), worst.end(), e, better);
          size_t w_at = pos - worst.begin();
          worst.insert(pos, e);
          worst_rows.insert(worst_rows.begin() + w_at, std::vector<double>(x.data() + at * d, x.data() + (at + 1) * d));
          if (worst.size() > keep) {
            worst.pop_back();
            worst_rows.pop_back();
          }
        }
      }
    }
    std::vector<uint64_t> busy;
    for (uint64_t c = 0; c < k; ++c)
      if (busy_mask[c]) busy.push_back(c);
    LTB_RETURN_IF_ERROR(ParallelFor(busy, o_.jobs, Progress{}, "clusters", [&](uint64_t c) -> Status {
      for (uint64_t bi = 0; bi < nb; ++bi) {  // block after block, as if one at a time
        const auto& mem = members[bi][c];
        if (mem.empty()) continue;
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
      }
      return Status::Ok();
    }));
    for (uint64_t bi = 0; bi < nb; ++bi) {
      rows_done_ += blocks[bi].rows;
      ReportRows(rows_done_);
    }
    if (nb < group) break;
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

Status CpcaFitter::Encode(const Assigner& a, const Model& rounded, uint64_t row0, uint64_t n, std::vector<double>* x,
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

Status CpcaFitter::Evaluate(const Model& rounded, double* err, double* norm, std::vector<uint64_t>* sizes) {
  const uint64_t nr = pr_.n_rows, d = pr_.d;
  // `group` pass blocks at a time (their sub-blocks in parallel); per-row results are
  // summed in row order, so the totals do not depend on the grouping.
  const uint64_t block = PassBlockRows(d), group = std::max<uint64_t>(1, pr_.group_blocks);
  const uint64_t span = group * block;
  Assigner a(rounded, pr_.s);
  std::vector<uint32_t> ids(span);
  std::vector<float> w(span * pr_.s);
  std::vector<double> e(span), xx(span);
  sizes->assign(pr_.k, 0);
  *err = 0;
  *norm = 0;
  for (uint64_t row0 = 0; row0 < nr; row0 += span) {
    if (progress_.Cancelled()) return Cancelled("interrupted in the final pass; rerun the same command to resume");
    const uint64_t rows = std::min(span, nr - row0);
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
    for (uint64_t b0 = 0; b0 < rows; b0 += block) {  // one report per pass block
      rows_done_ += std::min(block, rows - b0);
      ReportRows(rows_done_);
    }
  }
  return Status::Ok();
}

Result<bool> CpcaFitter::Resume(const std::string& cp_path, const nlohmann::json& identity, Model* m,
                                FitState* st) const {
  const uint64_t k = pr_.k, d = pr_.d, p = pr_.p;
  auto cp = ReadCpcaCheckpoint(cp_path, k * d * (p + 1) + 16);
  if (!cp.ok()) return cp.status();
  bool loaded = false;
  if (cp->has_value() && (**cp).header.value("identity", nlohmann::json()) == identity) {
    const CpcaCheckpoint& c = **cp;
    const uint64_t base = k * d * (p + 1);
    if (LoadModel(c.values, k, d, p, m) && c.values.size() >= base + 1) {
      st->level = c.header.value("level", uint64_t{0});
      st->level_passes = c.header.value("level_passes", uint64_t{0});
      st->passes = c.header.value("passes", uint64_t{0});
      st->final_passes = c.header.value("final_passes", uint64_t{0});
      st->phase = c.header.value("phase", std::string("iterate"));
      st->last_error = c.values[base];
      loaded = st->level < pr_.levels.size() && st->final_passes <= st->passes &&
               (pr_.dense_first || (st->phase != "final" && st->final_passes == 0));
      if (st->phase == "encode") {
        const auto& extra = c.header["extra"];
        loaded = loaded && c.values.size() == base + 3 && extra.is_object() && extra.contains("sizes") &&
                 extra["sizes"].is_array() && extra["sizes"].size() == k;
        if (loaded) {
          st->final_err = c.values[base + 1];
          st->final_norm = c.values[base + 2];
          st->sizes = extra["sizes"].get<std::vector<uint64_t>>();
        }
      }
    }
  }
  return loaded;
}

// Alternate assignment and refit, growing the basis dimension level by level (dense-first:
// on the dense rows).
Status CpcaFitter::Iterate(const std::string& cp_path, const nlohmann::json& identity, Model* m, FitState* st) {
  while (st->phase == "iterate") {
    const uint64_t dim = pr_.levels[st->level];
    const bool last_level = st->level + 1 == pr_.levels.size();
    LTB_ASSIGN_OR_RETURN(double e, Pass(m, dim, st->passes, pr_.dense_first));
    ++st->passes;
    ++st->level_passes;
    const bool converged = st->last_error >= 0 && st->last_error - e <= o_.tolerance * st->last_error;
    st->last_error = e;
    if (st->passes >= o_.max_iterations || (last_level && converged)) {
      if (pr_.dense_first && pr_.final_iterations > 0) {
        st->phase = "final";
        st->last_error = -1;  // the dense rows' error: not comparable with all rows'
      } else {
        st->phase = "evaluate";
      }
    } else if (!last_level && (converged || st->level_passes >= o_.level_iterations)) {
      ++st->level;
      st->level_passes = 0;
      st->last_error = -1;
    }
    LTB_RETURN_IF_ERROR(WriteCheckpoint(cp_path, identity, st->phase, st->level, st->level_passes, st->passes,
                                        st->final_passes, st->last_error, *m));
  }
  cache_ = DenseCache();  // the passes that follow read all rows from the input
  return Status::Ok();
}

// Dense-first: LBG passes over all rows at the full dimension (the first assigns the
// sparse rows to their nearest clusters), until final_iterations or the error improves by
// less than the tolerance (relative), as the last growth level stops.
Status CpcaFitter::FinalPasses(const std::string& cp_path, const nlohmann::json& identity, Model* m, FitState* st) {
  while (st->phase == "final") {
    LTB_ASSIGN_OR_RETURN(double e, Pass(m, pr_.s, st->passes, /*dense_only=*/false));
    ++st->passes;
    ++st->final_passes;
    const bool converged = st->last_error >= 0 && st->last_error - e <= o_.tolerance * st->last_error;
    st->last_error = e;
    if (st->final_passes >= pr_.final_iterations || converged) st->phase = "evaluate";
    LTB_RETURN_IF_ERROR(WriteCheckpoint(cp_path, identity, st->phase, st->level, st->level_passes, st->passes,
                                        st->final_passes, st->last_error, *m));
  }
  return Status::Ok();
}

uint64_t CpcaFitter::RowsStreamed(const FitState& st) const {
  const uint64_t growth = st.passes - st.final_passes;
  const uint64_t done = (st.phase == "encode") ? pr_.n_rows : 0;  // the evaluation pass
  return growth * (pr_.dense_first ? pr_.n_dense : pr_.n_rows) + st.final_passes * pr_.n_rows + done;
}

uint64_t CpcaFitter::rows_total() const {
  if (!pr_.dense_first) return (o_.max_iterations + 2) * pr_.n_rows;
  return o_.max_iterations * pr_.n_dense + (pr_.final_iterations + 2) * pr_.n_rows;
}

Result<FitOutcome> CpcaFitter::Fit(const std::string& cp_path, const nlohmann::json& identity) {
  const auto t0 = std::chrono::steady_clock::now();
  Model m;
  FitState st;
  FitOutcome out;
  LTB_ASSIGN_OR_RETURN(out.resumed, Resume(cp_path, identity, &m, &st));
  if (!out.resumed) {
    st = FitState();
    LTB_RETURN_IF_ERROR(Initialise(&m));
    LTB_RETURN_IF_ERROR(WriteCheckpoint(cp_path, identity, st.phase, st.level, st.level_passes, st.passes,
                                        st.final_passes, st.last_error, m));
  }
  rows_done_ = RowsStreamed(st);
  LTB_RETURN_IF_ERROR(Iterate(cp_path, identity, &m, &st));
  out.seconds_dense = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  LTB_RETURN_IF_ERROR(FinalPasses(cp_path, identity, &m, &st));
  out.rounded = Rounded(m);
  if (st.phase != "encode") {
    LTB_RETURN_IF_ERROR(Evaluate(out.rounded, &st.final_err, &st.final_norm, &st.sizes));
    st.phase = "encode";
    LTB_RETURN_IF_ERROR(WriteCheckpoint(cp_path, identity, st.phase, st.level, st.level_passes, st.passes,
                                        st.final_passes, st.last_error, m, {{"sizes", st.sizes}},
                                        {st.final_err, st.final_norm}));
  }
  out.passes = st.passes;
  out.final_passes = st.final_passes;
  out.squared_error = st.final_err;
  out.squared_norm = st.final_norm;
  out.sizes = std::move(st.sizes);
  return out;
}

}  // namespace ltb::stages::cpca_internal
