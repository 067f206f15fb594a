// Over 700 lines: the two phases share the checkpoint and the row bookkeeping; the ray-free
// parts are in sparse_rows.cpp and the lasso in l1_solver.cpp.
// `ltbake sample --sparse` (docs/SPARSE.md; Huang & Ramamoorthi 2010, §4–§5).
//
// Phase 1 places dense rows in rounds — a uniformly random first round, then rounds drawn
// with probability proportional to the local rank of the dense rows near each candidate —
// and traces each on a quarter of its texels plus the texels whose 7×7 window disagrees.
// The dense rows are committed to a checkpoint beside the output (row, direct term,
// indirect term, feature flags), chunk by chunk, so an interrupted phase 1 resumes. Phase 2
// writes the output block by block: dense rows from the checkpoint, every other row traced
// on its feature texels and reconstructed from its dense neighbours.
//
// Deterministic: every random choice comes from a counter-based hash of (seed, round, row);
// the rounds are a fixed number of fixed-size chunks of dense rows; and a row's arithmetic
// never depends on --jobs, --chunk-rows or where a run was interrupted.
#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <memory>
#include <unordered_map>
#include <vector>

#include "format/io/container_reader.h"
#include "format/io/container_writer.h"
#include "format/io/file.h"
#include "stages/common/basis.h"
#include "stages/common/parallel_for.h"
#include "stages/inspect/inspect.h"
#include "stages/row_transform/row_transform.h"
#include "stages/sample/l1_solver.h"
#include "stages/sample/sample_internal.h"
#include "stages/sample/sampler.h"
#include "stages/sample/sparse_internal.h"
#include "stages/sample/sparse_rows.h"

