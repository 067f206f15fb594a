// `ltbake sample --sparse auto` (docs/SPARSE.md "Sparse or full: --sparse auto"): a short
// pilot measures what a row costs traced in full, traced as a dense row and reconstructed as
// a sparse row on this scene, and the bake goes the cheaper way.
//
// The pilot copies phase 2's situation in a few small neighbourhoods. Around each of a few
// seed rows (drawn by a hash of the seed), the rows within four radii are flagged dense with
// probability --dense-fraction (the density phase 2 sees); the seed's nearest unflagged rows
// are the pilot's sparse rows. Each is reconstructed (ReconstructRow, the bake's own code,
// fallbacks included) from the flagged rows it picks as neighbours, which are traced first
// (TraceDenseRow), and traced in full (Sampler::Transport) for the comparison. Costs are
// thread CPU seconds, so other processes on the machine do not tilt them. The prediction:
//   full   = V · t_full
//   sparse = D · t_dense + (V − D) · t_sparse
// over V rows that see geometry and D dense rows; sparse wins when it is at most kMargin of
// full. Neighbourhoods run a batch (one per thread) at a time, and a clear case stops early.
// The decision and its figures go into the output's metadata, and a rerun that resumes
// the output follows them.
#include <algorithm>
#include <cmath>
#include <ctime>
#include <mutex>
#include <string>
#include <vector>

#include "format/io/container_reader.h"
#include "format/io/file.h"
#include "stages/common/parallel_for.h"
#include "stages/sample/sparse_internal.h"

