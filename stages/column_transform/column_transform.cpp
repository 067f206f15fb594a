#include "stages/column_transform/column_transform.h"

#include <algorithm>
#include <atomic>
#include <cctype>
#include <cmath>
#include <cstring>
#include <mutex>

#include "format/io/container_reader.h"
#include "format/io/container_writer.h"
#include "stages/column_transform/column_compressor.h"
#include "stages/common/basis.h"
#include "stages/common/parallel_for.h"
#include "stages/common/quantity.h"

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

// Per-column energy histograms of every depth, for the budget search (compact: one set of
// flat vectors per column).
struct ColumnCurves {
  std::vector<uint32_t> offset;             // depths + 1 entries into the flat vectors
  std::vector<int32_t> bin;                 // ascending within a depth
  std::vector<uint64_t> count_at_or_above;  // Σ counts of bins >= this one
  std::vector<double> energy_below;         // Σ energy of bins < this one
  std::vector<double> depth_total;          // Σ energy of all bins, per depth
};

// Cost of column c at depth d for threshold bin g: dropped energy + λ · kept count.
struct Point {
  double cost;
  uint64_t count;
};
Point Evaluate(const ColumnCurves& cc, int d, int g, double lambda) {
  uint32_t a = cc.offset[d], b = cc.offset[d + 1];
  auto first = std::lower_bound(cc.bin.begin() + a, cc.bin.begin() + b, g) - cc.bin.begin();
  if (static_cast<uint32_t>(first) == b) return {cc.depth_total[d], 0};
  return {cc.energy_below[first] + lambda * static_cast<double>(cc.count_at_or_above[first]),
          cc.count_at_or_above[first]};
}

// The depth a column picks at threshold bin g (least cost; then fewer terms; then shallower).
int PickDepth(const ColumnCurves& cc, int g, double lambda, uint64_t* count) {
  int best = -1;
  Point bp{0, 0};
  for (int d = 0; d + 1 < static_cast<int>(cc.offset.size()); ++d) {
    Point p = Evaluate(cc, d, g, lambda);
    if (best < 0 || p.cost < bp.cost || (p.cost == bp.cost && p.count < bp.count)) {
      best = d;
      bp = p;
    }
  }
  *count = bp.count;
  return best;
}

}  // namespace

uint64_t OutputBlockColumns(uint64_t rows, uint64_t cols, uint64_t nshards) {
  uint64_t block = std::max<uint64_t>(1, kTargetChunkBytes / (std::max<uint64_t>(rows, 1) * 4));
  if (nshards > 1) block = std::min(block, std::max<uint64_t>(1, (cols + 4 * nshards - 1) / (4 * nshards)));
  return std::max<uint64_t>(1, std::min(block, cols));
}

namespace {

struct Plan {
  uint64_t width = 0, height = 0;
  int min_depth = 0, max_depth = 0;
  uint64_t block = 0;
};

}  // namespace