namespace ltb::stages {

using namespace ltb::format;

std::string SparseCheckpointPath(const std::string& output) { return output + ".dense.ltm"; }

namespace sample_internal {
namespace sparse_bake {

Result<RowPoints> PrimaryPoints(const Sampler& sampler, const Prepared& p, int jobs, const Progress& progress) {
  RowPoints rp;
  rp.pt.resize(p.rows);
  std::vector<uint64_t> blocks;
  for (uint64_t r0 = 0; r0 < p.rows; r0 += 4096) blocks.push_back(r0);
  LTB_RETURN_IF_ERROR(ParallelFor(blocks, jobs, Progress{.update = nullptr, .cancelled = progress.cancelled}, "rows",
                                  [&](uint64_t r0) -> Status {
                                    for (uint64_t r = r0; r < std::min(p.rows, r0 + 4096); ++r)
                                      rp.pt[r] = sampler.Primary(r);
                                    return Status::Ok();
                                  }));
  for (uint64_t r = 0; r < p.rows; ++r)
    if (rp.pt[r].valid) rp.valid.push_back(r);
  return rp;
}

Params Resolve(const SampleOptions& o, const Prepared& p, const RowPoints& rows) {
  Params pr;
  const SparseOptions& so = o.sparse;
  pr.cols = 6ull * p.r * p.r;
  const uint64_t v = rows.valid.size();
  pr.dense = v == 0 ? 0 : std::clamp<uint64_t>(static_cast<uint64_t>(std::llround(so.dense_fraction * v)), 1, v);
  // At most 64 dense rows a chunk, and never more than there are (a 16x16 image has ~25).
  pr.dense_block = std::clamp<uint64_t>((2u << 20) / (pr.cols * 4), 1, std::clamp<uint64_t>(pr.dense, 1, 64));
  uint64_t first = std::max<uint64_t>(1, static_cast<uint64_t>(std::llround(so.initial_fraction * v)));
  first = std::min(pr.dense, (first + pr.dense_block - 1) / pr.dense_block * pr.dense_block);
  for (uint64_t done = 0; done < pr.dense;) {
    const uint64_t n = std::min(first, pr.dense - done);
    pr.rounds.push_back(n);
    done += n;
  }
  if (so.radius) {
    pr.radius = *so.radius;
  } else {
    glm::dvec3 lo(INFINITY), hi(-INFINITY);
    for (uint64_t r : rows.valid) {
      lo = glm::min(lo, rows.pt[r].p);
      hi = glm::max(hi, rows.pt[r].p);
    }
    const double diag = v ? glm::length(hi - lo) : 0.0;
    pr.radius = diag > 0 ? kRadiusFactor * diag : 1.0;
  }
  // The paper's 350 features at R = 32, scaled with 6R², but at least 4 per neighbour: fewer
  // constraints than that let the fit match them with weights that are wrong elsewhere.
  const auto scaled = static_cast<uint64_t>(std::llround(350.0 * static_cast<double>(pr.cols) / 6144.0));
  pr.features = static_cast<uint32_t>(
      so.features.value_or(std::min<uint64_t>(pr.cols, std::max<uint64_t>(scaled, 4ull * so.neighbours))));
  pr.neighbours = so.neighbours;
  pr.l1.lambda_rel = so.lambda;
  pr.l1.tolerance = kL1Tolerance;
  pr.l1.max_sweeps = kL1MaxSweeps;
  pr.l1.nonnegative = true;
  return pr;
}

DenseRowResult TraceDenseRow(const Sampler& s, uint64_t row, const RowPoint& rp, uint64_t cols, DenseScratch& ds,
                             float* direct, float* indirect, uint8_t* features) {
  DenseRowResult out;
  ds.unoccluded.resize(cols);
  ds.value.assign(cols, 0.0);
  s.Unoccluded(row, rp, ds.unoccluded.data(), ds.sc);
  sp::GridSelection(s.cube_res(), ds.unoccluded.data(), &ds.grid);
  out.rays += s.DirectSelected(row, rp, ds.grid.data(), ds.value.data(), ds.sc);
  const uint64_t second = sp::SecondPass(*ds.windows, ds.unoccluded.data(), ds.grid, ds.value.data(), &ds.second);
  if (second > 0) out.rays += s.DirectSelected(row, rp, ds.second.data(), ds.value.data(), ds.sc);
  out.traced = second + static_cast<uint64_t>(std::count(ds.grid.begin(), ds.grid.end(), uint8_t{1}));
  for (uint64_t c = 0; c < cols; ++c) direct[c] = static_cast<float>(ds.value[c]);
  if (indirect != nullptr) {
    ds.indirect.assign(cols, 0.0);
    out.rays += s.IndirectTerm(row, rp, std::max<uint64_t>(1, s.DefaultPaths() / 4), ds.indirect.data());
    for (uint64_t c = 0; c < cols; ++c) indirect[c] = static_cast<float>(ds.indirect[c]);
  }
  if (features != nullptr) std::copy(ds.second.begin(), ds.second.end(), features);
  return out;
}

void DenseNeighbours(const Context& c, const sp::PointGrid& grid, const RowPoint& rp, std::vector<uint32_t>* nb) {
  double radius = c.pr.radius;
  for (int widen = 0; widen < 3; ++widen, radius *= 2) {
    grid.Query(rp.p, rp.n, radius, c.pr.neighbours, kNormalCos, -1, nb);
    if (nb->size() >= 2) break;
  }
}

SparseRowOutcome ReconstructRow(const Context& c, const sp::PointGrid& grid, std::span<const sp::DenseView> views,
                                uint64_t row, const RowPoint& rp, float* out) {
  thread_local DenseScratch ds;
  ds.windows = &c.windows;
  thread_local sp::Scratch fs;
  thread_local std::vector<uint32_t> nb_idx, texels;
  thread_local std::vector<sp::DenseView> nb;
  thread_local std::vector<uint8_t> relevant, select;
  thread_local std::vector<double> b;
  thread_local std::vector<float> ind_scratch;
  const uint64_t cols = c.pr.cols;
  DenseNeighbours(c, grid, rp, &nb_idx);
  // Traced like a dense row instead: no dense row anywhere near, or a fit that does not
  // match its own traced texels.
  auto fallback = [&](double why, uint64_t traced_before, uint64_t rays_before) {
    // The direct term traced like a dense row's; the indirect, smooth across the surface, the
    // mean of the dense neighbours' (traced when there are none).
    const bool traced_indirect = c.p.bounces > 0 && nb.empty();
    ind_scratch.assign(c.p.bounces > 0 ? cols : 0, 0.0f);
    DenseRowResult d =
        TraceDenseRow(c.s, row, rp, cols, ds, out, traced_indirect ? ind_scratch.data() : nullptr, nullptr);
    if (c.p.bounces > 0 && !nb.empty()) {
      float used = 0;
      for (const sp::DenseView& v : nb) {
        if (v.indirect == nullptr) continue;
        for (uint64_t k = 0; k < cols; ++k) ind_scratch[k] += v.indirect[k];
        used += 1;
      }
      for (uint64_t k = 0; used > 0 && k < cols; ++k) ind_scratch[k] /= used;
    }
    for (uint64_t k = 0; k < ind_scratch.size(); ++k)
      out[k] = static_cast<float>(double{out[k]} + double{ind_scratch[k]});
    return SparseRowOutcome{kDense, static_cast<float>(why), static_cast<uint32_t>(traced_before + d.traced),
                            rays_before + d.rays};
  };
  nb.clear();
  if (nb_idx.empty()) return fallback(1.0, 0, 0);
  for (uint32_t k : nb_idx) nb.push_back(views[k]);
  relevant.resize(cols);
  for (uint64_t k = 0; k < cols; ++k) relevant[k] = c.s.BelowHorizon(rp.n, k) ? 0 : 1;
  sp::ChooseFeatures(nb, cols, relevant.data(), c.pr.features, kMinFeatures, fs, &texels);
  select.assign(cols, 0);
  for (uint32_t k : texels) select[k] = 1;
  // The selected texels of a full-length row, with the variance of each estimate (spp ≥ 2).
  ds.value.assign(cols, 0.0);
  ds.indirect.assign(cols, 0.0);  // the variances
  uint64_t nr = 0;
  if (!texels.empty()) {
    nr = c.s.spp() >= 2 ? c.s.DirectWithVariance(row, rp, ds.value.data(), ds.indirect.data(), ds.sc, select.data())
                        : c.s.DirectSelected(row, rp, select.data(), ds.value.data(), ds.sc);
  }
  b.resize(texels.size());
  double b2 = 0, noise = 0;
  for (size_t j = 0; j < texels.size(); ++j) {
    b[j] = ds.value[texels[j]];
    b2 += b[j] * b[j];
    noise += ds.indirect[texels[j]];
  }
  sp::Fit fit = sp::Reconstruct(nb, cols, texels, b.data(), relevant.data(), c.pr.l1, fs, out);
  const bool dark = b2 == 0;
  // The fit is judged by what it misses beyond the traced values' own Monte Carlo noise: a
  // fit that matched the noise too would be worse, not better.
  const double excess = b2 > 0 ? std::sqrt(std::max(0.0, fit.residual * fit.residual - noise / b2)) : 0.0;
  if (excess > c.o.sparse.max_residual || (dark && !texels.empty())) {
    return fallback(dark ? 1.0 : excess, texels.size(), nr);
  }
  return SparseRowOutcome{kSparse, static_cast<float>(excess), static_cast<uint32_t>(texels.size()), nr};
}

}  // namespace sparse_bake

namespace {

using namespace sparse_bake;

// Array indices of the checkpoint.
enum CheckpointArray : uint32_t {
  kRow = 0,
  kDirect = 1,
  kFeatures = 2,
  kDenseRays = 3,
  kDenseSeconds = 4,
  kDenseTraced = 5,
  kIndirect = 6
};
// Extra arrays of the output, after matrix, mask, position, normal.
enum OutputArray : uint32_t { kKind = 4, kTraced = 5, kRays = 6, kResidual = 7, kSeconds = 8 };

// A uniform number in (0, 1] from (seed, round, row).
double Uniform(uint64_t seed, uint64_t round, uint64_t row) {
  const uint64_t z = sample::Mix64(seed ^ 0x5EED5EED5EED5EEDull ^ sample::Mix64(round * 0x9E3779B97F4A7C15ull + row));
  return (static_cast<double>(z >> 11) + 1.0) * 0x1.0p-53;
}

nlohmann::json ParamsJson(const SampleOptions& o, const Params& pr) {
  return {{"dense_fraction", o.sparse.dense_fraction},
          {"initial_fraction", o.sparse.initial_fraction},
          {"radius", pr.radius},
          {"features", pr.features},
          {"neighbours", pr.neighbours},
          {"l1_lambda", pr.l1.lambda_rel},
          {"l1_tolerance", pr.l1.tolerance},
          {"l1_nonnegative", pr.l1.nonnegative},
          {"window", 2 * sp::kWindowHalf + 1},
          {"normal_cos", kNormalCos},
          {"rank_res", kRankRes},
          {"rank_threshold", kRankThreshold},
          {"min_features", kMinFeatures},
          {"max_residual", o.sparse.max_residual}};
}

// ---- Phase 1 ----

struct Phase1 {
  std::vector<uint64_t> rows;  // dense index -> row
  std::vector<float> low;      // dense index -> the direct term box-filtered to 6·kRankRes²
  uint64_t rays = 0;           // traced by this run
  double seconds = 0;
};

class Phase1Runner {
 public:
  explicit Phase1Runner(const Context& c) : c_(c) {
    low_res_ = std::min(c.p.r, kRankRes);
    low_cols_ = 6ull * low_res_ * low_res_;
  }