namespace ltb::stages::sample_internal::sparse_bake {
namespace {

constexpr uint32_t kSeeds = 8;            // neighbourhoods
constexpr uint32_t kInner = 8;            // sparse rows per neighbourhood
constexpr double kRegionRadii = 4.0;      // a neighbourhood: the rows within this many radii of its seed
constexpr double kMargin = 0.8;           // sparse when predicted at most this fraction of full
constexpr uint64_t kPilotRound = 0xA070;  // hash rounds of the pilot's draws (none of phase 1's)
// Early stop: after kClearRows pilot rows, when the predicted speed-up is below kClearBelow or
// above kClearAbove times the one sparse needs (1 / margin).
constexpr uint64_t kClearRows = 16;
constexpr double kClearBelow = 0.8, kClearAbove = 1.5;

double Hash01(uint64_t seed, uint64_t round, uint64_t row) {
  const uint64_t z = sample::Mix64(seed ^ 0xA07055A07055A070ull ^ sample::Mix64(round * 0x9E3779B97F4A7C15ull + row));
  return (static_cast<double>(z >> 11) + 1.0) * 0x1.0p-53;
}

double ThreadCpuSeconds() {
  timespec t{};
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t);
  return static_cast<double>(t.tv_sec) + 1e-9 * static_cast<double>(t.tv_nsec);
}

struct Tally {
  std::mutex mu;
  double full = 0, dense = 0, sparse = 0;  // thread CPU seconds
  uint64_t full_rows = 0, dense_rows = 0, sparse_rows = 0, fallbacks = 0;
};

// One neighbourhood of the pilot.
Status Neighbourhood(const Context& c, const sp::PointGrid& all, uint64_t seed_row, Tally* tally) {
  const RowPoint& sp0 = c.pts.pt[seed_row];
  std::vector<uint32_t> region;  // indices into c.pts.valid, the nearest first
  all.Query(sp0.p, sp0.n, kRegionRadii * c.pr.radius, UINT32_MAX, -2.0, -1, &region);
  std::vector<uint64_t> inner, flagged;
  for (uint32_t i : region) {
    const uint64_t r = c.pts.valid[i];
    if (Hash01(c.p.seed, kPilotRound + 1, r) <= c.o.sparse.dense_fraction) {
      flagged.push_back(r);
    } else if (inner.size() < kInner) {
      inner.push_back(r);
    }
  }
  if (inner.empty()) return Status::Ok();
  std::vector<glm::dvec3> fpos, fnor;
  for (uint64_t r : flagged) {
    fpos.push_back(c.pts.pt[r].p);
    fnor.push_back(c.pts.pt[r].n);
  }
  const sp::PointGrid local(c.pr.radius / 4, fpos, fnor);
  // The flagged rows the sparse rows take as neighbours, traced as dense rows.
  std::vector<uint8_t> needed(flagged.size(), 0);
  std::vector<uint32_t> nb;
  for (uint64_t r : inner) {
    DenseNeighbours(c, local, c.pts.pt[r], &nb);
    for (uint32_t k : nb) needed[k] = 1;
  }
  const uint64_t cols = c.pr.cols;
  const bool bounces = c.p.bounces > 0;
  std::vector<float> direct(flagged.size() * cols), indirect(bounces ? flagged.size() * cols : 0);
  std::vector<uint8_t> features(flagged.size() * cols);
  std::vector<sp::DenseView> views(flagged.size());
  // Scratch that lives with the thread, as in the bake, and a thread's first calls untimed:
  // they allocate it (measured: that made the first rows of a pilot look 1.3x dearer).
  thread_local DenseScratch ds;
  thread_local RowScratch sc;
  thread_local bool warm = false;
  ds.windows = &c.windows;
  std::vector<float> out(cols), out2(cols);
  sample::Counters cnt;
  if (!warm) {
    TraceDenseRow(c.s, inner[0], c.pts.pt[inner[0]], cols, ds, out.data(), bounces ? out2.data() : nullptr, nullptr);
    c.s.Transport(inner[0], c.pts.pt[inner[0]], out.data(), sc, cnt);
  }
  double t_dense = 0, t_sparse = 0, t_full = 0;
  uint64_t n_dense = 0, fallbacks = 0;
  for (size_t k = 0; k < flagged.size(); ++k) {
    if (!needed[k]) continue;
    if (c.progress.Cancelled()) return Cancelled("interrupted during the --sparse auto pilot; rerun to start over");
    float* d = direct.data() + k * cols;
    float* ind = bounces ? indirect.data() + k * cols : nullptr;
    const double t0 = ThreadCpuSeconds();
    TraceDenseRow(c.s, flagged[k], c.pts.pt[flagged[k]], cols, ds, d, ind, features.data() + k * cols);
    t_dense += ThreadCpuSeconds() - t0;
    ++n_dense;
    views[k] = sp::DenseView{d, ind, features.data() + k * cols};
  }
  if (!warm) ReconstructRow(c, local, views, inner[0], c.pts.pt[inner[0]], out.data());
  warm = true;
  for (uint64_t r : inner) {
    const double t0 = ThreadCpuSeconds();
    const SparseRowOutcome o = ReconstructRow(c, local, views, r, c.pts.pt[r], out.data());
    const double t1 = ThreadCpuSeconds();
    c.s.Transport(r, c.pts.pt[r], out.data(), sc, cnt);
    t_full += ThreadCpuSeconds() - t1;
    t_sparse += t1 - t0;
    if (o.kind == kDense) ++fallbacks;
  }
  LTB_RETURN_IF_ERROR(c.p.geo.rays->error());
  std::lock_guard<std::mutex> lock(tally->mu);
  tally->dense += t_dense;
  tally->dense_rows += n_dense;
  tally->sparse += t_sparse;
  tally->full += t_full;
  tally->sparse_rows += inner.size();
  tally->full_rows += inner.size();
  tally->fallbacks += fallbacks;
  return Status::Ok();
}

// The figures of *d from the pilot's tally: per-row costs and both predictions, and the decision.
void Predict(const Tally& t, uint64_t valid, uint64_t dense, SparseAuto* d) {
  d->pilot_rows = t.sparse_rows;
  d->pilot_dense_rows = t.dense_rows;
  d->full_row = t.full_rows ? t.full / static_cast<double>(t.full_rows) : 0;
  d->sparse_row = t.sparse_rows ? t.sparse / static_cast<double>(t.sparse_rows) : 0;
  d->dense_row = t.dense_rows ? t.dense / static_cast<double>(t.dense_rows) : d->full_row;
  d->fallback_fraction = t.sparse_rows ? static_cast<double>(t.fallbacks) / static_cast<double>(t.sparse_rows) : 0;
  const auto vd = static_cast<double>(valid), dd = static_cast<double>(dense);
  d->predicted_full = vd * d->full_row;
  d->predicted_sparse = dd * d->dense_row + (vd - dd) * d->sparse_row;
  d->sparse = t.sparse_rows > 0 && d->predicted_sparse <= d->margin * d->predicted_full;
}

std::string Ms(double seconds) {
  char b[32];
  std::snprintf(b, sizeof b, "%.3g ms", seconds * 1e3);
  return b;
}

// The decision recorded in an output an earlier run started for the same scene and sampling
// (what the costs depend on; other differences are the writer's to refuse or replace).
std::optional<SparseAuto> Recorded(const Context& c) {
  const std::string& output = c.o.output;
  if (!io::PathExists(output)) return std::nullopt;
  auto f = io::File::Open(output, io::File::Mode::kRead);
  if (!f.ok()) return std::nullopt;
  auto size = f->Size();
  if (!size.ok()) return std::nullopt;
  auto prelude = io::ReadPrelude(*f, *size);
  if (!prelude.ok()) return std::nullopt;
  const nlohmann::json& m = prelude->metadata.json;
  if (!m.contains("provenance") || !m["provenance"].contains("parameters")) return std::nullopt;
  const nlohmann::json& params = m["provenance"]["parameters"];
  const nlohmann::json same = {{"cube_res", c.p.r},
                               {"spp", c.p.spp},
                               {"bounces", c.p.bounces},
                               {"seed", c.p.seed},
                               {"scene_hash", c.p.geo.scene_hash}};
  for (const auto& [key, value] : same.items()) {
    if (!params.contains(key) || params[key] != value) return std::nullopt;
  }
  if (!params.contains("sparse_auto")) return std::nullopt;
  auto d = SparseAutoFromJson(params["sparse_auto"]);
  if (!d.ok()) return std::nullopt;
  d->resumed = true;
  return *d;
}

}  // namespace

