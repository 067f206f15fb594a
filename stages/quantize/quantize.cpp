#include "stages/quantize/quantize.h"

#include <algorithm>
#include <atomic>
#include <bit>
#include <cmath>
#include <span>
#if defined(__AVX2__)
#include <immintrin.h>
#endif

#include "format/io/container_reader.h"
#include "format/io/container_writer.h"
#include "stages/column_transform/column_codec.h"
#include "stages/column_transform/column_transform.h"
#include "stages/common/basis.h"
#include "stages/common/parallel_for.h"
#include "stages/common/thread_zeros.h"

namespace ltb::stages {

using namespace ltb::format;

namespace {

constexpr const char* kScaleArray = "scale";

uint64_t SplitMix64(uint64_t x) {
  x += 0x9E3779B97F4A7C15ull;
  x = (x ^ (x >> 30)) * 0xBF58476D1CE4E5B9ull;
  x = (x ^ (x >> 27)) * 0x94D049BB133111EBull;
  return x ^ (x >> 31);
}

}  // namespace

int32_t QuantizeValue(double v, double m, double levels, bool dither, uint64_t seed, uint64_t column,
                      uint32_t position) {
  double x = v / m * levels;  // in [−Q, Q]
  double q;
  if (dither) {
    uint64_t h = SplitMix64(seed ^ SplitMix64(column * 0x100000001B3ull ^ SplitMix64(position)));
    double u = static_cast<double>(h >> 11) * 0x1p-53;  // [0, 1)
    q = std::floor(x + u);
  } else {
    q = std::round(x);
  }
  q = std::clamp(q, -levels, levels);
  return static_cast<int32_t>(q);
}

double StepForErrorRatio(double ratio, double truncation_error, double energy, uint64_t kept) {
  if (kept == 0) return 1.0;  // nothing to quantize
  const double e = std::max(truncation_error, 1e-10 * energy);
  return std::sqrt(12.0 * (ratio * ratio - 1.0) * e / static_cast<double>(kept));
}

namespace {

// The scaled coefficients (v · factor) of a deterministic sample of the matrix's nonzeros:
// each one with probability 1/stride by a hash of (column, position), gathered in chunk
// order whatever the number of jobs; `count` is every nonzero.
struct StepSample {
  std::vector<double> values;
  uint64_t count = 0;
};

constexpr uint64_t kStepSample = 4u << 20;

// std::round (half away from zero), inline: trunc plus one where the exact fraction is at
// least a half. Equal to std::round for every double (the fraction x − trunc(x) is exact), up
// to the sign of a zero result, which QuantizationError's square does not see.
inline double RoundHalfAway(double x) {
  const double t = std::trunc(x);
  return t + std::copysign(static_cast<double>(std::fabs(x - t) >= 0.5), x);  // branch-free: vectorises
}

inline double SquaredRoundingError(double x, double step) {
  const double d = RoundHalfAway(x / step) * step - x;
  return d * d;
}

// Σ (round(v / step) · step − v)² over x. `ordered`: added in x's order, bit for bit the
// scalar loop's sum; else in eight interleaved partial sums (vectorised, several times
// faster), within (n − 1)·2^−53 of the exact sum relative, as any order of adding n
// non-negative terms is.
double QuantizationError(const std::vector<double>& x, double step, bool ordered) {
  constexpr size_t kLanes = 8;
  double e = 0;
  size_t i = 0;
  if (ordered) {
    for (; i + kLanes <= x.size(); i += kLanes) {
      double d2[kLanes];
      for (size_t k = 0; k < kLanes; ++k) d2[k] = SquaredRoundingError(x[i + k], step);
      for (size_t k = 0; k < kLanes; ++k) e += d2[k];
    }
  } else {
#if defined(__AVX2__)
    // SquaredRoundingError four at a time, the same operations (no contraction: -ffp-contract=off).
    const __m256d vstep = _mm256_set1_pd(step), half = _mm256_set1_pd(0.5), one = _mm256_set1_pd(1.0);
    const __m256d sign = _mm256_set1_pd(-0.0);
    __m256d acc0 = _mm256_setzero_pd(), acc1 = _mm256_setzero_pd();
    auto squares = [&](const double* p) {
      const __m256d v = _mm256_loadu_pd(p);
      const __m256d q = _mm256_div_pd(v, vstep);
      const __m256d t = _mm256_round_pd(q, _MM_FROUND_TO_ZERO | _MM_FROUND_NO_EXC);
      const __m256d frac = _mm256_andnot_pd(sign, _mm256_sub_pd(q, t));
      const __m256d up =
          _mm256_or_pd(_mm256_and_pd(_mm256_cmp_pd(frac, half, _CMP_GE_OQ), one), _mm256_and_pd(q, sign));
      const __m256d d = _mm256_sub_pd(_mm256_mul_pd(_mm256_add_pd(t, up), vstep), v);
      return _mm256_mul_pd(d, d);
    };
    for (; i + kLanes <= x.size(); i += kLanes) {
      acc0 = _mm256_add_pd(acc0, squares(x.data() + i));
      acc1 = _mm256_add_pd(acc1, squares(x.data() + i + 4));
    }
    double acc[kLanes];
    _mm256_storeu_pd(acc, acc0);
    _mm256_storeu_pd(acc + 4, acc1);
#else
    double acc[kLanes] = {};
    for (; i + kLanes <= x.size(); i += kLanes) {
      for (size_t k = 0; k < kLanes; ++k) acc[k] += SquaredRoundingError(x[i + k], step);
    }
#endif
    for (size_t k = 0; k < kLanes; ++k) e += acc[k];
  }
  for (; i < x.size(); ++i) e += SquaredRoundingError(x[i], step);
  return e;
}

// The largest step whose quantization error over the matrix (estimated on the sample) is
// at most (ratio² − 1) times the truncation error. Reads every chunk, also in a shard, so
// every shard finds the same step (it is in the metadata).
Result<double> RefineStep(const io::ContainerReader& in, const ColumnCodec& codec,
                          const std::vector<std::vector<double>>& factors, double ratio,
                          const ColumnTransformResult& totals, double model_step, int jobs, const Progress& progress) {
  const ArraySpec& a = in.metadata().matrix();
  const uint64_t pixels = a.rows;
  const uint64_t stride = std::max<uint64_t>(1, (totals.nonzeros + kStepSample - 1) / kStepSample);
  std::vector<StepSample> per_chunk(a.ChunkCount());
  std::atomic<uint64_t> sampled{0};  // bounded: column_stats that undercount are damage
  std::vector<uint64_t> chunks(a.ChunkCount());
  for (uint64_t c = 0; c < chunks.size(); ++c) chunks[c] = c;
  Status s = ParallelFor(chunks, jobs, progress, "chunks (step search)", [&](uint64_t c) -> Status {
    LTB_ASSIGN_OR_RETURN(SparseChunk sc, in.ReadSparse(0, c));
    LTB_ASSIGN_OR_RETURN(const std::vector<uint8_t> depths,
                         ReadLinesAs<uint8_t>(in, static_cast<uint32_t>(codec.depth_array()), sc.extent.col0,
                                              sc.extent.col0 + sc.extent.cols));
    auto values = sc.as<float>();
    StepSample& out = per_chunk[c];
    for (size_t i = 0; i < sc.index.size(); ++i) {
      const uint64_t k = sc.index[i] / pixels, p = sc.index[i] % pixels, col = sc.extent.col0 + k;
      const int d = depths[k];
      if (d > codec.max_depth()) {
        return DataLoss(in.path() + ": column " + std::to_string(col) + " has depth " + std::to_string(d));
      }
      out.count++;
      if (stride > 1 && SplitMix64(col * 0x9E3779B97F4A7C15ull ^ SplitMix64(p)) % stride != 0) continue;
      out.values.push_back(static_cast<double>(values[i]) * factors[d][p]);
    }
    if (sampled.fetch_add(out.values.size()) + out.values.size() > 4 * kStepSample + totals.nonzeros) {
      return DataLoss(in.path() + ": its column_stats count " + std::to_string(totals.nonzeros) +
                      " nonzeros, but the matrix holds far more; the file is damaged (rerun column-transform)");
    }
    return Status::Ok();
  });
  LTB_RETURN_IF_ERROR(s);
  std::vector<double> x;
  uint64_t count = 0;
  for (StepSample& ps : per_chunk) {
    x.insert(x.end(), ps.values.begin(), ps.values.end());
    count += ps.count;
  }
  if (x.empty()) return model_step;
  const double weight = static_cast<double>(count) / static_cast<double>(x.size());
  const double target = (ratio * ratio - 1.0) * std::max(totals.error, 1e-10 * totals.energy);
  // Whether the sample's error (its squares added in order, as QuantizeValue rounds) at this
  // step is within the target.
  auto within = [&](double step) { return QuantizationErrorAtMost(x, step, weight, target); };
  // The largest step whose error stays within the target, bisected in log(step) over
  // 2^±12 around the model's (the error grows with the step, up to small wiggles).
  double lo = std::log2(model_step) - 12, hi = std::log2(model_step) + 12;
  if (!within(std::exp2(lo))) return std::exp2(lo);
  if (within(std::exp2(hi))) return std::exp2(hi);
  for (int it = 0; it < 48; ++it) {
    const double mid = 0.5 * (lo + hi);
    (within(std::exp2(mid)) ? lo : hi) = mid;
  }
  return std::exp2(lo);
}

// The options as run: --error-ratio quantizes with bits 24 and no dither.
Result<QuantizeOptions> ResolveOptions(const QuantizeOptions& options) {
  QuantizeOptions o = options;
  if (o.error_ratio != 0) {
    if (!(o.error_ratio > 1.0 && o.error_ratio <= 100.0)) {
      return InvalidArgument("--error-ratio " + std::to_string(o.error_ratio) +
                             ": expected a factor in (1, 100] on the RMS error, e.g. 1.1");
    }
    o.bits = 24;
    o.dither = false;
  }
  if (o.bits < 2 || o.bits > 24) {
    return InvalidArgument("--bits " + std::to_string(o.bits) + ": expected 2..24 (f32 coefficients carry 24 bits)");
  }
  return o;
}

// The input: a complete column-transform output, not yet quantized.
Result<io::ContainerReader> OpenInput(const QuantizeOptions& o) {
  LTB_ASSIGN_OR_RETURN(io::ContainerReader in, io::ContainerReader::Open(o.input));
  const Metadata& meta = in.metadata();
  if (meta.json.contains("quantization")) {
    return FailedPrecondition(o.input +
                              ": is already quantized; quantize takes the output of `ltbake column-transform`");
  }
  if (!ColumnCodec::IsColumnTransformed(meta)) {
    return FailedPrecondition(o.input +
                              ": is not a column-transform output; run `ltbake column-transform` first "
                              "(after `ltbake transpose`)");
  }
  LTB_RETURN_IF_ERROR(RequireCompleteF32Matrix(in));
  return in;
}

// --error-ratio: the step from the input's totals (its column_stats, returned in
// *totals_in), then refined on the coefficients themselves (N·Δ²/12 holds only while Δ is
// small beside them).
Result<double> FindStep(const QuantizeOptions& o, const io::ContainerReader& in, const ColumnCodec& codec,
                        const std::vector<std::vector<double>>& factors, const Progress& progress,
                        ColumnTransformResult* totals_in) {
  LTB_ASSIGN_OR_RETURN(*totals_in, SummarizeColumnTransform(o.input));
  double step = StepForErrorRatio(o.error_ratio, totals_in->error, totals_in->energy, totals_in->nonzeros);
  if (!(step > 0) || !std::isfinite(step)) {
    return DataLoss(o.input + ": column_stats give no usable quantization step (error " +
                    std::to_string(totals_in->error) + ", energy " + std::to_string(totals_in->energy) + ")");
  }
  return RefineStep(in, codec, factors, o.error_ratio, *totals_in, step, o.jobs, progress);
}

// The output's metadata and where its tables are.
struct QuantizeOutput {
  nlohmann::json meta;
  std::vector<uint32_t> row_tables;  // the input arrays kept, output arrays 1, 2, ...
  uint32_t depth_array = 0;
  int scale_array = -1;  // per-column maxima (--bits) only: one step needs none
};

// A per-column table of the output: one line per column, in as few chunks as fit
// kSideTableChunkBytes (one, up to 2 Mi columns of f64).
ArraySpec ColumnTableSpec(const char* name, DType dtype, uint64_t cols) {
  ArraySpec s;
  s.name = name;
  s.dtype = dtype;
  s.rows = cols;
  s.cols = 1;
  s.layout = Layout::kRows;
  s.block = BlockForTargetBytes(cols, 1, dtype, Layout::kRows, kSideTableChunkBytes);
  return s;
}

// The output's metadata (docs/COLUMN-TRANSFORM.md): the matrix as i32; the row tables
// relighting reads; "depth" (u8) and, for --bits, "scale" (f64) per column, each in one
// chunk written after the matrix (one step for the matrix is in the metadata:
// "quantization.step"); "quantization", what ColumnCodec::FromMetadata reads back; and the
// input's column totals under "column_transform.totals" instead of its per-column
// column_stats (which nothing reads after quantize: relight estimates the column norms
// from the coefficients).
Result<QuantizeOutput> OutputMetadata(const QuantizeOptions& o, const io::ContainerReader& in,
                                      const ColumnTransformResult& totals, Scaling scaling, bool step_mode,
                                      double step) {
  const Metadata& meta = in.metadata();
  const ArraySpec& a = meta.matrix();
  if (meta.FindArray(kScaleArray) >= 0) return FailedPrecondition(o.input + ": already has a \"scale\" array");
  QuantizeOutput out;
  nlohmann::json& out_meta = out.meta;
  out_meta = meta.json;
  ArraySpec m = a;
  m.dtype = DType::kI32;
  out_meta["arrays"] = nlohmann::json::array({m.ToJson()});
  nlohmann::json& ct = out_meta["column_transform"];
  nlohmann::json dropped = ct.value("row_tables_dropped", nlohmann::json::array());
  const int depth_in = meta.FindArray(ct.value("depth_array", std::string("depth")));
  const int stats_in = meta.FindArray(ct.value("stats_array", std::string("column_stats")));
  for (uint32_t arr = 1; arr < meta.arrays.size(); ++arr) {
    if (static_cast<int>(arr) == depth_in || static_cast<int>(arr) == stats_in) continue;
    if (!KeptByCompressedOutputs(meta.arrays[arr].name)) {  // an older column-transform kept more
      dropped.push_back(meta.arrays[arr].name);
      continue;
    }
    out.row_tables.push_back(arr);
    out_meta["arrays"].push_back(PassThroughSpec(meta.arrays[arr]).ToJson());
  }
  out.depth_array = static_cast<uint32_t>(out_meta["arrays"].size());
  out_meta["arrays"].push_back(ColumnTableSpec("depth", DType::kU8, a.cols).ToJson());
  if (!step_mode) {
    out.scale_array = static_cast<int>(out.depth_array) + 1;
    out_meta["arrays"].push_back(ColumnTableSpec(kScaleArray, DType::kF64, a.cols).ToJson());
  }
  ct["depth_array"] = "depth";
  ct.erase("stats_array");
  if (!dropped.empty()) ct["row_tables_dropped"] = dropped;
  ct["totals"] = {{"energy", totals.energy},
                  {"error", totals.error},
                  {"nonzeros", totals.nonzeros},
                  {"empty_columns", totals.empty_columns},
                  {"depth_histogram", totals.depth_histogram}};
  out_meta["basis"]["rows"]["coefficients"] = "column_transform, quantized";
  out_meta["quantization"] = {{"bits", o.bits},
                              {"scaling", ScalingName(scaling)},
                              {"dither", o.dither},
                              {"seed", o.seed},
                              {"decode", "v = q / (2^(bits-1) - 1) * scale / factor (docs/COLUMN-TRANSFORM.md)"}};
  if (!step_mode) out_meta["quantization"]["scale_array"] = kScaleArray;
  nlohmann::json params = {
      {"bits", o.bits}, {"scaling", ScalingName(scaling)}, {"dither", o.dither}, {"seed", o.seed}, {"zstd", o.zstd}};
  if (step_mode) {
    out_meta["quantization"]["error_ratio"] = o.error_ratio;
    out_meta["quantization"]["step"] = step;  // scale = step · (2^(bits-1) - 1) in every column
    params = {{"error_ratio", o.error_ratio}, {"zstd", o.zstd}};
  }
  out_meta["provenance"] = Provenance("quantize", params, {&in});
  return out;
}

// Σ squared quantization error (double bits, CAS-added).
void AddError(std::atomic<uint64_t>* sum_bits, double e) {
  uint64_t cur = sum_bits->load();
  while (!sum_bits->compare_exchange_weak(cur, std::bit_cast<uint64_t>(std::bit_cast<double>(cur) + e))) {
  }
}

// What every chunk of the quantization pass reads and writes.
struct QuantizeJob {
  const QuantizeOptions& o;
  const io::ContainerReader& in;
  io::ContainerWriter& out;
  const ColumnCodec& codec;
  const std::vector<std::vector<double>>& factors;  // per depth, per position
  bool step_mode = false;
  double step = 0;
  double levels = 0;                 // Q
  std::atomic<uint64_t>* qerr_bits;  // AddError
  std::atomic<uint64_t>* nonzeros;   // of the chunks this run quantizes and writes
  EncodeOptions matrix_encoding;     // sparse i32
  std::vector<double>* scales;       // per column of the matrix: each chunk fills its own
};

// One input chunk: its stored coefficients and their columns' depths.
struct InputChunk {
  SparseChunk sc;
  std::vector<uint8_t> depths;
};

Result<InputChunk> ReadInputChunk(const QuantizeJob& job, uint64_t c) {
  InputChunk ic;
  LTB_ASSIGN_OR_RETURN(ic.sc, job.in.ReadSparse(0, c));
  const ChunkExtent& e = ic.sc.extent;
  LTB_ASSIGN_OR_RETURN(
      ic.depths, ReadLinesAs<uint8_t>(job.in, static_cast<uint32_t>(job.codec.depth_array()), e.col0, e.col0 + e.cols));
  return ic;
}

// The scaled coefficients (v · factor) of column k of the chunk, positions [begin, end) of
// its index, into *scaled; returns their largest magnitude M, the column's scale (Δ · Q for
// every column with a nonzero in --error-ratio mode), 0 for a column of (signed) zeros.
Result<double> ScaleColumn(const QuantizeJob& job, const InputChunk& ic, uint64_t k, size_t begin, size_t end,
                           std::vector<double>* scaled) {
  const SparseChunk& sc = ic.sc;
  const uint64_t pixels = job.in.metadata().matrix().rows;
  const uint64_t col = sc.extent.col0 + k;
  const int d = ic.depths[k];
  if (d > job.codec.max_depth()) {
    return DataLoss(job.o.input + ": column " + std::to_string(col) + " has depth " + std::to_string(d));
  }
  const std::vector<double>& factor = job.factors[d];
  auto values = sc.as<float>();
  scaled->resize(end - begin);
  double mx = 0;
  for (size_t i = begin; i < end; ++i) {
    const uint32_t p = sc.index[i] - static_cast<uint32_t>(k * pixels);
    const double v = static_cast<double>(values[i]) * factor[p];
    (*scaled)[i - begin] = v;
    mx = std::max(mx, std::fabs(v));
  }
  if (!std::isfinite(mx))
    return DataLoss(job.o.input + ": column " + std::to_string(col) + " holds a non-finite coefficient");
  if (mx == 0) return 0.0;                            // only signed zeros
  return job.step_mode ? job.step * job.levels : mx;  // q = round(v / Δ): the same step in every column
}

// Chunk c: the scales of its columns into job.scales and, with `quantize`, its quantized
// matrix chunk (written unless already committed).
Status QuantizeChunk(const QuantizeJob& job, uint64_t c, bool quantize) {
  const QuantizeOptions& o = job.o;
  const uint64_t pixels = job.in.metadata().matrix().rows;
  const double levels = job.levels;
  LTB_ASSIGN_OR_RETURN(const InputChunk ic, ReadInputChunk(job, c));
  const SparseChunk& sc = ic.sc;
  const ChunkExtent& e = sc.extent;
  // The dense chunk, in this thread's reused buffer; the positions a chunk sets (those of
  // its input) are cleared after it is written, on every path out.
  const std::span<int32_t> dense = quantize ? ThreadZeros<int32_t>(e.cols * pixels) : std::span<int32_t>();
  const ClearOnExit clear(dense, sc.index);
  std::vector<double> scaled;
  size_t pos = 0;
  uint64_t nonzeros = 0;
  for (uint64_t k = 0; k < e.cols; ++k) {
    const size_t begin = pos;
    while (pos < sc.index.size() && sc.index[pos] < (k + 1) * pixels) ++pos;
    LTB_ASSIGN_OR_RETURN(const double mx, ScaleColumn(job, ic, k, begin, pos, &scaled));
    (*job.scales)[e.col0 + k] = mx;
    if (!quantize || mx == 0) continue;
    double column_error = 0;
    for (size_t i = begin; i < pos; ++i) {
      const uint32_t p = sc.index[i] - static_cast<uint32_t>(k * pixels);
      const int32_t q = QuantizeValue(scaled[i - begin], mx, levels, o.dither, o.seed, e.col0 + k, p);
      dense[sc.index[i]] = q;
      nonzeros += q != 0 ? 1 : 0;
      const double err = static_cast<double>(q) * (mx / levels) - scaled[i - begin];
      column_error += err * err;
    }
    AddError(job.qerr_bits, column_error);
  }
  if (quantize && !job.out.Has(0, c)) {
    LTB_RETURN_IF_ERROR(job.out.Put(0, c, BytesOf(std::span<const int32_t>(dense)), job.matrix_encoding));
    *job.nonzeros += nonzeros;
  }
  return Status::Ok();
}

// Writes the missing chunks of per-column table `arr` from its values for every column.
Status PutColumnTable(io::ContainerWriter& out, uint32_t arr, const std::byte* values, uint64_t* chunks_written) {
  const ArraySpec& spec = out.metadata().arrays[arr];
  const uint64_t line = DTypeSize(spec.dtype);
  EncodeOptions side;
  side.zstd = true;
  for (uint64_t c : out.Missing(arr)) {
    const uint64_t l0 = c * spec.block, l1 = std::min(spec.rows, l0 + spec.block);
    LTB_RETURN_IF_ERROR(out.Put(arr, c, ByteSpan(values + l0 * line, (l1 - l0) * line), side));
    ++*chunks_written;
  }
  return Status::Ok();
}

// The per-column tables, once every matrix chunk is committed: "depth" copied from the
// input, "scale" (--bits) from job.scales, after the scales of the chunks this run did not
// quantize (committed before a resume, or another shard's) are computed the same way.
Status PutColumnTables(const QuantizeJob& job, const QuantizeOutput& layout, const std::vector<bool>& scaled,
                       const Progress& progress, uint64_t* chunks_written) {
  io::ContainerWriter& out = job.out;
  if (layout.scale_array >= 0 && !out.Missing(static_cast<uint32_t>(layout.scale_array)).empty()) {
    std::vector<uint64_t> rest;
    for (uint64_t c = 0; c < scaled.size(); ++c)
      if (!scaled[c]) rest.push_back(c);
    LTB_RETURN_IF_ERROR(ParallelFor(rest, job.o.jobs, progress, "chunks (scales)",
                                    [&](uint64_t c) { return QuantizeChunk(job, c, false); }));
    LTB_RETURN_IF_ERROR(PutColumnTable(out, static_cast<uint32_t>(layout.scale_array),
                                       reinterpret_cast<const std::byte*>(job.scales->data()), chunks_written));
  }
  if (!out.Missing(layout.depth_array).empty()) {
    const uint64_t cols = job.in.metadata().matrix().cols;
    LTB_ASSIGN_OR_RETURN(std::vector<std::byte> depth,
                         ReadLines(job.in, static_cast<uint32_t>(job.codec.depth_array()), 0, cols));
    LTB_RETURN_IF_ERROR(PutColumnTable(out, layout.depth_array, depth.data(), chunks_written));
  }
  return Status::Ok();
}

// Coefficients the input kept, from its side table, over the chunks `out` owns.
Result<uint64_t> InputNonzeros(const io::ContainerReader& in, const Metadata& out_meta) {
  const Metadata& meta = in.metadata();
  uint64_t nonzeros = 0;
  int stats = meta.FindArray(meta.json["column_transform"].value("stats_array", std::string("column_stats")));
  if (stats >= 0) {
    for (uint64_t c = 0; c < meta.arrays[stats].ChunkCount(); ++c) {
      if (!out_meta.Owns(0, c)) continue;  // a shard: its own columns (the stats share the matrix's blocks)
      LTB_ASSIGN_OR_RETURN(io::Chunk sc, in.ReadChunk(static_cast<uint32_t>(stats), c));
      auto v = sc.as<double>();
      for (size_t i = 2; i < v.size(); i += 3) nonzeros += static_cast<uint64_t>(v[i]);
    }
  }
  return nonzeros;
}

}  // namespace

// From the fast sum where that decides it: both sums are within γ = n·2^−53 of the exact one
// relative (the margin takes 4γ, for its own rounding), so a fast sum farther than that from
// the bound gives the ordered sum's answer; near it (the last steps of a bisection) the
// ordered sum is taken.
bool QuantizationErrorAtMost(const std::vector<double>& x, double step, double weight, double bound) {
  const double fast = QuantizationError(x, step, false);
  const double margin = 4.0 * (static_cast<double>(x.size()) + 1.0) * 0x1p-53 * fast;
  if ((fast + margin) * weight < bound) return true;
  if ((fast - margin) * weight > bound) return false;
  return QuantizationError(x, step, true) * weight <= bound;
}

Result<QuantizeResult> RunQuantize(const QuantizeOptions& options, const Progress& progress) {
  LTB_ASSIGN_OR_RETURN(const QuantizeOptions o, ResolveOptions(options));
  const bool step_mode = o.error_ratio != 0;
  LTB_ASSIGN_OR_RETURN(io::ContainerReader in, OpenInput(o));
  const Metadata& meta = in.metadata();
  LTB_ASSIGN_OR_RETURN(ColumnCodec codec, ColumnCodec::FromMetadata(meta, o.input));
  const ArraySpec& a = meta.matrix();

  const Scaling scaling = step_mode ? Scaling::kNorm : o.level_scaling ? Scaling::kNormLevel : Scaling::kNone;
  // The codec of the input knows no quantization; the factors of this run's scaling:
  const auto factors = QuantizationFactors(codec.filter(), codec.width(), codec.height(), codec.max_depth(), scaling);
  double step = 0;
  ColumnTransformResult totals_in;
  if (step_mode) {
    LTB_ASSIGN_OR_RETURN(step, FindStep(o, in, codec, factors, progress, &totals_in));
  }
  if (!step_mode) {
    LTB_ASSIGN_OR_RETURN(totals_in, SummarizeColumnTransform(o.input));
  }
  LTB_ASSIGN_OR_RETURN(QuantizeOutput layout, OutputMetadata(o, in, totals_in, scaling, step_mode, step));
  io::WriterOptions wo;
  wo.overwrite_mismatch = o.overwrite;
  LTB_ASSIGN_OR_RETURN(io::ContainerWriter out, io::OpenStageOutput(o.output, layout.meta, wo, o.shard));

  QuantizeResult result;
  result.rows = a.rows;
  result.cols = a.cols;
  for (const ArraySpec& s : out.metadata().arrays) result.chunks_total += s.ChunkCount();
  result.chunks_already_committed = out.resume_info().committed_chunks;

  for (uint32_t k = 0; k < layout.row_tables.size(); ++k) {
    LTB_RETURN_IF_ERROR(CopyArray(in, layout.row_tables[k], out, k + 1, &result.chunks_written));
  }
  const std::vector<uint64_t> items = out.Missing(0);

  std::atomic<uint64_t> qerr_bits{0};  // Σ squared quantization error (double bits, CAS-added)
  std::atomic<uint64_t> nonzeros_written{0};
  std::vector<double> scales(a.cols, 0.0);
  QuantizeJob job{.o = o,
                  .in = in,
                  .out = out,
                  .codec = codec,
                  .factors = factors,
                  .step_mode = step_mode,
                  .step = step,
                  .levels = Quantization{o.bits}.Levels(),
                  .qerr_bits = &qerr_bits,
                  .nonzeros = &nonzeros_written,
                  .scales = &scales};
  job.matrix_encoding.sparse = true;
  job.matrix_encoding.dtype = DType::kI32;
  job.matrix_encoding.zstd = o.zstd;
  // Also the coded encoding (format 1.2), its contexts shaped by the column image.
  job.matrix_encoding.coded = true;
  job.matrix_encoding.coded_width = codec.width();
  std::vector<bool> scaled(a.ChunkCount(), false);
  for (uint64_t c : items) scaled[c] = true;  // each a distinct chunk: no two jobs write one flag
  std::atomic<uint64_t> written{0};
  Status s = ParallelFor(items, o.jobs, progress, "chunks", [&](uint64_t c) -> Status {
    LTB_RETURN_IF_ERROR(QuantizeChunk(job, c, true));
    written++;
    return Status::Ok();
  });
  result.chunks_written += written;
  LTB_RETURN_IF_ERROR(s);
  LTB_RETURN_IF_ERROR(PutColumnTables(job, layout, scaled, progress, &result.chunks_written));
  LTB_RETURN_IF_ERROR(out.Finish());

  result.step = step;
  // Only a run that quantized every chunk saw every error (a resumed one reports NaN).
  result.quantization_error = result.chunks_already_committed == 0 ? std::bit_cast<double>(qerr_bits.load()) : NAN;
  result.truncation_error = totals_in.error;
  result.energy = totals_in.energy;
  const Metadata out_meta_parsed = out.metadata();
  // The chunks written now were counted as they were; only those committed before are read.
  LTB_ASSIGN_OR_RETURN(QuantizeResult totals, SummarizeQuantized(out.path(), scaled));
  result.nonzeros_out = totals.nonzeros_out + nonzeros_written.load();
  result.matrix_bytes = totals.matrix_bytes;
  LTB_ASSIGN_OR_RETURN(result.nonzeros_in, InputNonzeros(in, out_meta_parsed));
  return result;
}

Result<QuantizeResult> SummarizeQuantized(const std::string& path, const std::vector<bool>& skip_nonzeros) {
  LTB_ASSIGN_OR_RETURN(io::ContainerReader r, io::ContainerReader::Open(path));
  QuantizeResult t;
  t.rows = r.metadata().matrix().rows;
  t.cols = r.metadata().matrix().cols;
  for (uint64_t c = 0; c < r.metadata().matrix().ChunkCount(); ++c) {
    if (!r.metadata().Owns(0, c)) continue;  // a shard file: its own columns
    const IndexEntry* e = r.Find(0, c);
    if (e == nullptr) return FailedPrecondition(path + ": chunk " + std::to_string(c) + " is missing");
    t.matrix_bytes += e->header.payload_length;
    if (c < skip_nonzeros.size() && skip_nonzeros[c]) continue;
    LTB_ASSIGN_OR_RETURN(SparseChunk sc, r.ReadSparse(0, c));
    t.nonzeros_out += sc.index.size();
  }
  return t;
}

}  // namespace ltb::stages