  nlohmann::json Metadata() const {
    const uint64_t d = c_.pr.dense, b = c_.pr.dense_block;
    nlohmann::json arrays = {RowArray("row", DType::kU64, d, 1, b).ToJson(),
                             RowArray("direct", DType::kF32, d, c_.pr.cols, b).ToJson(),
                             RowArray("features", DType::kU8, d, c_.pr.cols, b).ToJson(),
                             RowArray("rays", DType::kU64, d, 1, b).ToJson(),
                             RowArray("seconds", DType::kF32, d, 1, b).ToJson(),
                             RowArray("traced", DType::kU32, d, 1, b).ToJson()};
    if (c_.p.bounces > 0) arrays.push_back(RowArray("indirect", DType::kF32, d, c_.pr.cols, b).ToJson());
    nlohmann::json params = {{"cube_res", c_.p.r},
                             {"spp", c_.p.spp},
                             {"bounces", c_.p.bounces},
                             {"seed", c_.p.seed},
                             {"scene_hash", c_.p.geo.scene_hash},
                             {"sparse", ParamsJson(c_.o, c_.pr)}};
    return {{"arrays", arrays}, {"provenance", Provenance("sample --sparse (phase 1 checkpoint)", params, {})}};
  }

  Status Run(Phase1* out) {
    const auto t0 = std::chrono::steady_clock::now();
    const std::string path = SparseCheckpointPath(c_.o.output);
    io::WriterOptions wo;
    wo.overwrite_mismatch = c_.o.overwrite;
    wo.direct_io = false;
    LTB_ASSIGN_OR_RETURN(io::ContainerWriter w, io::ContainerWriter::Open(path, Metadata(), wo));
    // Chunks an earlier run committed (read back through a reader of the same file).
    std::unique_ptr<io::ContainerReader> resumed;
    if (w.resume_info().committed_chunks > 0) {
      LTB_ASSIGN_OR_RETURN(io::ContainerReader r, io::ContainerReader::Open(path));
      resumed = std::make_unique<io::ContainerReader>(std::move(r));
    }
    const uint32_t narrays = c_.p.bounces > 0 ? 7 : 6;
    out->rows.clear();
    out->low.assign(c_.pr.dense * low_cols_, 0.0f);
    std::vector<uint8_t> is_dense(c_.p.rows, 0);
    uint64_t start = 0;
    for (size_t round = 0; round < c_.pr.rounds.size(); ++round) {
      std::vector<uint64_t> chosen = Choose(round, c_.pr.rounds[round], *out, is_dense);
      for (uint64_t r : chosen) is_dense[r] = 1;
      out->rows.insert(out->rows.end(), chosen.begin(), chosen.end());
      const uint64_t c0 = start / c_.pr.dense_block,
                     c1 = (start + chosen.size() + c_.pr.dense_block - 1) / c_.pr.dense_block;
      std::vector<uint64_t> todo;
      for (uint64_t c = c0; c < c1; ++c) {
        bool have = true;
        for (uint32_t a = 0; a < narrays; ++a) have = have && w.Has(a, c);
        if (have && resumed) {
          LTB_RETURN_IF_ERROR(LoadChunk(*resumed, c, *out));
        } else {
          todo.push_back(c);
        }
      }
      std::atomic<uint64_t> rays{0};
      LTB_RETURN_IF_ERROR(ParallelFor(todo, c_.o.jobs, Progress{.update = nullptr, .cancelled = c_.progress.cancelled},
                                      "chunks", [&](uint64_t c) -> Status { return TraceChunk(w, c, *out, &rays); }));
      out->rays += rays;
      start += chosen.size();
    }
    LTB_RETURN_IF_ERROR(w.Finish());
    out->seconds = Seconds(t0);
    return Status::Ok();
  }

