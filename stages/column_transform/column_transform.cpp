#include "stages/column_transform/column_transform.h"

#include <algorithm>
#include <atomic>
#include <cctype>
#include <cmath>
#include <cstring>
#include <deque>
#include <memory>
#include <mutex>

#include "format/io/container_reader.h"
#include "format/io/container_writer.h"
#include "stages/column_transform/budget_solver.h"
#include "stages/column_transform/column_compressor.h"
#include "stages/common/basis.h"
#include "stages/common/parallel_for.h"
#include "stages/common/quantity.h"
#include "stages/common/thread_zeros.h"

namespace ltb::stages {

using namespace ltb::format;

Result<DepthMode> ParseDepthMode(const std::string& text) {
  DepthMode m;
  if (text == "adaptive") return m;
  if (text == "none") {
    m.kind = DepthMode::Kind::kNone;
    return m;
  }
  if (text == "full") {
    m.kind = DepthMode::Kind::kFull;
    return m;
  }
  if (!text.empty() && text.size() <= 3 && std::all_of(text.begin(), text.end(), ::isdigit)) {
    m.kind = DepthMode::Kind::kFixed;
    m.fixed = std::stoi(text);
    return m;
  }
  return InvalidArgument("--depth \"" + text + "\": expected adaptive, none, full or a depth 0, 1, 2, ...");
}

std::string DepthModeName(const DepthMode& m) {
  switch (m.kind) {
    case DepthMode::Kind::kAdaptive:
      return "adaptive";
    case DepthMode::Kind::kNone:
      return "none";
    case DepthMode::Kind::kFull:
      return "full";
    case DepthMode::Kind::kFixed:
      return std::to_string(m.fixed);
  }
  return "?";
}

namespace {

constexpr const char* kDepthArray = "depth";
constexpr const char* kStatsArray = "column_stats";
constexpr uint64_t kStatsPerColumn = 3;  // energy, error, nonzeros

}  // namespace

uint64_t OutputBlockColumns(uint64_t rows, uint64_t cols, uint64_t nshards) {
  uint64_t block = std::max<uint64_t>(1, kTargetChunkBytes / (std::max<uint64_t>(rows, 1) * 4));
  if (nshards > 1) block = std::min(block, std::max<uint64_t>(1, (cols + 4 * nshards - 1) / (4 * nshards)));
  return std::max<uint64_t>(1, std::min(block, cols));
}

namespace {

// The column images, the depth range, the output chunking and the jobs that fit.
struct Plan {
  uint64_t width = 0, height = 0;
  int min_depth = 0, max_depth = 0;
  uint64_t block = 0;
  uint64_t pixels = 0;  // rows of the matrix: width · height
  int jobs = 0;
};

// How the columns' coefficients are selected.
struct SelectionPlan {
  nlohmann::json selection;  // metadata "column_transform.selection"
  uint64_t terms = 0;        // --terms / --keep: per column
  uint64_t budget = 0;       // --budget: for the matrix
  bool global = false;       // --budget / --target-error: one threshold for the matrix
};

// The output's metadata and where its side tables are.
struct OutputLayout {
  nlohmann::json meta;
  uint32_t depth_array = 0, stats_array = 0;
  std::vector<uint32_t> row_tables;  // the input arrays kept, output arrays 1, 2, ...
};

// The input: the output of `transpose` (column blocks, complete f32), not yet transformed.
Result<io::ContainerReader> OpenInput(const ColumnTransformOptions& o) {
  LTB_ASSIGN_OR_RETURN(io::ContainerReader in, io::ContainerReader::Open(o.input));
  LTB_RETURN_IF_ERROR(RefuseCpcaOutput(in, "column-transform"));
  const Metadata& meta = in.metadata();
  const ArraySpec& a = meta.matrix();
  if (meta.json.contains("column_transform")) {
    return FailedPrecondition(o.input +
                              ": is already column-transformed (by `ltbake column-transform`); its input "
                              "is the output of `ltbake transpose`");
  }
  if (a.layout != Layout::kCols) {
    return FailedPrecondition(o.input +
                              ": is stored in row blocks; column-transform needs column blocks — run "
                              "`ltbake transpose " +
                              o.input + " -o cols.ltm` first");
  }
  LTB_RETURN_IF_ERROR(RequireCompleteF32Matrix(in));
  return in;
}

// The column image (width × height) and the depth range of --depth.
Status PlanImage(const ColumnTransformOptions& o, const Metadata& meta, Plan* plan) {
  const ArraySpec& a = meta.matrix();
  auto image = ReadImageRows(meta);
  if (image) {
    plan->width = image->width;
    plan->height = image->height;
  } else if (o.depth.kind == DepthMode::Kind::kNone) {
    plan->width = a.rows;
    plan->height = 1;
  } else {
    std::string rows_kind = meta.json.value("basis", nlohmann::json::object())
                                .value("rows", nlohmann::json::object())
                                .value("kind", std::string("generic"));
    return FailedPrecondition(
        o.input + ": its rows are " +
        (rows_kind == "vertices" ? "mesh vertices" : "not declared an image (" + rows_kind + ")") +
        ", so its columns have no 2D image domain to transform; use `--depth none` (the 2D method), or compress it "
        "with `ltbake cpca`");
  }
  const int deepest = wavelet::MaxDepth(plan->width, plan->height);
  switch (o.depth.kind) {
    case DepthMode::Kind::kAdaptive:
      plan->max_depth = deepest;
      break;
    case DepthMode::Kind::kNone:
      break;
    case DepthMode::Kind::kFull:
      plan->min_depth = plan->max_depth = deepest;
      break;
    case DepthMode::Kind::kFixed:
      if (o.depth.fixed > deepest) {
        return InvalidArgument("--depth " + std::to_string(o.depth.fixed) + ": a " + std::to_string(plan->width) + "x" +
                               std::to_string(plan->height) + " image has at most " + std::to_string(deepest) +
                               " steps");
      }
      plan->min_depth = plan->max_depth = o.depth.fixed;
      break;
  }
  if (plan->max_depth > 0) {
    Status s = wavelet::CheckSize(o.filter, plan->width, plan->height);
    if (!s.ok()) return s.WithContext(o.input + ": column images");
  }
  if (plan->width * plan->height > UINT32_MAX) {
    return InvalidArgument(o.input + ": columns of " + std::to_string(a.rows) + " rows exceed 2^32 coefficients");
  }
  return Status::Ok();
}

// Columns per output chunk, and the jobs that fit in --mem-limit.
Status PlanChunks(const ColumnTransformOptions& o, const ArraySpec& a, Plan* plan) {
  plan->block =
      o.block_cols ? std::min<uint64_t>(o.block_cols, a.cols) : OutputBlockColumns(a.rows, a.cols, o.shard.count);
  const uint64_t pixels = plan->pixels = a.rows;
  const bool ortho = wavelet::IsOrthonormal(o.filter);
  if (plan->block > kMaxSparseElements / pixels) {  // (block · pixels could overflow)
    return InvalidArgument("--block-cols " + std::to_string(plan->block) + ": a chunk of " +
                           std::to_string(plan->block) + " columns of " + std::to_string(pixels) +
                           " rows is over the 2^32 elements of a sparse "
                           "chunk; use at most " +
                           std::to_string(kMaxSparseElements / pixels));
  }

  // Memory: each job holds a compressor, one input chunk (and the columns of one lane
  // group from earlier chunks), and the output chunk dense and encoded (at most as large).
  const uint64_t per_job = ColumnCompressor::WorkingBytes(plan->width, plan->height, plan->max_depth, ortho) +
                           (a.block + ColumnCompressor::kLanes) * pixels * 4 + 2 * plan->block * pixels * 4;
  int jobs = std::max(1, o.jobs);
  if (per_job > o.mem_limit) {
    return FailedPrecondition("column-transform needs " + std::to_string(per_job >> 20) + " MiB per job for " +
                              std::to_string(plan->block) + " columns of " + std::to_string(plan->width) + "x" +
                              std::to_string(plan->height) + " per output chunk, over --mem-limit " +
                              std::to_string(o.mem_limit >> 20) + " MiB; raise --mem-limit" +
                              (plan->block > 1 ? " or lower --block-cols" : ""));
  }
  plan->jobs = static_cast<int>(std::min<uint64_t>(jobs, o.mem_limit / per_job));
  return Status::Ok();
}

// Selection parameters and metadata.
Result<SelectionPlan> PlanSelection(const ColumnTransformOptions& o, const ArraySpec& a) {
  const uint64_t pixels = a.rows;
  SelectionPlan sel;
  switch (o.terms.kind) {
    case TermsMode::Kind::kTerms:
      if (o.terms.terms == 0) return InvalidArgument("--terms must be at least 1");
      sel.terms = o.terms.terms;
      sel.selection = {{"terms", sel.terms}};
      break;
    case TermsMode::Kind::kKeep:
      if (!(o.terms.keep > 0 && o.terms.keep <= 1)) {
        return InvalidArgument("--keep " + std::to_string(o.terms.keep) + ": expected a fraction in (0, 1]");
      }
      sel.terms = std::max<uint64_t>(1, static_cast<uint64_t>(std::ceil(o.terms.keep * static_cast<double>(pixels))));
      sel.selection = {{"keep", o.terms.keep}, {"terms", sel.terms}};
      break;
    case TermsMode::Kind::kBudget: {
      auto parsed = ParseBudget(o.terms.budget);
      if (!parsed.ok()) return parsed.status().WithContext("--budget");
      sel.budget = BudgetNonzeros(*parsed, a.rows, a.cols);
      sel.selection = {{"budget", sel.budget}};
      break;
    }
    case TermsMode::Kind::kTargetError:
      if (!(o.terms.target_error > 0 && o.terms.target_error < 1)) {
        return InvalidArgument("--target-error " + std::to_string(o.terms.target_error) +
                               ": expected a relative RMS error in (0, 1), e.g. 0.02 or 2%");
      }
      sel.selection = {{"target_error", o.terms.target_error}};
      break;
  }
  sel.global = o.terms.kind == TermsMode::Kind::kBudget || o.terms.kind == TermsMode::Kind::kTargetError;
  return sel;
}

// The output's metadata (docs/COLUMN-TRANSFORM.md): the matrix in column groups of
// plan.block, the row side tables passed through, the per-column "depth" and
// "column_stats" tables chunked like the matrix, and "column_transform" (what
// ColumnCodec::FromMetadata and SummarizeColumnTransform read back).
Result<OutputLayout> OutputMetadata(const ColumnTransformOptions& o, const io::ContainerReader& in, const Plan& plan,
                                    const SelectionPlan& sel) {
  const Metadata& meta = in.metadata();
  const ArraySpec& a = meta.matrix();
  OutputLayout out;
  nlohmann::json& out_meta = out.meta;
  out_meta = meta.json;
  ArraySpec out_spec = a;
  out_spec.block = plan.block;
  out_meta["arrays"] = nlohmann::json::array({out_spec.ToJson()});
  nlohmann::json dropped = nlohmann::json::array();
  for (uint32_t arr = 1; arr < meta.arrays.size(); ++arr) {
    if (!KeptByCompressedOutputs(meta.arrays[arr].name)) {
      dropped.push_back(meta.arrays[arr].name);
      continue;
    }
    out.row_tables.push_back(arr);
    out_meta["arrays"].push_back(PassThroughSpec(meta.arrays[arr]).ToJson());
  }
  ArraySpec depth_spec;
  depth_spec.name = kDepthArray;
  depth_spec.dtype = DType::kU8;
  depth_spec.rows = a.cols;
  depth_spec.cols = 1;
  depth_spec.layout = Layout::kRows;
  depth_spec.block = plan.block;
  ArraySpec stats_spec = depth_spec;
  stats_spec.name = kStatsArray;
  stats_spec.dtype = DType::kF64;
  stats_spec.cols = kStatsPerColumn;
  if (meta.FindArray(kDepthArray) >= 0 || meta.FindArray(kStatsArray) >= 0) {
    return FailedPrecondition(o.input + ": already has a \"depth\" or \"column_stats\" array");
  }
  out.depth_array = static_cast<uint32_t>(out_meta["arrays"].size());
  out.stats_array = out.depth_array + 1;
  out_meta["arrays"].push_back(depth_spec.ToJson());
  out_meta["arrays"].push_back(stats_spec.ToJson());
  out_meta["basis"]["rows"]["coefficients"] = "column_transform";
  out_meta["column_transform"] = {{"filter", wavelet::FilterName(o.filter)},
                                  {"depth", DepthModeName(o.depth)},
                                  {"min_depth", plan.min_depth},
                                  {"max_depth", plan.max_depth},
                                  {"image", {{"width", plan.width}, {"height", plan.height}}},
                                  {"layout", "mallat"},
                                  {"selection", sel.selection},
                                  {"depth_array", kDepthArray},
                                  {"stats_array", kStatsArray}};
  if (!dropped.empty()) out_meta["column_transform"]["row_tables_dropped"] = dropped;
  out_meta["provenance"] = Provenance("column-transform",
                                      {{"filter", wavelet::FilterName(o.filter)},
                                       {"depth", DepthModeName(o.depth)},
                                       {"selection", sel.selection},
                                       {"zstd", o.zstd}},
                                      {&in});
  return out;
}

// Output chunks missing from any of the matrix and its two side tables (each chunk is
// computed once and writes the arrays it lacks).
std::vector<uint64_t> MissingChunks(const io::ContainerWriter& out, const OutputLayout& layout) {
  std::vector<uint64_t> m0 = out.Missing(0), m1 = out.Missing(layout.depth_array), m2 = out.Missing(layout.stats_array);
  std::vector<uint64_t> items = m0;
  items.insert(items.end(), m1.begin(), m1.end());
  items.insert(items.end(), m2.begin(), m2.end());
  std::sort(items.begin(), items.end());
  items.erase(std::unique(items.begin(), items.end()), items.end());
  return items;
}

Result<ColumnCompressor> MakeCompressor(wavelet::Filter filter, const Plan& plan) {
  return ColumnCompressor::Create(filter, plan.width, plan.height, plan.min_depth, plan.max_depth);
}

// One compressor per worker thread, reused across chunks (and across runs in one process
// while the plan is the same).
Result<ColumnCompressor*> ThreadCompressor(wavelet::Filter filter, const Plan& plan) {
  thread_local std::unique_ptr<ColumnCompressor> comp;
  if (!comp || comp->filter() != filter || comp->width() != plan.width || comp->height() != plan.height ||
      comp->max_depth() != plan.max_depth || comp->min_depth() != plan.min_depth) {
    LTB_ASSIGN_OR_RETURN(ColumnCompressor cc, MakeCompressor(filter, plan));
    comp = std::make_unique<ColumnCompressor>(std::move(cc));
  }
  return comp.get();
}

// Budget: first pass over every column (the allocation is global), then a bisection on
// the threshold bin (BudgetSolver); each column's depth follows from it. Fills the
// result's budget, estimated_error, lambda and histogram_bytes.
Result<BudgetAllocation> SolveBudget(const ColumnTransformOptions& o, const io::ContainerReader& in, const Plan& plan,
                                     const SelectionPlan& sel, const Progress& progress,
                                     ColumnTransformResult* result) {
  const ArraySpec& a = in.metadata().matrix();
  const uint64_t pixels = plan.pixels;
  BudgetSolver solver(a.cols);
  std::atomic<uint64_t> hist_bytes{0};
  std::vector<uint64_t> all_chunks(a.ChunkCount());
  for (uint64_t i = 0; i < all_chunks.size(); ++i) all_chunks[i] = i;
  Progress pass1 = progress;
  Status s = ParallelFor(all_chunks, plan.jobs, pass1, "chunks (budget pass)", [&](uint64_t c) -> Status {
    LTB_ASSIGN_OR_RETURN(ColumnCompressor * comp, ThreadCompressor(o.filter, plan));
    LTB_ASSIGN_OR_RETURN(io::Chunk chunk, in.ReadChunk(0, c));
    const ChunkExtent e = chunk.extent();
    auto values = chunk.as<float>();
    const int depths = comp->depths();
    std::vector<EnergyHistogram> h(ColumnCompressor::kLanes * depths);
    for (uint64_t k0 = 0; k0 < e.cols; k0 += ColumnCompressor::kLanes) {
      size_t n = std::min<uint64_t>(ColumnCompressor::kLanes, e.cols - k0);
      const float* cols[ColumnCompressor::kLanes];
      for (size_t k = 0; k < n; ++k) cols[k] = values.data() + (k0 + k) * pixels;
      double energy[ColumnCompressor::kLanes];
      Status hs = comp->Histograms(cols, n, h.data(), energy);
      if (!hs.ok()) return hs.WithContext(o.input + ": column " + std::to_string(e.col0 + k0));
      for (size_t k = 0; k < n; ++k) {
        uint64_t bytes = solver.AddColumn(e.col0 + k0 + k, h.data() + k * depths, depths);
        if (hist_bytes.fetch_add(bytes) + bytes > o.mem_limit / 2) {
          return FailedPrecondition("the --budget search needs more than half of --mem-limit (" +
                                    std::to_string(o.mem_limit >> 20) +
                                    " MiB) for its per-column energy histograms; raise --mem-limit or use "
                                    "--terms / --keep");
        }
      }
    }
    return Status::Ok();
  });
  LTB_RETURN_IF_ERROR(s);
  result->histogram_bytes = hist_bytes;
  BudgetAllocation alloc = o.terms.kind == TermsMode::Kind::kTargetError
                               ? solver.ForTargetError(o.terms.target_error, plan.min_depth)
                               : solver.ForBudget(sel.budget, plan.min_depth);
  result->budget = alloc.budget;
  result->estimated_error = alloc.estimated_error;
  result->lambda = alloc.lambda;
  return alloc;
}

// What every output chunk of the second pass reads and writes.
struct ChunkJob {
  const ColumnTransformOptions& o;
  const io::ContainerReader& in;
  io::ContainerWriter& out;
  const Plan& plan;
  const OutputLayout& layout;
  const SelectionPlan& sel;
  const BudgetAllocation& alloc;  // empty (no depths) without a global selection
  EncodeOptions matrix_encoding;  // sparse f32
  EncodeOptions side_encoding;    // depth and column_stats: zstd where it saves
};

// One output chunk of columns: its matrix chunk (dense, encoded sparse), and its rows of
// the depth and column_stats tables, each written unless already committed.
Status PutColumnGroup(const ChunkJob& job, uint64_t c, std::span<const float> dense, const std::vector<uint8_t>& depths,
                      const std::vector<double>& stats) {
  if (!job.out.Has(0, c)) {
    LTB_RETURN_IF_ERROR(job.out.Put(0, c, BytesOf(dense), job.matrix_encoding));
  }
  if (!job.out.Has(job.layout.depth_array, c)) {
    LTB_RETURN_IF_ERROR(job.out.Put(job.layout.depth_array, c, BytesOf(depths), job.side_encoding));
  }
  if (!job.out.Has(job.layout.stats_array, c)) {
    LTB_RETURN_IF_ERROR(job.out.Put(job.layout.stats_array, c, BytesOf(stats), job.side_encoding));
  }
  return Status::Ok();
}

// Output chunk c: columns [col0, col0 + ncols), read from the input chunks over them, each
// column transformed to its depth and its selected coefficients kept. Columns go to the
// compressor eight at a time whatever the input chunking (large columns come one per
// input chunk): a group may span input chunks of fewer than eight columns, which stay
// alive until it is done.
Status TransformChunk(const ChunkJob& job, uint64_t c) {
  constexpr size_t kLanes = ColumnCompressor::kLanes;
  const ArraySpec& a = job.in.metadata().matrix();
  const Plan& plan = job.plan;
  const uint64_t pixels = plan.pixels;
  LTB_ASSIGN_OR_RETURN(ColumnCompressor * comp, ThreadCompressor(job.o.filter, plan));
  const uint64_t col0 = c * plan.block, ncols = std::min(plan.block, a.cols - col0);
  // The dense output chunk, in this thread's reused buffer; the positions written are
  // cleared after it is put, on every path out.
  const std::span<float> dense = ThreadZeros<float>(ncols * pixels);
  std::vector<uint64_t> written;
  const ClearOnExit clear(dense, written);
  std::vector<uint8_t> depths(ncols, 0);
  std::vector<double> stats(ncols * kStatsPerColumn, 0.0);
  ColumnChoice choice[kLanes];
  Selection sel[kLanes];
  int override_depth[kLanes];
  const float* cols[kLanes];
  uint64_t first_j = 0;  // matrix column of cols[0]
  size_t pending = 0;
  std::deque<io::Chunk> held;  // input chunks the pending columns point into
  auto flush = [&]() -> Status {
    for (size_t k = 0; k < pending; ++k) {
      const uint64_t j = first_j + k;
      if (job.alloc.depth.empty()) {
        sel[k].kind = Selection::Kind::kTerms;
        sel[k].terms = job.sel.terms;
        override_depth[k] = -1;
      } else {
        sel[k].kind = Selection::Kind::kThreshold;
        sel[k].threshold_bin = job.alloc.threshold_bin;
        sel[k].terms = job.alloc.extra[j];
        override_depth[k] = job.alloc.depth[j];
      }
    }
    Status cs = comp->Choose(cols, pending, sel, override_depth, choice);
    if (!cs.ok()) return cs.WithContext(job.o.input + ": column " + std::to_string(first_j));
    for (size_t k = 0; k < pending; ++k) {
      const uint64_t m = first_j + k - col0;  // column within the output chunk
      float* out_col = dense.data() + m * pixels;
      for (size_t i = 0; i < choice[k].index.size(); ++i) {
        out_col[choice[k].index[i]] = choice[k].value[i];
        written.push_back(m * pixels + choice[k].index[i]);
      }
      depths[m] = static_cast<uint8_t>(choice[k].depth);
      stats[m * kStatsPerColumn + 0] = choice[k].energy;
      stats[m * kStatsPerColumn + 1] = choice[k].error;
      stats[m * kStatsPerColumn + 2] = static_cast<double>(choice[k].index.size());
    }
    pending = 0;
    while (held.size() > 1) held.pop_front();  // the current chunk may hold the next group
    return Status::Ok();
  };
  for (uint64_t ic = col0 / a.block; ic * a.block < col0 + ncols; ++ic) {
    // Input chunks of a lane group or more finish their groups (memory: one such chunk).
    if (a.block >= kLanes && pending > 0) LTB_RETURN_IF_ERROR(flush());
    LTB_ASSIGN_OR_RETURN(io::Chunk chunk, job.in.ReadChunk(0, ic));
    held.push_back(std::move(chunk));
    const ChunkExtent e = held.back().extent();
    auto values = held.back().as<float>();
    const uint64_t j0 = std::max(e.col0, col0), j1 = std::min(e.col0 + e.cols, col0 + ncols);
    for (uint64_t j = j0; j < j1; ++j) {
      if (pending == 0) first_j = j;
      cols[pending++] = values.data() + (j - e.col0) * pixels;
      if (pending == kLanes) LTB_RETURN_IF_ERROR(flush());
    }
  }
  if (pending > 0) LTB_RETURN_IF_ERROR(flush());
  return PutColumnGroup(job, c, dense, depths, stats);
}

}  // namespace

Result<ColumnTransformResult> RunColumnTransform(const ColumnTransformOptions& o, const Progress& progress) {
  LTB_ASSIGN_OR_RETURN(io::ContainerReader in, OpenInput(o));
  const Metadata& meta = in.metadata();
  const ArraySpec& a = meta.matrix();
  Plan plan;
  LTB_RETURN_IF_ERROR(PlanImage(o, meta, &plan));
  LTB_RETURN_IF_ERROR(PlanChunks(o, a, &plan));
  LTB_ASSIGN_OR_RETURN(SelectionPlan sel, PlanSelection(o, a));
  LTB_ASSIGN_OR_RETURN(OutputLayout layout, OutputMetadata(o, in, plan, sel));
  io::WriterOptions wo;
  wo.overwrite_mismatch = o.overwrite;
  LTB_ASSIGN_OR_RETURN(io::ContainerWriter out, io::OpenStageOutput(o.output, layout.meta, wo, o.shard));

  ColumnTransformResult result;
  result.rows = a.rows;
  result.cols = a.cols;
  result.width = plan.width;
  result.height = plan.height;
  result.min_depth = plan.min_depth;
  result.max_depth = plan.max_depth;
  result.jobs_used = plan.jobs;
  result.budget = sel.budget;
  for (const ArraySpec& s : out.metadata().arrays) result.chunks_total += s.ChunkCount();
  result.chunks_already_committed = out.resume_info().committed_chunks;

  // Row side tables pass through, in few chunks.
  for (uint32_t k = 0; k < layout.row_tables.size(); ++k) {
    LTB_RETURN_IF_ERROR(CopyArray(in, layout.row_tables[k], out, k + 1, &result.chunks_written));
  }
  const std::vector<uint64_t> items = MissingChunks(out, layout);
  LTB_RETURN_IF_ERROR(MakeCompressor(o.filter, plan).status());

  BudgetAllocation alloc;  // stays empty without a global selection (or with nothing to do)
  if (sel.global && !items.empty()) {
    LTB_ASSIGN_OR_RETURN(alloc, SolveBudget(o, in, plan, sel, progress, &result));
  }

  ChunkJob job{.o = o, .in = in, .out = out, .plan = plan, .layout = layout, .sel = sel, .alloc = alloc};
  job.matrix_encoding.zstd = o.zstd;
  job.matrix_encoding.sparse = true;
  job.matrix_encoding.dtype = DType::kF32;
  job.side_encoding.zstd = true;
  std::atomic<uint64_t> written{0};
  Status s = ParallelFor(items, plan.jobs, progress, "chunks", [&](uint64_t c) -> Status {
    LTB_RETURN_IF_ERROR(TransformChunk(job, c));
    written++;
    return Status::Ok();
  });
  result.chunks_written += written;
  LTB_RETURN_IF_ERROR(s);
  LTB_RETURN_IF_ERROR(out.Finish());

  LTB_ASSIGN_OR_RETURN(ColumnTransformResult totals, SummarizeColumnTransform(out.path()));
  result.empty_columns = totals.empty_columns;
  result.nonzeros = totals.nonzeros;
  result.energy = totals.energy;
  result.error = totals.error;
  result.depth_histogram = totals.depth_histogram;
  return result;
}

namespace {

// A quantize output's column totals: its input's, recorded in "column_transform.totals"
// (the per-column column_stats are not carried past quantize).
Result<ColumnTransformResult> TotalsFromMetadata(const std::string& path, const Metadata& meta) {
  const auto& ct = meta.json["column_transform"];
  const auto& t = ct["totals"];
  auto bad = [&](const std::string& what) { return DataLoss(path + ": column_transform.totals: " + what); };
  if (!t.is_object()) return bad("not an object");
  ColumnTransformResult r;
  r.rows = meta.matrix().rows;
  r.cols = meta.matrix().cols;
  r.min_depth = ct.value("min_depth", 0);
  r.max_depth = ct.value("max_depth", 0);
  for (const char* k : {"energy", "error"})
    if (!t.value(k, nlohmann::json()).is_number() || !(t[k].get<double>() >= 0))
      return bad(std::string(k) + " missing or negative");
  for (const char* k : {"nonzeros", "empty_columns"})
    if (!t.value(k, nlohmann::json()).is_number_unsigned()) return bad(std::string(k) + " missing");
  r.energy = t["energy"].get<double>();
  r.error = t["error"].get<double>();
  r.nonzeros = t["nonzeros"].get<uint64_t>();
  r.empty_columns = t["empty_columns"].get<uint64_t>();
  const auto& h = t.value("depth_histogram", nlohmann::json());
  if (!h.is_array() || h.size() > 65) return bad("depth_histogram missing");
  for (const auto& v : h) {
    if (!v.is_number_unsigned()) return bad("depth_histogram holds " + v.dump());
    r.depth_histogram.push_back(v.get<uint64_t>());
  }
  return r;
}

}  // namespace

Result<ColumnTransformResult> SummarizeColumnTransform(const std::string& path) {
  LTB_ASSIGN_OR_RETURN(io::ContainerReader r, io::ContainerReader::Open(path));
  const Metadata& meta = r.metadata();
  if (!meta.json.contains("column_transform") || !meta.json["column_transform"].is_object()) {
    return FailedPrecondition(path + ": is not a column-transform output");
  }
  const auto& ct = meta.json["column_transform"];
  if (!ct.contains("stats_array") && ct.contains("totals")) return TotalsFromMetadata(path, meta);
  int depth_array = meta.FindArray(ct.value("depth_array", kDepthArray));
  int stats_array = meta.FindArray(ct.value("stats_array", kStatsArray));
  if (depth_array < 0 || stats_array < 0) return DataLoss(path + ": column_transform names arrays that are missing");
  const ArraySpec& ds = meta.arrays[depth_array];
  const ArraySpec& ss = meta.arrays[stats_array];
  if (ds.dtype != DType::kU8 || ss.dtype != DType::kF64 || ss.cols != kStatsPerColumn ||
      ds.rows != meta.matrix().cols || ss.rows != meta.matrix().cols) {
    return DataLoss(path + ": depth / column_stats arrays have unexpected shapes");
  }
  ColumnTransformResult t;
  t.rows = meta.matrix().rows;
  t.cols = meta.matrix().cols;
  t.min_depth = ct.value("min_depth", 0);
  t.max_depth = ct.value("max_depth", 0);
  if (t.max_depth < 0 || t.max_depth > 64) return DataLoss(path + ": max_depth " + std::to_string(t.max_depth));
  t.depth_histogram.assign(t.max_depth + 1, 0);
  for (uint64_t c = 0; c < ds.ChunkCount(); ++c) {
    if (!meta.Owns(depth_array, c)) continue;  // a shard file: its own columns
    LTB_ASSIGN_OR_RETURN(io::Chunk dc, r.ReadChunk(depth_array, c));
    LTB_ASSIGN_OR_RETURN(io::Chunk sc, r.ReadChunk(stats_array, c));
    auto d = dc.as<uint8_t>();
    auto st = sc.as<double>();
    for (size_t k = 0; k < d.size(); ++k) {
      double energy = st[k * kStatsPerColumn], error = st[k * kStatsPerColumn + 1], nnz = st[k * kStatsPerColumn + 2];
      t.energy += energy;
      t.error += error;
      t.nonzeros += static_cast<uint64_t>(nnz);
      if (energy == 0) {
        t.empty_columns++;
      } else if (d[k] <= t.max_depth) {
        t.depth_histogram[d[k]]++;
      } else {
        return DataLoss(path + ": column " + std::to_string(c * ds.block + k) + " has depth " + std::to_string(d[k]) +
                        ", over max_depth " + std::to_string(t.max_depth));
      }
    }
  }
  return t;
}

}  // namespace ltb::stages
