#include "stages/cpca/cpca.h"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>

#include "format/io/container_reader.h"
#include "format/io/container_writer.h"
#include "format/io/file.h"
#include "format/io/file_lock.h"
#include "stages/common/basis.h"
#include "stages/common/parallel_for.h"
#include "stages/cpca/cpca_fit.h"
#include "stages/cpca/cpca_model.h"

namespace ltb::stages {

using namespace ltb::format;
using cpca_internal::Assigner;
using cpca_internal::CpcaFitter;
using cpca_internal::FitOutcome;
using cpca_internal::Params;

std::string CpcaCheckpointPath(const std::string& output) { return output + ".cpca-state"; }

namespace {

Status CheckOptions(const CpcaOptions& o) {
  if (o.clusters == 0) return InvalidArgument("--clusters 0: need at least one cluster");
  if (o.growth_step == 0) return InvalidArgument("--growth-step 0: need at least 1");
  if (o.max_iterations == 0) return InvalidArgument("--max-iterations 0: need at least 1");
  if (!(o.tolerance >= 0) || !std::isfinite(o.tolerance)) {
    return InvalidArgument("--tolerance " + std::to_string(o.tolerance) + ": need a finite value >= 0");
  }
  return Status::Ok();
}

// The input: a complete f32 row-block matrix with at least K rows and S dimensions.
Status CheckInput(const CpcaOptions& o, const io::ContainerReader& in) {
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
  return Status::Ok();
}

// Dense-first, resolved: whether the growth levels run on the dense rows, which array
// marks them, and how many there are.
struct DensePlan {
  bool on = false;
  int array = -1;
  uint64_t dense = 0;
};

Result<DensePlan> PlanDenseFirst(const CpcaOptions& o, const io::ContainerReader& in) {
  if (o.dense_first == DenseFirst::kOff) return DensePlan{};
  const bool asked = o.dense_first == DenseFirst::kOn;
  const Metadata& meta = in.metadata();
  const uint64_t n = meta.matrix().rows;
  const int a = meta.FindArray(kSparseKindArray);
  if (a < 0) {
    if (!asked) return DensePlan{};
    return FailedPrecondition(o.input + ": has no \"" + kSparseKindArray +
                              "\" array, so --dense-first has no dense rows to start from (a sparse bake of "
                              "`ltbake sample` writes it, and row-transform keeps it); drop --dense-first (or give "
                              "--no-dense-first) for a densely sampled matrix");
  }
  const ArraySpec& spec = meta.arrays[a];
  if (spec.dtype != DType::kU8 || spec.cols != 1 || spec.rows != n || spec.layout != Layout::kRows) {
    return DataLoss(o.input + ": side table \"" + kSparseKindArray + "\" is " + std::to_string(spec.rows) + " x " +
                    std::to_string(spec.cols) + " " + DTypeName(spec.dtype) + " (" + LayoutName(spec.layout) +
                    "), not one u8 per row of the " + std::to_string(n) + "-row matrix in row blocks");
  }
  uint64_t count[3] = {0, 0, 0};
  for (uint64_t c = 0; c < spec.ChunkCount(); ++c) {
    LTB_ASSIGN_OR_RETURN(io::Chunk chunk, in.ReadChunk(static_cast<uint32_t>(a), c));
    auto v = chunk.as<uint8_t>();
    for (size_t i = 0; i < v.size(); ++i) {
      if (v[i] > 2) {
        return DataLoss(o.input + ": side table \"" + kSparseKindArray + "\" gives row " +
                        std::to_string(chunk.extent().row0 + i) + " kind " + std::to_string(v[i]) +
                        "; the kinds are 0 (no geometry), 1 (dense) and 2 (sparse)");
      }
      count[v[i]]++;
    }
  }
  const uint64_t dense = count[kSparseKindDense];
  if (dense == 0) {
    if (!asked) return DensePlan{};
    return FailedPrecondition(o.input + ": its \"" + kSparseKindArray + "\" array marks none of its " +
                              std::to_string(n) + " rows dense (kind 1; " + std::to_string(count[2]) + " sparse, " +
                              std::to_string(count[0]) +
                              " without geometry), so --dense-first has nothing to start from; rerun with "
                              "--no-dense-first");
  }
  if (dense < o.clusters) {
    return FailedPrecondition(o.input + ": has " + std::to_string(dense) + " dense rows (\"" + kSparseKindArray +
                              "\" 1), fewer than --clusters " + std::to_string(o.clusters) +
                              "; dense-first seeds the clusters from dense rows: use at most " + std::to_string(dense) +
                              " clusters, or --no-dense-first");
  }
  return DensePlan{true, a, dense};
}

// Memory: everything but the k-means++ sample is independent of the row count.
struct MemoryPlan {
  uint64_t fixed = 0, per_sample_row = 0, min_sample = 0;
};

// kind_block: the rows per chunk of dense-first's "sparse_kind" array, or 0.
Result<MemoryPlan> PlanMemory(const CpcaOptions& o, uint64_t n, uint64_t d, uint64_t p, uint64_t kind_block) {
  const uint64_t k = o.clusters, s = o.basis;
  const uint64_t jobs = static_cast<uint64_t>(std::max(1, o.jobs));
  const uint64_t block = cpca_internal::PassBlockRows(d);
  constexpr uint64_t kSubRows = cpca_internal::kSubRows;
  const uint64_t model = k * d * 8 * (1 + p);
  const uint64_t fixed = 2 * model                         // model and the rounded copy
                         + k * d * 8 * (1 + p)             // per-pass sums and Σ z zᵀ Q
                         + k * (s + 1) * d * 8             // the assignment's stacked vectors
                         + block * d * 8 * 2 + block * 24  // pass block and its ids/errors
                         + jobs * (block * d * 8 + block * p * 8 + kSubRows * (k * (s + 1) + d) * 8) + 16 * d * 8 +
                         (16ull << 20)  // reseed rows, output chunk buffers
                         // dense-first: the side array's chunk (decoded, copied), a block's row list
                         + (kind_block > 0 ? 2 * kind_block + block * 8 : 0);
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
  return MemoryPlan{fixed, per_sample_row, min_sample};
}

// The passes' memory beside `fixed`, decided once the sample is sized (so neither changes
// the sample, which is part of the run's identity): the extra pass blocks read together
// (PassGroupBlocks) and, in dense-first, the dense rows held in memory (f32 and row number
// each) — when they fit --mem-limit with the sample (which is then read from them), or
// after it (gathered at the first dense pass), else streamed every pass. Returns the
// estimated peak: the start's (fixed + sample) or the passes', whichever is larger.
uint64_t PlanPasses(const CpcaOptions& o, const MemoryPlan& mem, uint64_t n_dense, Params* pr) {
  const uint64_t d = pr->d, block = cpca_internal::PassBlockRows(d);
  pr->group_blocks = cpca_internal::PassGroupBlocks(d, o.jobs);
  uint64_t group = (pr->group_blocks - 1) * block * (d * 8 + 24 + pr->s * 4);
  if (mem.fixed + group > o.mem_limit) {
    pr->group_blocks = 1;
    group = 0;
  }
  const uint64_t sample = pr->sample_rows * mem.per_sample_row;
  const uint64_t cache = n_dense * (d * 4 + 8);
  pr->dense_cache = pr->dense_first && mem.fixed + group + cache <= o.mem_limit;
  pr->sample_from_cache = pr->dense_cache && mem.fixed + sample + cache <= o.mem_limit;
  const uint64_t held = pr->dense_cache ? cache : 0;
  return std::max(mem.fixed + sample + (pr->sample_from_cache ? cache : 0), mem.fixed + group + held);
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
  // Rows the passes read: growth passes (dense rows only in dense-first), final passes,
  // evaluation and encoding.
  const uint64_t n = result.rows;
  result.rows_streamed = (result.iterations + 2) * n;
  if (c.contains("dense_first") && c["dense_first"].is_object()) {
    const auto& df = c["dense_first"];
    result.dense_first = true;
    result.dense_rows = df.value("dense_rows", uint64_t{0});
    const uint64_t dense_passes = df.value("dense_passes", uint64_t{0});
    const uint64_t final_passes = df.value("final_passes", uint64_t{0});
    result.rows_streamed = dense_passes * result.dense_rows + (final_passes + 2) * n;
  }
  result.relative_rms_error = c.value("relative_rms_error", 0.0);
  result.squared_error = c.value("squared_error", 0.0);
  result.squared_norm = c.value("squared_norm", 0.0);
  result.empty_clusters = c.value("empty_clusters", uint64_t{0});
  result.model_bytes = StoredBytes(r, 0);
  for (uint32_t a = 1; a < r.metadata().arrays.size(); ++a) result.row_bytes += StoredBytes(r, a);
  return result;
}

// An existing output: done already (true), resumable, or another run's (refused, or
// removed with its checkpoint under --overwrite).
Result<bool> CheckExistingOutput(const CpcaOptions& o, const nlohmann::json& provenance, const std::string& cp_path) {
  if (!io::PathExists(o.output)) return false;
  auto prev = io::ContainerReader::Open(o.output);
  const bool same = prev.ok() && prev->metadata().json.value("provenance", nlohmann::json()) == provenance &&
                    CpcaModel::IsCpca(prev->metadata());
  if (same && prev->complete()) {
    // A run killed between sealing the output and removing its checkpoint left one.
    std::remove(cp_path.c_str());
    return true;
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
  return false;
}

// The output container from the fit (completing a partial one): the model's vectors, then
// each row chunk's ids and weights, encoded with the rounded model.
Status WriteOutput(const CpcaOptions& o, const io::ContainerReader& in, const Params& pr,
                   const nlohmann::json& provenance, const CpcaFitter& fitter, const FitOutcome& fit,
                   const Progress& progress, CpcaResult* result) {
  const uint64_t n = pr.n_rows, d = pr.d, k = pr.k, s = pr.s;
  uint64_t empty = 0;
  for (uint64_t c : fit.sizes) empty += c == 0;
  const CpcaLayout layout = CpcaLayout::For(k, s, n, d, cpca_internal::kSubRows);
  CpcaFitInfo info;
  info.iterations = fit.passes;
  info.growth_levels = pr.levels;
  info.seed = o.seed;
  info.squared_error = fit.squared_error;
  info.squared_norm = fit.squared_norm;
  info.empty_clusters = empty;
  info.dense_first = pr.dense_first;
  info.dense_rows = pr.dense_first ? pr.n_dense : 0;
  info.dense_passes = fit.passes - fit.final_passes;
  info.final_passes = fit.final_passes;
  nlohmann::json basis = in.metadata().json.value("basis", nlohmann::json::object());
  nlohmann::json out_meta = CpcaOutputMetadata(layout, info, basis, provenance);
  // A colour bake's channel and reflectance table go with the rows (docs/COLOUR.md).
  const int refl = in.metadata().FindArray("reflectance");
  if (refl >= 0) out_meta["arrays"].push_back(in.metadata().arrays[refl].ToJson());
  // A set member's identity, and a factored bake's view factors and geometry (docs/GLOSSY.md).
  for (const char* key : {"channel", "term", "factor", "geometry"}) {
    if (in.metadata().json.contains(key)) out_meta[key] = in.metadata().json[key];
  }
  io::WriterOptions wo;
  wo.overwrite_mismatch = o.overwrite;
  LTB_ASSIGN_OR_RETURN(io::ContainerWriter out, io::ContainerWriter::Open(o.output, out_meta, wo));
  result->resumed = result->resumed || out.resume_info().resumed;
  result->chunks_already_committed = out.resume_info().committed_chunks;

  const cpca_internal::Model& rounded = fit.rounded;
  LTB_ASSIGN_OR_RETURN(uint64_t vectors_written, WriteCpcaVectors(out, layout, [&](uint64_t cl, uint64_t i, float* v) {
                         for (uint64_t j = 0; j < d; ++j) {
                           v[j] = static_cast<float>(i == 0 ? rounded.mean(cl, j) : rounded.dir[cl](j, i - 1));
                         }
                       }));
  result->chunks_written += vectors_written;
  const Assigner final_assigner(rounded, s);
  const uint64_t base_done = fitter.rows_done();
  std::atomic<uint64_t> encoded{0};
  // Row chunks are encoded in parallel, and so are pieces of a chunk when there are fewer
  // chunks than threads (a chunk holds up to 2^20/S rows: often all of them). Pieces start
  // at multiples of kSubRows, so every row is encoded in the same sub-block either way.
  const uint64_t row_chunks = layout.ids.ChunkCount();
  const uint64_t jobs = static_cast<uint64_t>(std::max(1, o.jobs));
  const int inner = static_cast<int>(std::max<uint64_t>(1, (jobs + row_chunks - 1) / row_chunks));
  auto encode = [&](uint64_t row0, uint64_t rows, uint32_t* id, float* w) -> Status {
    constexpr uint64_t kPiece = 16 * cpca_internal::kSubRows;
    std::vector<uint64_t> pieces;
    for (uint64_t at = 0; at < rows; at += kPiece) pieces.push_back(at);
    return ParallelFor(pieces, inner, Progress{}, "rows", [&](uint64_t at) -> Status {
      if (progress.Cancelled()) return Cancelled("interrupted while writing; rerun the same command to resume");
      const uint64_t n_rows = std::min(kPiece, rows - at);
      std::vector<double> err(n_rows), x;
      return fitter.Encode(final_assigner, rounded, row0 + at, n_rows, &x, id + at, w + at * s, err.data());
    });
  };
  auto done = [&](uint64_t rows) { progress.Report(base_done + (encoded += rows), fitter.rows_total(), "rows"); };
  LTB_ASSIGN_OR_RETURN(uint64_t rows_written, WriteCpcaRows(out, layout, o.jobs, encode, done));
  result->chunks_written += rows_written;
  if (refl >= 0) {
    const auto out_refl = static_cast<uint32_t>(out.metadata().FindArray("reflectance"));
    for (uint64_t c : out.Missing(out_refl)) {
      LTB_ASSIGN_OR_RETURN(io::Chunk chunk, in.ReadChunk(static_cast<uint32_t>(refl), c));
      LTB_RETURN_IF_ERROR(out.Put(out_refl, c, chunk.bytes()));
      result->chunks_written++;
    }
  }
  return out.Finish();
}

}  // namespace

Result<CpcaResult> RunCpca(const CpcaOptions& o, const Progress& progress) {
  const auto t0 = std::chrono::steady_clock::now();
  LTB_RETURN_IF_ERROR(CheckOptions(o));
  LTB_ASSIGN_OR_RETURN(io::ContainerReader in, io::ContainerReader::Open(o.input));
  LTB_RETURN_IF_ERROR(CheckInput(o, in));
  LTB_ASSIGN_OR_RETURN(const DensePlan dense, PlanDenseFirst(o, in));
  const ArraySpec& a = in.metadata().matrix();
  const uint64_t n = a.rows, d = a.cols, k = o.clusters, s = o.basis;
  const uint64_t p = s == 0 ? 0 : std::min(d, s + o.oversample);
  const uint64_t kind_block = dense.on ? in.metadata().arrays[dense.array].block : 0;
  LTB_ASSIGN_OR_RETURN(const MemoryPlan mem, PlanMemory(o, n, d, p, kind_block));
  Params pr;
  pr.k = k;
  pr.s = s;
  pr.p = p;
  pr.n_rows = n;
  pr.d = d;
  pr.sample_rows = std::min({n, o.sample_rows, (o.mem_limit - mem.fixed) / mem.per_sample_row});
  pr.sample_rows = std::max(pr.sample_rows, mem.min_sample);
  pr.levels = cpca_internal::Levels(s, o.growth_step);
  if (dense.on) {
    pr.dense_first = true;
    pr.n_dense = dense.dense;
    pr.kind_array = dense.array;
    pr.final_iterations = o.final_iterations;
    pr.sample_rows = std::min(pr.sample_rows, pr.n_dense);  // the sample is of dense rows
  }

  // The mode is part of the run's identity through these parameters (a plain run's are
  // those of builds before dense-first, so their outputs and checkpoints stay valid).
  nlohmann::json params = {{"clusters", k},
                           {"basis", s},
                           {"growth_step", o.growth_step},
                           {"level_iterations", o.level_iterations},
                           {"max_iterations", o.max_iterations},
                           {"tolerance", o.tolerance},
                           {"oversample", o.oversample},
                           {"sample_rows", pr.sample_rows},
                           {"seed", o.seed}};
  if (dense.on) {
    params["dense_first"] = true;
    params["final_iterations"] = o.final_iterations;
  }
  const nlohmann::json provenance = Provenance("cpca", params, {&in});
  const std::string cp_path = CpcaCheckpointPath(o.output);

  CpcaResult result;
  result.rows = n;
  result.dims = d;
  result.clusters = k;
  result.basis = s;
  result.memory_bytes = PlanPasses(o, mem, pr.n_dense, &pr);
  result.dense_first = dense.on;
  result.dense_rows = dense.on ? dense.dense : 0;
  result.dense_cache_bytes = pr.dense_cache ? pr.n_dense * (d * 4 + 8) : 0;
  result.dense_cache_sample = pr.sample_from_cache;

  // One writer per output, before the output or its checkpoint is touched (held to the end;
  // the container writer shares it).
  LTB_ASSIGN_OR_RETURN(io::FileLock output_lock, io::LockOutput(o.output));
  LTB_ASSIGN_OR_RETURN(result.already_complete, CheckExistingOutput(o, provenance, cp_path));
  if (result.already_complete) return Summarize(o.output, result);

  const auto t_fit = std::chrono::steady_clock::now();
  CpcaFitter fitter(o, in, pr, progress);
  const nlohmann::json identity = {{"provenance", provenance}, {"k", k}, {"d", d}, {"p", p}, {"s", s}};
  LTB_ASSIGN_OR_RETURN(const FitOutcome fit, fitter.Fit(cp_path, identity));
  result.resumed = fit.resumed;
  LTB_RETURN_IF_ERROR(WriteOutput(o, in, pr, provenance, fitter, fit, progress, &result));
  std::remove(cp_path.c_str());
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  const double before_fit = std::chrono::duration<double>(t_fit - t0).count();
  result.seconds_dense = before_fit + fit.seconds_dense;
  result.seconds_final = std::max(0.0, seconds - result.seconds_dense);
  return Summarize(o.output, result);
}

}  // namespace ltb::stages