 private:
  // Dense rows of one round: a weighted draw without replacement among the rows that see
  // geometry and are not dense yet (Efraimidis–Spirakis keys u^(1/w), the largest win).
  std::vector<uint64_t> Choose(size_t round, uint64_t count, const Phase1& st, const std::vector<uint8_t>& is_dense) {
    std::vector<double> weight;
    if (round > 0) weight = CandidateWeights(st, is_dense);
    std::vector<std::pair<double, uint64_t>> keys;
    keys.reserve(c_.pts.valid.size());
    for (size_t i = 0; i < c_.pts.valid.size(); ++i) {
      const uint64_t r = c_.pts.valid[i];
      if (is_dense[r]) continue;
      const double w = round == 0 ? 1.0 : weight[i];
      keys.emplace_back(std::log(Uniform(c_.p.seed, round, r)) / w, r);
    }
    count = std::min<uint64_t>(count, keys.size());
    std::partial_sort(
        keys.begin(), keys.begin() + static_cast<std::ptrdiff_t>(count), keys.end(),
        [](const auto& a, const auto& b) { return a.first != b.first ? a.first > b.first : a.second < b.second; });
    std::vector<uint64_t> rows;
    for (uint64_t i = 0; i < count; ++i) rows.push_back(keys[i].second);
    std::sort(rows.begin(), rows.end());
    return rows;
  }