nlohmann::json SparseAutoJson(const SparseAuto& d) {
  return {{"decision", d.sparse ? "sparse" : "full"},
          {"reason", d.reason},
          {"pilot_rows", d.pilot_rows},
          {"pilot_dense_rows", d.pilot_dense_rows},
          {"pilot_seconds", d.pilot_seconds},
          {"cpu_seconds_per_row", {{"full", d.full_row}, {"dense", d.dense_row}, {"sparse", d.sparse_row}}},
          {"fallback_fraction", d.fallback_fraction},
          {"predicted_cpu_seconds", {{"full", d.predicted_full}, {"sparse", d.predicted_sparse}}},
          {"margin", d.margin}};
}

Result<SparseAuto> SparseAutoFromJson(const nlohmann::json& j) {
  try {
    SparseAuto d;
    d.sparse = j.at("decision").get<std::string>() == "sparse";
    d.reason = j.at("reason").get<std::string>();
    d.pilot_rows = j.at("pilot_rows").get<uint64_t>();
    d.pilot_dense_rows = j.at("pilot_dense_rows").get<uint64_t>();
    d.pilot_seconds = j.at("pilot_seconds").get<double>();
    d.full_row = j.at("cpu_seconds_per_row").at("full").get<double>();
    d.dense_row = j.at("cpu_seconds_per_row").at("dense").get<double>();
    d.sparse_row = j.at("cpu_seconds_per_row").at("sparse").get<double>();
    d.fallback_fraction = j.at("fallback_fraction").get<double>();
    d.predicted_full = j.at("predicted_cpu_seconds").at("full").get<double>();
    d.predicted_sparse = j.at("predicted_cpu_seconds").at("sparse").get<double>();
    d.margin = j.at("margin").get<double>();
    return d;
  } catch (const nlohmann::json::exception& e) {
    return InvalidArgument(std::string("sparse_auto record: ") + e.what());
  }
}