Result<ColumnTransformResult> RunColumnTransform(const ColumnTransformOptions& o, const Progress& progress) {
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

  Plan plan;
  auto image = ReadImageRows(meta);
  if (image) {
    plan.width = image->width;
    plan.height = image->height;
  } else if (o.depth.kind == DepthMode::Kind::kNone) {
    plan.width = a.rows;
    plan.height = 1;
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
  const int deepest = wavelet::MaxDepth(plan.width, plan.height);
  switch (o.depth.kind) {
    case DepthMode::Kind::kAdaptive:
      plan.max_depth = deepest;
      break;
    case DepthMode::Kind::kNone:
      break;
    case DepthMode::Kind::kFull:
      plan.min_depth = plan.max_depth = deepest;
      break;
    case DepthMode::Kind::kFixed:
      if (o.depth.fixed > deepest) {
        return InvalidArgument("--depth " + std::to_string(o.depth.fixed) + ": a " + std::to_string(plan.width) + "x" +
                               std::to_string(plan.height) + " image has at most " + std::to_string(deepest) +
                               " steps");
      }
      plan.min_depth = plan.max_depth = o.depth.fixed;
      break;
  }
  if (plan.max_depth > 0) {
    Status s = wavelet::CheckSize(o.filter, plan.width, plan.height);
    if (!s.ok()) return s.WithContext(o.input + ": column images");
  }
  if (plan.width * plan.height > UINT32_MAX) {
    return InvalidArgument(o.input + ": columns of " + std::to_string(a.rows) + " rows exceed 2^32 coefficients");
  }
  plan.block =
      o.block_cols ? std::min<uint64_t>(o.block_cols, a.cols) : OutputBlockColumns(a.rows, a.cols, o.shard.count);
  const uint64_t pixels = a.rows;
  const bool ortho = wavelet::IsOrthonormal(o.filter);
  if (plan.block > kMaxSparseElements / pixels) {  // (block · pixels could overflow)
    return InvalidArgument("--block-cols " + std::to_string(plan.block) + ": a chunk of " + std::to_string(plan.block) +
                           " columns of " + std::to_string(pixels) +
                           " rows is over the 2^32 elements of a sparse "
                           "chunk; use at most " +
                           std::to_string(kMaxSparseElements / pixels));
  }

  // Memory: each job holds a compressor, one input chunk, and the output chunk dense and
  // encoded (at most as large).
  const uint64_t per_job = ColumnCompressor::WorkingBytes(plan.width, plan.height, plan.max_depth, ortho) +
                           a.block * pixels * 4 + 2 * plan.block * pixels * 4;
  int jobs = std::max(1, o.jobs);
  if (per_job > o.mem_limit) {
    return FailedPrecondition("column-transform needs " + std::to_string(per_job >> 20) + " MiB per job for " +
                              std::to_string(plan.block) + " columns of " + std::to_string(plan.width) + "x" +
                              std::to_string(plan.height) + " per output chunk, over --mem-limit " +
                              std::to_string(o.mem_limit >> 20) + " MiB; raise --mem-limit" +
                              (plan.block > 1 ? " or lower --block-cols" : ""));
  }
  jobs = static_cast<int>(std::min<uint64_t>(jobs, o.mem_limit / per_job));

  // Selection parameters and metadata.
  nlohmann::json selection;
  uint64_t terms = 0, budget = 0;
  switch (o.terms.kind) {
    case TermsMode::Kind::kTerms:
      if (o.terms.terms == 0) return InvalidArgument("--terms must be at least 1");
      terms = o.terms.terms;
      selection = {{"terms", terms}};
      break;
    case TermsMode::Kind::kKeep:
      if (!(o.terms.keep > 0 && o.terms.keep <= 1)) {
        return InvalidArgument("--keep " + std::to_string(o.terms.keep) + ": expected a fraction in (0, 1]");
      }
      terms = std::max<uint64_t>(1, static_cast<uint64_t>(std::ceil(o.terms.keep * static_cast<double>(pixels))));
      selection = {{"keep", o.terms.keep}, {"terms", terms}};
      break;
    case TermsMode::Kind::kBudget: {
      auto parsed = ParseBudget(o.terms.budget);
      if (!parsed.ok()) return parsed.status().WithContext("--budget");
      budget = BudgetNonzeros(*parsed, a.rows, a.cols);
      selection = {{"budget", budget}};
      break;
    }
    case TermsMode::Kind::kTargetError:
      if (!(o.terms.target_error > 0 && o.terms.target_error < 1)) {
        return InvalidArgument("--target-error " + std::to_string(o.terms.target_error) +
                               ": expected a relative RMS error in (0, 1), e.g. 0.02 or 2%");
      }
      selection = {{"target_error", o.terms.target_error}};
      break;
  }
  const bool global = o.terms.kind == TermsMode::Kind::kBudget || o.terms.kind == TermsMode::Kind::kTargetError;

  nlohmann::json out_meta = meta.json;
  ArraySpec out_spec = a;
  out_spec.block = plan.block;
  out_meta["arrays"][0] = out_spec.ToJson();
  for (size_t arr = 1; arr < meta.arrays.size(); ++arr)
    out_meta["arrays"][arr] = PassThroughSpec(meta.arrays[arr]).ToJson();
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
  const uint32_t depth_array = static_cast<uint32_t>(meta.arrays.size());
  const uint32_t stats_array = depth_array + 1;
  out_meta["arrays"].push_back(depth_spec.ToJson());
  out_meta["arrays"].push_back(stats_spec.ToJson());
  out_meta["basis"]["rows"]["coefficients"] = "column_transform";
  out_meta["column_transform"] = {{"filter", wavelet::FilterName(o.filter)},
                                  {"depth", DepthModeName(o.depth)},
                                  {"min_depth", plan.min_depth},
                                  {"max_depth", plan.max_depth},
                                  {"image", {{"width", plan.width}, {"height", plan.height}}},
                                  {"layout", "mallat"},
                                  {"selection", selection},
                                  {"depth_array", kDepthArray},
                                  {"stats_array", kStatsArray}};
  out_meta["provenance"] = Provenance("column-transform",
                                      {{"filter", wavelet::FilterName(o.filter)},
                                       {"depth", DepthModeName(o.depth)},
                                       {"selection", selection},
                                       {"zstd", o.zstd}},
                                      {&in});
  io::WriterOptions wo;
  wo.overwrite_mismatch = o.overwrite;
  LTB_ASSIGN_OR_RETURN(io::ContainerWriter out, io::OpenStageOutput(o.output, out_meta, wo, o.shard));

  ColumnTransformResult result;
  result.rows = a.rows;
  result.cols = a.cols;
  result.width = plan.width;
  result.height = plan.height;
  result.min_depth = plan.min_depth;
  result.max_depth = plan.max_depth;
  result.jobs_used = jobs;
  result.budget = budget;
  for (const ArraySpec& s : out.metadata().arrays) result.chunks_total += s.ChunkCount();
  result.chunks_already_committed = out.resume_info().committed_chunks;

  // Row side tables pass through, in few chunks.
  for (uint32_t arr = 1; arr < meta.arrays.size(); ++arr) {
    LTB_RETURN_IF_ERROR(CopyArray(in, arr, out, &result.chunks_written));
  }

  std::vector<uint64_t> items;
  {
    std::vector<uint64_t> m0 = out.Missing(0), m1 = out.Missing(depth_array), m2 = out.Missing(stats_array);
    items = m0;
    items.insert(items.end(), m1.begin(), m1.end());
    items.insert(items.end(), m2.begin(), m2.end());
    std::sort(items.begin(), items.end());
    items.erase(std::unique(items.begin(), items.end()), items.end());
  }

  auto make_compressor = [&]() {
    return ColumnCompressor::Create(o.filter, plan.width, plan.height, plan.min_depth, plan.max_depth);
  };
  LTB_RETURN_IF_ERROR(make_compressor().status());
  // One compressor per worker thread, reused across chunks (and across runs in one process
  // while the plan is the same).
  auto thread_compressor = [&]() -> Result<ColumnCompressor*> {
    thread_local std::unique_ptr<ColumnCompressor> comp;
    if (!comp || comp->filter() != o.filter || comp->width() != plan.width || comp->height() != plan.height ||
        comp->max_depth() != plan.max_depth || comp->min_depth() != plan.min_depth) {
      LTB_ASSIGN_OR_RETURN(ColumnCompressor cc, make_compressor());
      comp = std::make_unique<ColumnCompressor>(std::move(cc));
    }
    return comp.get();
  };

  // Budget: first pass over every column (the allocation is global), then a bisection on
  // the threshold bin; each column's depth follows from it.
  std::vector<int8_t> budget_depth;
  std::vector<uint64_t> budget_extra;  // terms each column takes from the bin below the threshold
  int threshold_bin = 0;
  if (global && !items.empty()) {
    std::vector<ColumnCurves> curves(a.cols);
    std::atomic<uint64_t> hist_bytes{0};
    std::vector<uint64_t> all_chunks(a.ChunkCount());
    for (uint64_t i = 0; i < all_chunks.size(); ++i) all_chunks[i] = i;
    Progress pass1 = progress;
    Status s = ParallelFor(all_chunks, jobs, pass1, "chunks (budget pass)", [&](uint64_t c) -> Status {
      LTB_ASSIGN_OR_RETURN(ColumnCompressor * comp, thread_compressor());
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
          ColumnCurves& cc = curves[e.col0 + k0 + k];
          cc.offset.push_back(0);
          for (int d = 0; d < depths; ++d) {
            const EnergyHistogram& hd = h[k * depths + d];
            size_t base = cc.bin.size();
            double below = 0;
            for (size_t i = 0; i < hd.bin.size(); ++i) {
              cc.bin.push_back(hd.bin[i]);
              cc.energy_below.push_back(below);
              below += hd.energy[i];
            }
            cc.depth_total.push_back(below);
            cc.count_at_or_above.resize(cc.bin.size());
            uint64_t above = 0;
            for (size_t i = hd.bin.size(); i-- > 0;) {
              above += hd.count[i];
              cc.count_at_or_above[base + i] = above;
            }
            cc.offset.push_back(static_cast<uint32_t>(cc.bin.size()));
          }
          uint64_t bytes = cc.bin.size() * (4 + 8 + 8) + cc.offset.size() * 4 + cc.depth_total.size() * 8 + 128;
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
    result.histogram_bytes = hist_bytes;
    int lo = INT32_MAX, hi = INT32_MIN;
    for (const ColumnCurves& cc : curves)
      if (!cc.bin.empty()) {
        lo = std::min(lo, *std::min_element(cc.bin.begin(), cc.bin.end()));
        hi = std::max(hi, *std::max_element(cc.bin.begin(), cc.bin.end()));
      }
    auto total = [&](int g) {
      double lambda = BinLowerEdge(g);
      uint64_t sum = 0;
      for (const ColumnCurves& cc : curves) {
        if (cc.bin.empty()) continue;
        uint64_t n = 0;
        PickDepth(cc, g, lambda, &n);
        sum += n;
      }
      return sum;
    };
    // --target-error: the relative error at threshold bin g, each column at its depth.
    auto error_at = [&](int g) {
      double lambda = BinLowerEdge(g), dropped = 0, energy = 0;
      for (const ColumnCurves& cc : curves) {
        if (cc.bin.empty()) continue;
        uint64_t n = 0;
        int d = PickDepth(cc, g, lambda, &n);
        Point p = Evaluate(cc, d, g, lambda);
        dropped += p.cost - lambda * static_cast<double>(p.count);
        energy += cc.depth_total[d];
      }
      return energy > 0 ? std::sqrt(std::max(0.0, dropped) / energy) : 0.0;
    };
    if (lo > hi) {
      threshold_bin = 0;  // every column is empty
    } else if (o.terms.kind == TermsMode::Kind::kTargetError) {
      // The largest threshold (fewest terms) within the target; bins are 1/8 octave apart.
      const double t = o.terms.target_error;
      if (error_at(hi + 1) <= t) {
        threshold_bin = hi + 1;
      } else {
        int l = lo, h = hi + 1;  // error_at(l) ≤ t (every term kept) < error_at(h)
        while (h - l > 1) {
          int mid = l + (h - l) / 2;
          (error_at(mid) <= t ? l : h) = mid;
        }
        threshold_bin = l;
      }
      budget = total(threshold_bin);  // met exactly: nothing to fill from the bin below
      result.budget = budget;
      result.estimated_error = error_at(threshold_bin);
    } else if (total(lo) <= budget) {
      threshold_bin = lo;
    } else {
      int l = lo, h = hi + 1;  // total(l) > budget >= total(h)
      while (h - l > 1) {
        int mid = l + (h - l) / 2;
        (total(mid) <= budget ? h : l) = mid;
      }
      threshold_bin = h;
    }
    budget_depth.assign(a.cols, -1);
    budget_extra.assign(a.cols, 0);
    double lambda = BinLowerEdge(threshold_bin);
    uint64_t used = 0;
    std::vector<uint64_t> in_next_bin(a.cols, 0);  // terms of bin threshold_bin − 1 at the chosen depth
    for (uint64_t c = 0; c < a.cols; ++c) {
      if (curves[c].bin.empty()) continue;
      uint64_t n = 0;
      int d = PickDepth(curves[c], threshold_bin, lambda, &n);
      budget_depth[c] = static_cast<int8_t>(plan.min_depth + d);
      used += n;
      Point below = Evaluate(curves[c], d, threshold_bin - 1, BinLowerEdge(threshold_bin - 1));
      in_next_bin[c] = below.count - n;
    }
    // The bins are 1/8 octave wide, and many equal values (a lit floor) can share one: fill
    // what is left of the budget from the next bin down, at each column's chosen depth,
    // in column order (each extra term lowers the error by at least λ/2^(1/8)).
    for (uint64_t c = 0; c < a.cols && used < budget; ++c) {
      uint64_t take = std::min(in_next_bin[c], budget - used);
      budget_extra[c] = take;
      used += take;
    }
    result.lambda = lambda;
  }

  EncodeOptions eo;
  eo.zstd = o.zstd;
  eo.sparse = true;
  eo.dtype = DType::kF32;
  EncodeOptions side;  // depth and column_stats: zstd where it saves
  side.zstd = true;
  std::atomic<uint64_t> written{0};
  Status s = ParallelFor(items, jobs, progress, "chunks", [&](uint64_t c) -> Status {
    LTB_ASSIGN_OR_RETURN(ColumnCompressor * comp, thread_compressor());
    // Output chunk c: columns [col0, col0 + ncols), read from the input chunks over them.
    const uint64_t col0 = c * plan.block, ncols = std::min(plan.block, a.cols - col0);
    std::vector<float> dense(ncols * pixels, 0.0f);
    std::vector<uint8_t> depths(ncols, 0);
    std::vector<double> stats(ncols * kStatsPerColumn, 0.0);
    ColumnChoice choice[ColumnCompressor::kLanes];
    Selection sel[ColumnCompressor::kLanes];
    int override_depth[ColumnCompressor::kLanes];
    for (uint64_t ic = col0 / a.block; ic * a.block < col0 + ncols; ++ic) {
      LTB_ASSIGN_OR_RETURN(io::Chunk chunk, in.ReadChunk(0, ic));
      const ChunkExtent e = chunk.extent();
      auto values = chunk.as<float>();
      const uint64_t j0 = std::max(e.col0, col0), j1 = std::min(e.col0 + e.cols, col0 + ncols);
      for (uint64_t jb = j0; jb < j1; jb += ColumnCompressor::kLanes) {
        size_t n = std::min<uint64_t>(ColumnCompressor::kLanes, j1 - jb);
        const float* cols[ColumnCompressor::kLanes];
        for (size_t k = 0; k < n; ++k) {
          const uint64_t j = jb + k;
          cols[k] = values.data() + (j - e.col0) * pixels;
          if (budget_depth.empty()) {
            sel[k].kind = Selection::Kind::kTerms;
            sel[k].terms = terms;
            override_depth[k] = -1;
          } else {
            sel[k].kind = Selection::Kind::kThreshold;
            sel[k].threshold_bin = threshold_bin;
            sel[k].terms = budget_extra[j];
            override_depth[k] = budget_depth[j];
          }
        }
        Status cs = comp->Choose(cols, n, sel, override_depth, choice);
        if (!cs.ok()) return cs.WithContext(o.input + ": column " + std::to_string(jb));
        for (size_t k = 0; k < n; ++k) {
          const uint64_t m = jb + k - col0;  // column within the output chunk
          float* out_col = dense.data() + m * pixels;
          for (size_t i = 0; i < choice[k].index.size(); ++i) out_col[choice[k].index[i]] = choice[k].value[i];
          depths[m] = static_cast<uint8_t>(choice[k].depth);
          stats[m * kStatsPerColumn + 0] = choice[k].energy;
          stats[m * kStatsPerColumn + 1] = choice[k].error;
          stats[m * kStatsPerColumn + 2] = static_cast<double>(choice[k].index.size());
        }
      }
    }
    if (!out.Has(0, c)) {
      LTB_RETURN_IF_ERROR(out.Put(0, c, BytesOf(dense), eo));
    }
    if (!out.Has(depth_array, c)) {
      LTB_RETURN_IF_ERROR(out.Put(depth_array, c, BytesOf(depths), side));
    }
    if (!out.Has(stats_array, c)) {
      LTB_RETURN_IF_ERROR(out.Put(stats_array, c, BytesOf(stats), side));
    }
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

Result<ColumnTransformResult> SummarizeColumnTransform(const std::string& path) {
  LTB_ASSIGN_OR_RETURN(io::ContainerReader r, io::ContainerReader::Open(path));
  const Metadata& meta = r.metadata();
  if (!meta.json.contains("column_transform") || !meta.json["column_transform"].is_object()) {
    return FailedPrecondition(path + ": is not a column-transform output");
  }
  const auto& ct = meta.json["column_transform"];
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