  // Per valid row: the local rank at its nearest dense row (within the radius, normals
  // alike), or the neighbour cap when none is near (unexplored).
  std::vector<double> CandidateWeights(const Phase1& st, const std::vector<uint8_t>& is_dense) {
    const size_t d = st.rows.size();
    std::vector<glm::dvec3> pos(d), nor(d);
    for (size_t i = 0; i < d; ++i) {
      pos[i] = c_.pts.pt[st.rows[i]].p;
      nor[i] = c_.pts.pt[st.rows[i]].n;
    }
    sp::PointGrid grid(c_.pr.radius / 4, pos, nor);
    std::vector<int> rank(d, 0);
    std::vector<uint64_t> items;
    for (uint64_t i = 0; i < d; i += 256) items.push_back(i);
    (void)ParallelFor(items, c_.o.jobs, Progress{}, "rows", [&](uint64_t i0) -> Status {
      std::vector<uint32_t> nb;
      std::vector<const float*> rows;
      for (uint64_t i = i0; i < std::min<uint64_t>(d, i0 + 256); ++i) {
        grid.Query(pos[i], nor[i], c_.pr.radius, c_.pr.neighbours, kNormalCos, -1, &nb);
        rows.clear();
        for (uint32_t k : nb) rows.push_back(st.low.data() + k * low_cols_);
        rank[i] = sp::NumericalRank(rows, low_cols_, kRankThreshold);
      }
      return Status::Ok();
    });
    std::vector<double> weight(c_.pts.valid.size(), 0.0);
    std::vector<uint64_t> vitems;
    for (uint64_t i = 0; i < c_.pts.valid.size(); i += 1024) vitems.push_back(i);
    (void)ParallelFor(vitems, c_.o.jobs, Progress{}, "rows", [&](uint64_t i0) -> Status {
      std::vector<uint32_t> nb;
      for (uint64_t i = i0; i < std::min<uint64_t>(c_.pts.valid.size(), i0 + 1024); ++i) {
        const RowPoint& q = c_.pts.pt[c_.pts.valid[i]];
        if (is_dense[c_.pts.valid[i]]) continue;
        grid.Query(q.p, q.n, c_.pr.radius, 1, kNormalCos, -1, &nb);
        weight[i] = nb.empty() ? static_cast<double>(c_.pr.neighbours) : std::max(kMinWeight, double(rank[nb[0]]));
      }
      return Status::Ok();
    });
    return weight;
  }

  void StoreLow(const float* direct, uint64_t index, Phase1& st) const {
    sp::Downsample(direct, c_.p.r, low_res_, st.low.data() + index * low_cols_);
  }

  Status LoadChunk(const io::ContainerReader& r, uint64_t c, Phase1& st) const {
    LTB_ASSIGN_OR_RETURN(io::Chunk rows, r.ReadChunk(kRow, c));
    LTB_ASSIGN_OR_RETURN(io::Chunk direct, r.ReadChunk(kDirect, c));
    auto ids = rows.as<uint64_t>();
    auto values = direct.as<float>();
    const uint64_t i0 = c * c_.pr.dense_block;
    for (uint64_t i = 0; i < ids.size(); ++i) {
      if (i0 + i >= st.rows.size() || ids[i] != st.rows[i0 + i]) {
        return DataLoss(r.path() + ": dense row " + std::to_string(i0 + i) + " is row " + std::to_string(ids[i]) +
                        ", but this run places row " + std::to_string(i0 + i < st.rows.size() ? st.rows[i0 + i] : 0) +
                        " there; remove the checkpoint to start phase 1 over");
      }
      StoreLow(values.data() + i * c_.pr.cols, i0 + i, st);
    }
    return Status::Ok();
  }

  Status TraceChunk(io::ContainerWriter& w, uint64_t c, Phase1& st, std::atomic<uint64_t>* rays) {
    thread_local DenseScratch ds;
    ds.windows = &c_.windows;
    const uint64_t i0 = c * c_.pr.dense_block, n = std::min(c_.pr.dense_block, c_.pr.dense - i0);
    const uint64_t cols = c_.pr.cols, fb = cols;
    std::vector<float> direct(n * cols), indirect(c_.p.bounces > 0 ? n * cols : 0), secs(n);
    std::vector<uint8_t> feat(n * fb);
    std::vector<uint64_t> ids(n), nrays(n);
    std::vector<uint32_t> ntraced(n);
    for (uint64_t i = 0; i < n; ++i) {
      if (c_.progress.Cancelled()) return Cancelled("interrupted; committed chunks are kept, rerun to resume");
      const auto t0 = std::chrono::steady_clock::now();
      ids[i] = st.rows[i0 + i];
      DenseRowResult d = TraceDenseRow(c_.s, ids[i], c_.pts.pt[ids[i]], cols, ds, direct.data() + i * cols,
                                       c_.p.bounces > 0 ? indirect.data() + i * cols : nullptr, feat.data() + i * fb);
      StoreLow(direct.data() + i * cols, i0 + i, st);
      *rays += d.rays;
      nrays[i] = d.rays;
      ntraced[i] = static_cast<uint32_t>(d.traced);
      secs[i] = static_cast<float>(Seconds(t0));
      c_.progress.Report(done_.fetch_add(1) + 1, c_.pr.dense, "dense rows");
    }
    LTB_RETURN_IF_ERROR(c_.p.geo.rays->error());
    auto bytes = [](const auto& v) {
      return ByteSpan(reinterpret_cast<const std::byte*>(v.data()), v.size() * sizeof(v[0]));
    };
    const ByteSpan parts[7] = {bytes(ids),  bytes(direct),  bytes(feat),    bytes(nrays),
                               bytes(secs), bytes(ntraced), bytes(indirect)};
    for (uint32_t a = 0; a < (c_.p.bounces > 0 ? 7u : 6u); ++a) {
      if (w.Has(a, c)) continue;
      LTB_RETURN_IF_ERROR(w.Put(a, c, parts[a]));
    }
    return Status::Ok();
  }