Result<SparseAuto> DecideSparse(const Context& c) {
  if (std::optional<SparseAuto> r = Recorded(c)) return *r;
  const auto t0 = std::chrono::steady_clock::now();
  SparseAuto d;
  const uint64_t v = c.pts.valid.size();
  if (v == 0) {
    d.reason = "no row sees geometry";
    return d;
  }
  std::vector<glm::dvec3> pos(v), nor(v);
  for (uint64_t i = 0; i < v; ++i) {
    pos[i] = c.pts.pt[c.pts.valid[i]].p;
    nor[i] = c.pts.pt[c.pts.valid[i]].n;
  }
  const sp::PointGrid all(c.pr.radius / 4, pos, nor);
  // The seeds: the rows with the smallest hashes, at most one in 20 rows' worth of pilot rows.
  const uint64_t seeds = std::clamp<uint64_t>(v / (20 * kInner), 1, kSeeds);
  std::vector<std::pair<double, uint64_t>> keys;
  keys.reserve(v);
  for (uint64_t r : c.pts.valid) keys.emplace_back(Hash01(c.p.seed, kPilotRound, r), r);
  std::partial_sort(keys.begin(), keys.begin() + static_cast<std::ptrdiff_t>(seeds), keys.end());
  std::vector<uint64_t> items;
  for (uint64_t i = 0; i < seeds; ++i) items.push_back(keys[i].second);
  // Seeds a batch (one per thread) at a time; a clear case stops after a batch of at least
  // kClearRows pilot rows: its prediction well short of the speed-up sparse needs, or well past it.
  Tally t;
  d.margin = c.o.sparse.auto_margin.value_or(kMargin);
  const auto batch = static_cast<uint64_t>(std::max(2, c.o.jobs));
  for (uint64_t i0 = 0; i0 < items.size(); i0 += batch) {
    const std::vector<uint64_t> part(items.begin() + static_cast<std::ptrdiff_t>(i0),
                                     items.begin() + static_cast<std::ptrdiff_t>(std::min(items.size(), i0 + batch)));
    LTB_RETURN_IF_ERROR(ParallelFor(part, c.o.jobs, Progress{.update = nullptr, .cancelled = c.progress.cancelled},
                                    "rows", [&](uint64_t r) { return Neighbourhood(c, all, r, &t); }));
    Predict(t, v, c.pr.dense, &d);
    const double speedup = d.predicted_sparse > 0 ? d.predicted_full / d.predicted_sparse : 0.0;
    if (t.sparse_rows >= kClearRows && (speedup * d.margin < kClearBelow || speedup * d.margin > kClearAbove)) break;
  }
  char r[96];
  std::snprintf(r, sizeof r,
                d.margin > 0 ? "%.2fx the full bake's speed (it needs %.2fx)"
                             : "%.2fx the full bake's speed (margin 0: never sparse)",
                d.predicted_sparse > 0 ? d.predicted_full / d.predicted_sparse : 0.0,
                d.margin > 0 ? 1.0 / d.margin : 0.0);
  d.reason = "a row costs " + Ms(d.full_row) + " traced in full, " + Ms(d.dense_row) + " as a dense row and " +
             Ms(d.sparse_row) + " as a sparse row (" + std::to_string(t.fallbacks) + " of " +
             std::to_string(t.sparse_rows) + " pilot rows traced like dense rows): sparse predicted at " + r;
  if (t.sparse_rows == 0) d.reason = "the pilot found no sparse row to try";
  d.pilot_seconds = Seconds(t0);
  return d;
}

}  // namespace ltb::stages::sample_internal::sparse_bake