  const Context& c_;
  uint32_t low_res_ = 1;
  uint64_t low_cols_ = 6;
  std::atomic<uint64_t> done_{0};
};

// ---- Phase 2 ----

// The sealed checkpoint, its chunks mapped: a view of every dense row.
struct DenseRows {
  io::ContainerReader reader;
  std::vector<io::Chunk> chunks;  // per chunk: direct, features, rays, seconds, [indirect]
  std::vector<sp::DenseView> views;
  std::vector<uint64_t> rays;
  std::vector<float> seconds;
  std::vector<uint32_t> traced;
};

Result<std::unique_ptr<DenseRows>> MapDense(const std::string& path, const Params& pr, bool bounces) {
  LTB_ASSIGN_OR_RETURN(io::ContainerReader r, io::ContainerReader::Open(path));
  auto d = std::make_unique<DenseRows>(DenseRows{std::move(r), {}, {}, {}, {}, {}});
  const uint64_t nchunks = (pr.dense + pr.dense_block - 1) / pr.dense_block, fb = pr.cols;
  d->views.resize(pr.dense);
  d->rays.resize(pr.dense);
  d->seconds.resize(pr.dense);
  d->traced.resize(pr.dense);
  for (uint64_t c = 0; c < nchunks; ++c) {
    LTB_ASSIGN_OR_RETURN(io::Chunk direct, d->reader.ReadChunk(kDirect, c));
    LTB_ASSIGN_OR_RETURN(io::Chunk feat, d->reader.ReadChunk(kFeatures, c));
    LTB_ASSIGN_OR_RETURN(io::Chunk rays, d->reader.ReadChunk(kDenseRays, c));
    LTB_ASSIGN_OR_RETURN(io::Chunk secs, d->reader.ReadChunk(kDenseSeconds, c));
    LTB_ASSIGN_OR_RETURN(io::Chunk traced, d->reader.ReadChunk(kDenseTraced, c));
    const uint64_t i0 = c * pr.dense_block, n = std::min(pr.dense_block, pr.dense - i0);
    for (uint64_t i = 0; i < n; ++i) {
      d->views[i0 + i].direct = direct.as<float>().data() + i * pr.cols;
      d->views[i0 + i].features = feat.as<uint8_t>().data() + i * fb;
      d->rays[i0 + i] = rays.as<uint64_t>()[i];
      d->seconds[i0 + i] = secs.as<float>()[i];
      d->traced[i0 + i] = traced.as<uint32_t>()[i];
    }
    d->chunks.push_back(std::move(direct));
    d->chunks.push_back(std::move(feat));
    if (bounces) {
      LTB_ASSIGN_OR_RETURN(io::Chunk ind, d->reader.ReadChunk(kIndirect, c));
      for (uint64_t i = 0; i < n; ++i) d->views[i0 + i].indirect = ind.as<float>().data() + i * pr.cols;
      d->chunks.push_back(std::move(ind));
    }
  }
  return d;
}

nlohmann::json OutputMetadata(const SampleOptions& o, const Prepared& p, const Params& pr, uint64_t block) {
  nlohmann::json meta = SampleMetadata(o, p, block);
  for (const ArraySpec& a :
       {RowArray("sparse_kind", DType::kU8, p.rows, 1, block), RowArray("sparse_traced", DType::kU32, p.rows, 1, block),
        RowArray("sparse_rays", DType::kU64, p.rows, 1, block),
        RowArray("sparse_residual", DType::kF32, p.rows, 1, block),
        RowArray("sparse_seconds", DType::kF32, p.rows, 1, block)}) {
    meta["arrays"].push_back(a.ToJson());
  }
  meta["provenance"]["parameters"]["sparse"] = ParamsJson(o, pr);
  AddReflectance(p, block, &meta);
  return meta;
}

struct Phase2Counters {
  std::atomic<uint64_t> rays_sparse{0}, written{0}, done{0};
};

class Phase2Runner {
 public:
  Phase2Runner(const Context& c, const DenseRows& dense, const std::vector<int64_t>& dense_of)
      : c_(c), dense_(dense), dense_of_(dense_of) {
    pos_.resize(c.pr.dense);
    nor_.resize(c.pr.dense);
    for (uint64_t r = 0; r < c.p.rows; ++r) {
      if (dense_of[r] < 0) continue;
      pos_[static_cast<size_t>(dense_of[r])] = c.pts.pt[r].p;
      nor_[static_cast<size_t>(dense_of[r])] = c.pts.pt[r].n;
    }
    grid_ = std::make_unique<sp::PointGrid>(c.pr.radius / 4, pos_, nor_);
  }

  Status Block(io::ContainerWriter& w, uint64_t chunk, uint64_t block, Phase2Counters& cnt) {
    const uint64_t cols = c_.pr.cols, r0 = chunk * block, n = std::min(block, c_.p.rows - r0);
    std::vector<float> mat(n * cols, 0.0f), pos(n * 3, 0.0f), nor(n * 3, 0.0f), residual(n, 0.0f), secs(n, 0.0f);
    std::vector<uint8_t> mask(n, 0), kind(n, kNone);
    std::vector<uint32_t> traced(n, 0);
    std::vector<uint64_t> rays(n, 0);
    for (uint64_t i = 0; i < n; ++i) {
      if (c_.progress.Cancelled()) return Cancelled("interrupted; committed chunks are kept, rerun to resume");
      c_.progress.Report(cnt.done.fetch_add(1) + 1, todo_rows_, "rows");
      const uint64_t row = r0 + i;
      const RowPoint& rp = c_.pts.pt[row];
      if (!rp.valid) continue;
      const auto t0 = std::chrono::steady_clock::now();
      mask[i] = 1;
      for (int k = 0; k < 3; ++k) {
        pos[3 * i + k] = static_cast<float>(rp.p[k]);
        nor[3 * i + k] = static_cast<float>(rp.n[k]);
      }
      float* out = mat.data() + i * cols;
      const int64_t di = dense_of_[row];
      if (di >= 0) {  // a dense row: direct + indirect from the checkpoint
        const sp::DenseView& v = dense_.views[static_cast<size_t>(di)];
        for (uint64_t c = 0; c < cols; ++c) {
          out[c] = v.indirect ? static_cast<float>(double{v.direct[c]} + double{v.indirect[c]}) : v.direct[c];
        }
        kind[i] = kDense;
        rays[i] = dense_.rays[static_cast<size_t>(di)];
        secs[i] = dense_.seconds[static_cast<size_t>(di)];
        traced[i] = dense_.traced[static_cast<size_t>(di)];
        continue;
      }
      const SparseRowOutcome r = ReconstructRow(c_, *grid_, dense_.views, row, rp, out);
      kind[i] = r.kind;
      residual[i] = r.residual;
      traced[i] = r.traced;
      rays[i] = r.rays;
      cnt.rays_sparse += r.rays;
      secs[i] = static_cast<float>(Seconds(t0));
    }
    LTB_RETURN_IF_ERROR(c_.p.geo.rays->error());
    EncodeOptions matrix_encoding;
    if (c_.o.row_filter) {  // fused row-transform, as RunRowTransform does to this block
      thread_local std::vector<float> scratch;
      scratch.resize(RowBlockScratchSize(c_.p.r));
      uint64_t zero_rows = 0;
      TransformRowBlock(*c_.o.row_filter, c_.p.r, mat.data(), n, scratch.data(), &zero_rows);
      matrix_encoding.zstd = c_.o.row_zstd;
    }
    auto bytes = [](const auto& v) {
      return ByteSpan(reinterpret_cast<const std::byte*>(v.data()), v.size() * sizeof(v[0]));
    };
    const ByteSpan parts[9] = {bytes(mat),    bytes(mask), bytes(pos),      bytes(nor), bytes(kind),
                               bytes(traced), bytes(rays), bytes(residual), bytes(secs)};
    for (uint32_t a = 0; a < 9; ++a) {
      if (w.Has(a, chunk)) continue;
      LTB_RETURN_IF_ERROR(w.Put(a, chunk, parts[a], a == 0 ? matrix_encoding : EncodeOptions{}));
      cnt.written++;
    }
    return Status::Ok();
  }

  void SetTodoRows(uint64_t n) { todo_rows_ = n; }

 private:
  const Context& c_;
  const DenseRows& dense_;
  const std::vector<int64_t>& dense_of_;
  std::vector<glm::dvec3> pos_, nor_;
  std::unique_ptr<sp::PointGrid> grid_;
  uint64_t todo_rows_ = 0;
};

}  // namespace

Result<std::optional<SampleResult>> RunSparseSample(const SampleOptions& o, const Prepared& p, const Progress& progress,
                                                    SparseAuto* full) {
  Sampler sampler(p.scene, p.geo, p.r, p.spp, p.bounces, p.seed);
  LTB_ASSIGN_OR_RETURN(RowPoints pts, PrimaryPoints(sampler, p, o.jobs, progress));
  const Params pr = Resolve(o, p, pts);
  const uint64_t block = BlockRows(o, p.rows, pr.cols);
  nlohmann::json out_meta = OutputMetadata(o, p, pr, block);
  const sp::WindowTable windows(p.r);
  const Context ctx{o, p, sampler, pts, pr, windows, progress};
  std::optional<SparseAuto> decision;
  if (o.sparse.automatic) {
    LTB_ASSIGN_OR_RETURN(SparseAuto d, DecideSparse(ctx));
    if (!d.sparse) {
      *full = d;
      return std::optional<SampleResult>();
    }
    out_meta["provenance"]["parameters"]["sparse_auto"] = SparseAutoJson(d);
    decision = d;
  }

  SampleResult result;
  result.rows = p.rows;
  result.valid_rows = pts.valid.size();
  result.cube_res = p.r;
  result.spp = p.spp;
  result.bounces = p.bounces;
  result.degenerate_triangles = p.geo.degenerate;
  SparseStats st;
  st.radius = pr.radius;
  st.features = pr.features;
  st.dense_rows = pr.dense;
  st.iterations = pr.rounds.size();
  st.entries_total = pts.valid.size() * pr.cols;

  // Open the output first: a finished output is not baked again, and other parameters are
  // refused before phase 1 spends anything.
  io::WriterOptions wo;
  wo.overwrite_mismatch = o.overwrite;
  wo.direct_io = o.direct_io;
  LTB_ASSIGN_OR_RETURN(io::ContainerWriter out, io::OpenStageOutput(o.output, out_meta, wo, o.shard));
  const uint64_t nchunks = (p.rows + block - 1) / block;
  result.chunks_total = nchunks * 9;
  result.chunks_already_committed = out.resume_info().committed_chunks;

  // Phase 1 (its checkpoint is sealed once done; a rerun reads it back).
  const std::string cp = SparseCheckpointPath(o.output);
  std::vector<uint64_t> todo;  // output blocks with any array missing
  for (uint32_t a = 0; a < 9; ++a) {
    std::vector<uint64_t> m = out.Missing(a);
    todo.insert(todo.end(), m.begin(), m.end());
  }
  std::sort(todo.begin(), todo.end());
  todo.erase(std::unique(todo.begin(), todo.end()), todo.end());
  Phase1 ph1;
  if (pr.dense > 0 && !todo.empty()) {  // a finished output needs neither phase
    Phase1Runner runner(ctx);
    LTB_RETURN_IF_ERROR(runner.Run(&ph1));
  }
  st.seconds[0] = ph1.seconds;

  // Phase 2.
  const auto t2 = std::chrono::steady_clock::now();
  std::vector<int64_t> dense_of(p.rows, -1);
  for (size_t i = 0; i < ph1.rows.size(); ++i) dense_of[ph1.rows[i]] = static_cast<int64_t>(i);
  std::unique_ptr<DenseRows> dense;
  if (!ph1.rows.empty()) {
    LTB_ASSIGN_OR_RETURN(dense, MapDense(cp, pr, p.bounces > 0));
  } else {
    dense = std::make_unique<DenseRows>();
  }
  Phase2Runner runner(ctx, *dense, dense_of);
  runner.SetTodoRows(std::min(p.rows, todo.size() * block));
  Phase2Counters cnt;
  Status s = ParallelFor(todo, o.jobs, Progress{.update = nullptr, .cancelled = progress.cancelled}, "chunks",
                         [&](uint64_t c) -> Status { return runner.Block(out, c, block, cnt); });
  result.chunks_written = cnt.written;
  LTB_RETURN_IF_ERROR(s);
  LTB_RETURN_IF_ERROR(WriteReflectance(p, sampler, block, out, false, progress));
  LTB_RETURN_IF_ERROR(out.Finish());
  st.seconds[1] = Seconds(t2);
  // The bake's totals (earlier runs' work included), from the sealed output's side tables.
  {
    LTB_ASSIGN_OR_RETURN(io::ContainerReader sealed, io::ContainerReader::Open(o.output));
    LTB_ASSIGN_OR_RETURN(nlohmann::json sum, SummarizeSparse(sealed));
    st.entries_traced[0] = sum["traced_entries"]["dense"].get<uint64_t>();
    st.entries_traced[1] = sum["traced_entries"]["sparse"].get<uint64_t>();
    st.fallback_rows = sum["rows"]["traced_in_full"].get<uint64_t>();
    st.sparse_rows = sum["rows"]["sparse"].get<uint64_t>() + st.fallback_rows;
    st.total_rays[0] = sum["rays"]["dense"].get<uint64_t>();
    st.total_rays[1] = sum["rays"]["sparse"].get<uint64_t>();
  }
  st.rays[0] = ph1.rays;
  st.rays[1] = cnt.rays_sparse;
  result.rays = st.rays[0] + st.rays[1];
  // The checkpoint has served: the output holds every row now.
  dense.reset();
  std::error_code ec;
  std::filesystem::remove(cp, ec);
  result.sparse = st;
  result.sparse_auto = decision;
  return std::optional<SampleResult>(std::move(result));
}

}  // namespace sample_internal
}  // namespace ltb::stages
