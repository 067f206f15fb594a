// `ltbake cpca --dense-first` (docs/CPCA.md "Dense-first (sparse bakes)"): on inputs that
// mark dense rows in a "sparse_kind" side array, the growth levels run on the dense rows and
// a few passes on all rows follow. Real containers are written to disk and RunCpca is
// called on them.
//
// Tolerances: a stored value carries a relative rounding error of at most u = 2^-24, so a
// row lying exactly in its cluster's affine subspace decodes with a relative error of about
// (2 + 2S)·u·√(S+1) (mean, S weights and S directions rounded once each; tests/cli/
// cpca_test.py derives the same bound), ×4 because mean and weights may exceed ‖x̂‖ a little.
#include <gtest/gtest.h>

#include <atomic>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <map>
#include <nlohmann/json.hpp>
#include <random>
#include <set>
#include <string>
#include <vector>

#include "format/array_spec.h"
#include "format/io/array_summary.h"
#include "format/io/container_reader.h"
#include "format/io/container_writer.h"
#include "stages/cpca/cpca.h"
#include "stages/cpca/cpca_model.h"

namespace ltb::stages {
namespace {

using format::ArraySpec;
using format::DType;
using format::Layout;

class TempDir {
 public:
  TempDir() {
    std::string tmpl = (std::filesystem::temp_directory_path() / "ltb-cpca-dense-XXXXXX").string();
    path_ = mkdtemp(tmpl.data());
  }
  ~TempDir() { std::filesystem::remove_all(path_); }
  std::string File(const std::string& name) const { return (std::filesystem::path(path_) / name).string(); }

 private:
  std::string path_;
};

// A test input: n × d rows, each row's sparse_kind and the subspace it was drawn from.
struct Rows {
  uint64_t n = 0, d = 0;
  std::vector<float> x;
  std::vector<uint8_t> kind;  // 0 all-zero, 1 dense, 2 sparse
  std::vector<int> label;     // the subspace; -1 for the all-zero rows
};

constexpr uint8_t kZero = 0, kDense = 1, kSparse = 2;

// Rows from k affine subspaces of dimension s in d dimensions (as tests/cli/cpca_test.py's
// affine_rows: means 3·N(0, 1), orthonormal bases, weights N(0, 1)). Subspace 0 is linear
// (mean 0), so the all-zero rows (every 97th row, kind 0) lie in it. A quarter of the
// other rows are dense (kind 1), the rest sparse (kind 2): every one of them lies exactly
// in its subspace, as a sparse bake's reconstruction from dense neighbours does.
Rows AffineRows(uint64_t k, uint64_t s, uint64_t d, uint64_t n, double noise, uint32_t seed) {
  std::mt19937_64 g(seed);
  std::normal_distribution<double> normal;
  std::uniform_real_distribution<double> unit;
  std::vector<std::vector<double>> mean(k, std::vector<double>(d, 0.0));
  std::vector<std::vector<std::vector<double>>> basis(k);
  for (uint64_t c = 0; c < k; ++c) {
    if (c > 0)
      for (double& v : mean[c]) v = 3 * normal(g);
    for (uint64_t i = 0; i < s; ++i) {  // Gram-Schmidt on Gaussian vectors
      std::vector<double> b(d);
      for (double& v : b) v = normal(g);
      for (const auto& q : basis[c]) {
        double dot = 0;
        for (uint64_t j = 0; j < d; ++j) dot += b[j] * q[j];
        for (uint64_t j = 0; j < d; ++j) b[j] -= dot * q[j];
      }
      double norm = 0;
      for (double v : b) norm += v * v;
      for (double& v : b) v /= std::sqrt(norm);
      basis[c].push_back(b);
    }
  }
  Rows r;
  r.n = n;
  r.d = d;
  r.x.assign(n * d, 0.0f);
  r.kind.assign(n, kSparse);
  r.label.assign(n, -1);
  uint64_t drawn = 0;
  for (uint64_t row = 0; row < n; ++row) {
    if (row % 97 == 5) {
      r.kind[row] = kZero;
      continue;
    }
    // The first 2k drawn rows: every subspace gets two dense rows at least.
    const uint64_t c = drawn < 2 * k ? drawn % k : static_cast<uint64_t>(unit(g) * k) % k;
    const bool dense = drawn < 2 * k || unit(g) < 0.25;
    ++drawn;
    r.label[row] = static_cast<int>(c);
    r.kind[row] = dense ? kDense : kSparse;
    std::vector<double> w(s);
    for (double& v : w) v = normal(g);
    for (uint64_t j = 0; j < d; ++j) {
      double v = mean[c][j];
      for (uint64_t i = 0; i < s; ++i) v += w[i] * basis[c][i][j];
      if (noise > 0) v += noise * normal(g);
      r.x[row * d + j] = static_cast<float>(v);
    }
  }
  return r;
}

uint64_t Count(const Rows& r, uint8_t kind) {
  uint64_t c = 0;
  for (uint8_t k : r.kind) c += k == kind;
  return c;
}

template <typename T>
format::ByteSpan Bytes(const T* p, uint64_t n) {
  return {reinterpret_cast<const std::byte*>(p), n * sizeof(T)};
}

// Writes the rows as a complete row-block f32 matrix of `block` rows per chunk and, when
// kind_block > 0, a "sparse_kind" side array (u8, one per row) of kind_block rows per chunk.
void WriteInput(const std::string& path, const Rows& r, uint64_t block, uint64_t kind_block) {
  ArraySpec m;
  m.name = "matrix";
  m.dtype = DType::kF32;
  m.rows = r.n;
  m.cols = r.d;
  m.layout = Layout::kRows;
  m.block = block;
  nlohmann::json arrays = nlohmann::json::array({m.ToJson()});
  ArraySpec k = m;
  k.name = kSparseKindArray;
  k.dtype = DType::kU8;
  k.cols = 1;
  k.block = kind_block;
  if (kind_block > 0) arrays.push_back(k.ToJson());
  const nlohmann::json meta = {{"arrays", arrays}, {"basis", {{"rows", {{"kind", "vertices"}, {"count", r.n}}}}}};
  auto w = io::ContainerWriter::Open(path, meta);
  ASSERT_TRUE(w.ok()) << w.status().message();
  for (uint64_t c = 0; c < m.ChunkCount(); ++c) {
    const format::ChunkExtent e = m.Extent(c);
    ASSERT_TRUE(w->Put(0, c, Bytes(r.x.data() + e.row0 * r.d, e.rows * r.d)).ok());
  }
  if (kind_block > 0) {
    for (uint64_t c = 0; c < k.ChunkCount(); ++c) {
      const format::ChunkExtent e = k.Extent(c);
      ASSERT_TRUE(w->Put(1, c, Bytes(r.kind.data() + e.row0, e.rows)).ok());
    }
  }
  Status s = w->Finish();
  ASSERT_TRUE(s.ok()) << s.message();
}

CpcaOptions Options(const std::string& in, const std::string& out, DenseFirst mode) {
  CpcaOptions o;
  o.input = in;
  o.output = out;
  o.clusters = 4;
  o.basis = 3;
  o.dense_first = mode;
  o.jobs = 2;
  o.mem_limit = 256ull << 20;
  return o;
}

CpcaResult RunOk(const CpcaOptions& o, const Progress& progress = {}) {
  auto r = RunCpca(o, progress);
  EXPECT_TRUE(r.ok()) << r.status().message();
  return r.ok() ? *r : CpcaResult{};
}

// The content_hash of every array of a container, recomputed from its chunks.
std::vector<std::string> Hashes(const std::string& path) {
  auto r = io::ContainerReader::Open(path);
  EXPECT_TRUE(r.ok()) << r.status().message();
  std::vector<std::string> h;
  if (!r.ok()) return h;
  for (uint32_t a = 0; a < r->metadata().arrays.size(); ++a) {
    auto s = io::SummarizeArray(*r, a, 1);
    EXPECT_TRUE(s.ok()) << s.status().message();
    h.push_back(s.ok() ? s->content_hash : "");
  }
  return h;
}

nlohmann::json Meta(const std::string& path) {
  auto r = io::ContainerReader::Open(path);
  EXPECT_TRUE(r.ok()) << r.status().message();
  return r.ok() ? r->metadata().json : nlohmann::json();
}

// The decoded approximation (through the reader convert and relight use) and its ids.
struct Decoded {
  std::vector<float> x;
  std::vector<uint32_t> ids;
};
Decoded Decode(const std::string& path) {
  Decoded out;
  auto in = io::ContainerReader::Open(path);
  EXPECT_TRUE(in.ok()) << in.status().message();
  if (!in.ok()) return out;
  auto m = CpcaModel::Load(*in, 1ull << 30);
  EXPECT_TRUE(m.ok()) << m.status().message();
  if (!m.ok()) return out;
  for (uint64_t c = 0; c < m->row_chunks(); ++c) {
    std::vector<float> chunk, w;
    std::vector<uint32_t> ids;
    EXPECT_TRUE(m->DecodeChunk(*in, c, &chunk).ok());
    EXPECT_TRUE(m->ReadRows(*in, c, &ids, &w).ok());
    out.x.insert(out.x.end(), chunk.begin(), chunk.end());
    out.ids.insert(out.ids.end(), ids.begin(), ids.end());
  }
  return out;
}

double RelativeError(const std::vector<float>& approx, const std::vector<float>& x) {
  double e = 0, n = 0;
  for (size_t i = 0; i < x.size(); ++i) {
    e += (static_cast<double>(approx[i]) - x[i]) * (static_cast<double>(approx[i]) - x[i]);
    n += static_cast<double>(x[i]) * x[i];
  }
  return std::sqrt(e / n);
}

struct DenseCounts {
  uint64_t dense_rows = 0, dense_passes = 0, final_passes = 0;
};
DenseCounts CountsOf(const std::string& path) {
  const nlohmann::json df = Meta(path)["cpca"].value("dense_first", nlohmann::json::object());
  return {df.value("dense_rows", uint64_t{0}), df.value("dense_passes", uint64_t{0}),
          df.value("final_passes", uint64_t{0})};
}

constexpr uint64_t kK = 4, kS = 3, kD = 48, kN = 2048;
const double kU = std::ldexp(1.0, -24);
const double kFloatBound = (2 + 2 * kS) * kU * std::sqrt(kS + 1.0) * 4;

TEST(CpcaDenseFirst, RecoversSubspacesFromDenseRowsAndStreamsFewerRows) {
  TempDir dir;
  const Rows rows = AffineRows(kK, kS, kD, kN, 0.0, 11);
  const uint64_t dense = Count(rows, kDense);
  ASSERT_GT(dense, kN / 5);
  ASSERT_LT(dense, kN / 3);
  ASSERT_GT(Count(rows, kZero), 0u);
  WriteInput(dir.File("in.ltm"), rows, 300, 300);

  const CpcaResult df = RunOk(Options(dir.File("in.ltm"), dir.File("df.ltm"), DenseFirst::kOn));
  EXPECT_TRUE(df.dense_first);
  EXPECT_EQ(df.dense_rows, dense);
  EXPECT_LE(df.relative_rms_error, kFloatBound);
  EXPECT_EQ(df.empty_clusters, 0u);
  // Independently of the reported error: decode through the reader.
  const Decoded dec = Decode(dir.File("df.ltm"));
  ASSERT_EQ(dec.x.size(), rows.x.size());
  EXPECT_LE(RelativeError(dec.x, rows.x), kFloatBound);
  // The partition: one cluster per subspace, the all-zero rows with the linear one's.
  std::map<int, std::set<uint32_t>> ids_of;
  for (uint64_t r = 0; r < kN; ++r) ids_of[rows.label[r] < 0 ? 0 : rows.label[r]].insert(dec.ids[r]);
  std::set<uint32_t> all;
  for (const auto& [label, ids] : ids_of) {
    EXPECT_EQ(ids.size(), 1u) << "subspace " << label << " split over clusters";
    all.insert(ids.begin(), ids.end());
  }
  EXPECT_EQ(all.size(), kK);

  // The mode and its parameters are in the provenance; the cpca block has the counts.
  const nlohmann::json params = Meta(dir.File("df.ltm"))["provenance"]["parameters"];
  EXPECT_EQ(params.value("dense_first", false), true);
  EXPECT_EQ(params.value("final_iterations", uint64_t{99}), 2u);
  const DenseCounts c = CountsOf(dir.File("df.ltm"));
  EXPECT_EQ(c.dense_rows, dense);
  EXPECT_EQ(c.dense_passes + c.final_passes, df.iterations);
  EXPECT_GE(c.final_passes, 1u);
  EXPECT_LE(c.final_passes, 2u);

  const CpcaResult plain = RunOk(Options(dir.File("in.ltm"), dir.File("plain.ltm"), DenseFirst::kOff));
  EXPECT_FALSE(plain.dense_first);
  EXPECT_EQ(plain.dense_rows, 0u);
  EXPECT_LE(plain.relative_rms_error, kFloatBound);
  // Rows streamed, from the pass counts: plain (P + 2)·N (P passes, evaluation, encoding);
  // dense-first P_d·N_d + (F + 2)·N. Growing through levels 0..S takes 2 passes per
  // intermediate level (--level-iterations) and at least 2 at the last (its convergence
  // test needs two), so P ≥ 2S + 2 = 8. With P_d = P the ratio (P·f + F + 2)/(P + 2),
  // f = N_d/N, decreases with P (its derivative has the sign of 2f − F − 2 < 0), so it is at
  // most (8f + F + 2)/10: ≈ 0.6 for f ≈ 1/4 and the default F = 2. The saving grows with the
  // passes: ≈ (1 − f) of the growth passes' rows.
  EXPECT_EQ(plain.rows_streamed, (plain.iterations + 2) * kN);
  EXPECT_EQ(df.rows_streamed, c.dense_passes * dense + (c.final_passes + 2) * kN);
  EXPECT_GE(c.dense_passes, 2 * kS + 2);
  EXPECT_EQ(plain.iterations, c.dense_passes) << "both modes grow the basis through the same levels here";
  const double f = static_cast<double>(dense) / kN;
  const double ratio = static_cast<double>(df.rows_streamed) / static_cast<double>(plain.rows_streamed);
  const double expected =
      (c.dense_passes * f + static_cast<double>(c.final_passes) + 2) / static_cast<double>(plain.iterations + 2);
  EXPECT_NEAR(ratio, expected, 1e-12);
  EXPECT_LE(ratio, ((2 * kS + 2) * f + static_cast<double>(c.final_passes) + 2) / (2 * kS + 4) + 1e-12);
  RecordProperty("rows_streamed_ratio", std::to_string(ratio));
  std::printf(
      "rows streamed: dense-first %llu, plain %llu (ratio %.3f; passes %llu dense + %llu final vs %llu); "
      "seconds: dense-first %.4f + %.4f, plain %.4f + %.4f\n",
      static_cast<unsigned long long>(df.rows_streamed), static_cast<unsigned long long>(plain.rows_streamed), ratio,
      static_cast<unsigned long long>(c.dense_passes), static_cast<unsigned long long>(c.final_passes),
      static_cast<unsigned long long>(plain.iterations), df.seconds_dense, df.seconds_final, plain.seconds_dense,
      plain.seconds_final);
}

// With noise off the subspaces both modes end in an LBG local optimum of the same
// objective at dimension S over all rows (dense-first's last passes are plain mode's
// passes); the dense rows are an unbiased quarter of every subspace, so they find the same
// partition and directions within the noise's sampling error (relative O(1/√(rows per
// cluster)) on the tail energy, about 2% here). 5% allows for that and one LBG pass less
// of refinement; 1e-6 for rounding.
TEST(CpcaDenseFirst, NoisyErrorCloseToPlain) {
  TempDir dir;
  const Rows rows = AffineRows(kK, kS, kD, kN, 0.05, 12);
  WriteInput(dir.File("noisy.ltm"), rows, 256, kN);
  const CpcaResult df = RunOk(Options(dir.File("noisy.ltm"), dir.File("df.ltm"), DenseFirst::kOn));
  const CpcaResult plain = RunOk(Options(dir.File("noisy.ltm"), dir.File("plain.ltm"), DenseFirst::kOff));
  EXPECT_GT(plain.relative_rms_error, 1e-3) << "noisy rows cannot be exact";
  EXPECT_LE(df.relative_rms_error, plain.relative_rms_error * 1.05 + 1e-6);
  std::printf("noisy: relative RMS error dense-first %.6g, plain %.6g (ratio %.4f)\n", df.relative_rms_error,
              plain.relative_rms_error, df.relative_rms_error / plain.relative_rms_error);
}

TEST(CpcaDenseFirst, SameContentForAnyJobsAndChunking) {
  TempDir dir;
  const Rows rows = AffineRows(kK, kS, kD, kN, 0.05, 13);
  WriteInput(dir.File("a.ltm"), rows, 64, 64);    // side array blocked like the matrix
  WriteInput(dir.File("b.ltm"), rows, 1000, kN);  // one side chunk (as row-transform passes it)
  std::vector<std::string> ref;
  for (const auto& [input, jobs] : std::vector<std::pair<std::string, int>>{{"a", 1}, {"a", 2}, {"b", 1}, {"b", 2}}) {
    CpcaOptions o =
        Options(dir.File(input + ".ltm"), dir.File(input + std::to_string(jobs) + "_out.ltm"), DenseFirst::kOn);
    o.jobs = jobs;
    const CpcaResult r = RunOk(o);
    EXPECT_TRUE(r.dense_first);
    const auto h = Hashes(o.output);
    ASSERT_EQ(h.size(), 3u);
    if (ref.empty()) ref = h;
    EXPECT_EQ(h, ref) << "input " << input << ", --jobs " << jobs;
  }
}

// The dense rows are read once and held in memory when they fit --mem-limit — beside the
// k-means++ sample (which is then taken from them) or after it — else streamed from the
// input in every dense pass: the same rows in the same blocks either way, so the same
// content. The limits come from the stage's own estimates: one byte under the peak with
// the sample taken from the cache (fixed + sample + cache), the cache is gathered after the
// sample (peak fixed + max(sample, passes' buffers + cache)); one byte under that, it does
// not fit (the cache is the larger here: about N/4 dense rows against a 256-row sample).
// D = 48: one pass block per pass; D = 2056: pass blocks of 256 rows (one sub-block), read
// and assigned two at a time with --jobs 2, one at a time with --jobs 1.
TEST(CpcaDenseFirst, SameContentWhetherDenseRowsAreCachedOrStreamed) {
  for (const auto& [d, n] : std::vector<std::pair<uint64_t, uint64_t>>{{kD, 4096}, {2056, 2048}}) {
    SCOPED_TRACE("D = " + std::to_string(d));
    TempDir dir;
    const Rows rows = AffineRows(kK, kS, d, n, 0.05, 22);
    WriteInput(dir.File("in.ltm"), rows, 300, 1000);  // chunks straddle pass blocks and sub-blocks
    CpcaOptions o = Options(dir.File("in.ltm"), dir.File("with-sample.ltm"), DenseFirst::kOn);
    o.sample_rows = 256;  // the same sample under every limit below (it is in the run's identity)
    o.mem_limit = 1ull << 30;
    const CpcaResult with_sample = RunOk(o);
    ASSERT_TRUE(with_sample.dense_first);
    EXPECT_EQ(with_sample.dense_cache_bytes, with_sample.dense_rows * (d * 4 + 8));
    EXPECT_TRUE(with_sample.dense_cache_sample);
    const auto ref = Hashes(o.output);
    const nlohmann::json provenance = Meta(o.output)["provenance"];

    o.output = dir.File("after-sample.ltm");
    o.mem_limit = with_sample.memory_bytes - 1;
    const CpcaResult after = RunOk(o);
    EXPECT_EQ(after.dense_cache_bytes, with_sample.dense_cache_bytes);
    EXPECT_FALSE(after.dense_cache_sample);
    EXPECT_LE(after.memory_bytes, o.mem_limit);

    o.output = dir.File("streamed.ltm");
    o.mem_limit = after.memory_bytes - 1;
    const CpcaResult streamed = RunOk(o);
    EXPECT_EQ(streamed.dense_cache_bytes, 0u);
    EXPECT_LE(streamed.memory_bytes, o.mem_limit);

    o.output = dir.File("one-job.ltm");
    o.mem_limit = 1ull << 30;
    o.jobs = 1;
    const CpcaResult one_job = RunOk(o);
    EXPECT_GT(one_job.dense_cache_bytes, 0u);

    for (const auto* r : {&after, &streamed, &one_job}) {
      EXPECT_EQ(r->iterations, with_sample.iterations);
      EXPECT_EQ(r->rows_streamed, with_sample.rows_streamed);
      EXPECT_EQ(r->squared_error, with_sample.squared_error);
    }
    for (const char* name : {"after-sample.ltm", "streamed.ltm", "one-job.ltm"}) {
      EXPECT_EQ(Hashes(dir.File(name)), ref) << name;
      EXPECT_EQ(Meta(dir.File(name))["provenance"], provenance) << name;
    }

    // Interrupted in the dense passes with the rows cached, resumed streaming them, and the
    // other way round (the limit is not part of the run's identity; the cache is rebuilt).
    const uint64_t cached_limit = 1ull << 30, streamed_limit = after.memory_bytes - 1;
    for (const auto& [first, second] :
         std::vector<std::pair<uint64_t, uint64_t>>{{cached_limit, streamed_limit}, {streamed_limit, cached_limit}}) {
      o.output = dir.File("cut-" + std::to_string(first) + ".ltm");
      o.jobs = 2;
      o.mem_limit = first;
      std::atomic<uint64_t> reports{0};
      Progress cut;
      cut.update = [&](uint64_t, uint64_t, const char*) { ++reports; };
      cut.cancelled = [&] { return reports.load() >= 3; };
      auto interrupted = RunCpca(o, cut);
      ASSERT_FALSE(interrupted.ok());
      EXPECT_EQ(interrupted.status().code(), StatusCode::kCancelled);
      o.mem_limit = second;
      const CpcaResult resumed = RunOk(o);
      EXPECT_TRUE(resumed.resumed);
      EXPECT_EQ(resumed.dense_cache_bytes > 0, second == cached_limit);
      EXPECT_EQ(Hashes(o.output), ref) << "cut with --mem-limit " << first << ", resumed with " << second;
    }
  }
}

TEST(CpcaDenseFirst, AutoFollowsTheSparseKindArray) {
  TempDir dir;
  const Rows rows = AffineRows(kK, kS, kD, kN, 0.05, 14);
  WriteInput(dir.File("sparse.ltm"), rows, 200, 200);
  const CpcaResult on = RunOk(Options(dir.File("sparse.ltm"), dir.File("on.ltm"), DenseFirst::kOn));
  const CpcaResult aut = RunOk(Options(dir.File("sparse.ltm"), dir.File("auto.ltm"), DenseFirst::kAuto));
  EXPECT_TRUE(aut.dense_first);
  EXPECT_EQ(aut.rows_streamed, on.rows_streamed);
  EXPECT_EQ(Hashes(dir.File("auto.ltm")), Hashes(dir.File("on.ltm")));
  EXPECT_EQ(Meta(dir.File("auto.ltm"))["provenance"], Meta(dir.File("on.ltm"))["provenance"]);
  // The same run either way: auto over the --dense-first output is a no-op, and reports
  // the mode and the rows streamed from the output.
  const CpcaResult again = RunOk(Options(dir.File("sparse.ltm"), dir.File("on.ltm"), DenseFirst::kAuto));
  EXPECT_TRUE(again.already_complete);
  EXPECT_TRUE(again.dense_first);
  EXPECT_EQ(again.dense_rows, on.dense_rows);
  EXPECT_EQ(again.rows_streamed, on.rows_streamed);

  // --no-dense-first on the same input: a plain run (no mode in the provenance).
  RunOk(Options(dir.File("sparse.ltm"), dir.File("off.ltm"), DenseFirst::kOff));
  EXPECT_FALSE(Meta(dir.File("off.ltm"))["provenance"]["parameters"].contains("dense_first"));
  EXPECT_FALSE(Meta(dir.File("off.ltm"))["cpca"].contains("dense_first"));
}

// Without the side array auto is plain mode: the run's parameters are those of builds
// before dense-first (so their outputs and checkpoints stay valid), and the content is the
// same as --no-dense-first's.
TEST(CpcaDenseFirst, AutoWithoutSparseKindIsPlain) {
  TempDir dir;
  const Rows rows = AffineRows(kK, kS, kD, kN, 0.05, 15);
  WriteInput(dir.File("dense.ltm"), rows, 256, 0);
  const CpcaResult aut = RunOk(Options(dir.File("dense.ltm"), dir.File("auto.ltm"), DenseFirst::kAuto));
  RunOk(Options(dir.File("dense.ltm"), dir.File("off.ltm"), DenseFirst::kOff));
  EXPECT_FALSE(aut.dense_first);
  EXPECT_EQ(aut.dense_rows, 0u);
  EXPECT_EQ(aut.rows_streamed, (aut.iterations + 2) * kN);
  EXPECT_EQ(Hashes(dir.File("auto.ltm")), Hashes(dir.File("off.ltm")));
  const nlohmann::json params = Meta(dir.File("auto.ltm"))["provenance"]["parameters"];
  std::vector<std::string> keys;
  for (const auto& [key, value] : params.items()) keys.push_back(key);
  EXPECT_EQ(keys, (std::vector<std::string>{"basis", "clusters", "growth_step", "level_iterations", "max_iterations",
                                            "oversample", "sample_rows", "seed", "tolerance"}));
  EXPECT_FALSE(Meta(dir.File("auto.ltm"))["cpca"].contains("dense_first"));
}

TEST(CpcaDenseFirst, RefusedWithoutSparseKindNamingTheFile) {
  TempDir dir;
  const Rows rows = AffineRows(kK, kS, kD, 512, 0.0, 16);
  WriteInput(dir.File("dense-only.ltm"), rows, 256, 0);
  auto r = RunCpca(Options(dir.File("dense-only.ltm"), dir.File("out.ltm"), DenseFirst::kOn), Progress{});
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.status().code(), StatusCode::kFailedPrecondition);
  EXPECT_NE(r.status().message().find(dir.File("dense-only.ltm")), std::string::npos) << r.status().message();
  EXPECT_NE(r.status().message().find("sparse_kind"), std::string::npos) << r.status().message();
  EXPECT_NE(r.status().message().find("--no-dense-first"), std::string::npos) << r.status().message();
  EXPECT_FALSE(std::filesystem::exists(dir.File("out.ltm")));
}

TEST(CpcaDenseFirst, NoDenseRowRefusedWhenAskedPlainWhenAuto) {
  TempDir dir;
  Rows rows = AffineRows(kK, kS, kD, 512, 0.0, 17);
  for (uint8_t& k : rows.kind)
    if (k == kDense) k = kSparse;
  WriteInput(dir.File("no-dense.ltm"), rows, 256, 256);
  auto r = RunCpca(Options(dir.File("no-dense.ltm"), dir.File("out.ltm"), DenseFirst::kOn), Progress{});
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.status().code(), StatusCode::kFailedPrecondition);
  EXPECT_NE(r.status().message().find(dir.File("no-dense.ltm")), std::string::npos) << r.status().message();
  EXPECT_NE(r.status().message().find("none of its 512 rows dense"), std::string::npos) << r.status().message();
  EXPECT_NE(r.status().message().find("--no-dense-first"), std::string::npos) << r.status().message();
  const CpcaResult aut = RunOk(Options(dir.File("no-dense.ltm"), dir.File("auto.ltm"), DenseFirst::kAuto));
  EXPECT_FALSE(aut.dense_first);
}

TEST(CpcaDenseFirst, FewerDenseRowsThanClustersRefused) {
  TempDir dir;
  Rows rows = AffineRows(kK, kS, kD, 512, 0.0, 18);
  uint64_t kept = 0;
  for (uint8_t& k : rows.kind)
    if (k == kDense && ++kept > kK - 1) k = kSparse;
  WriteInput(dir.File("few.ltm"), rows, 256, 256);
  auto r = RunCpca(Options(dir.File("few.ltm"), dir.File("out.ltm"), DenseFirst::kAuto), Progress{});
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("has 3 dense rows"), std::string::npos) << r.status().message();
  EXPECT_NE(r.status().message().find("--clusters 4"), std::string::npos) << r.status().message();
}

TEST(CpcaDenseFirst, UnknownKindRefusedNamingTheRow) {
  TempDir dir;
  Rows rows = AffineRows(kK, kS, kD, 512, 0.0, 19);
  rows.kind[300] = 7;
  WriteInput(dir.File("bad-kind.ltm"), rows, 256, 256);
  auto r = RunCpca(Options(dir.File("bad-kind.ltm"), dir.File("out.ltm"), DenseFirst::kAuto), Progress{});
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.status().code(), StatusCode::kDataLoss);
  EXPECT_NE(r.status().message().find("row 300 kind 7"), std::string::npos) << r.status().message();
  // --no-dense-first does not look at the side array.
  EXPECT_TRUE(RunCpca(Options(dir.File("bad-kind.ltm"), dir.File("off.ltm"), DenseFirst::kOff), Progress{}).ok());
}

TEST(CpcaDenseFirst, FinalIterationsAreIdentityAndCapped) {
  TempDir dir;
  const Rows rows = AffineRows(kK, kS, kD, kN, 0.05, 20);
  WriteInput(dir.File("in.ltm"), rows, 512, 512);
  CpcaOptions o = Options(dir.File("in.ltm"), dir.File("f0.ltm"), DenseFirst::kOn);
  o.final_iterations = 0;  // encode with the model of the dense rows
  const CpcaResult f0 = RunOk(o);
  EXPECT_EQ(CountsOf(o.output).final_passes, 0u);
  EXPECT_EQ(f0.rows_streamed, CountsOf(o.output).dense_passes * f0.dense_rows + 2 * kN);
  // Another --final-iterations is another run: refused over this output without --overwrite.
  o.final_iterations = 5;
  auto other = RunCpca(o, Progress{});
  ASSERT_FALSE(other.ok());
  EXPECT_NE(other.status().message().find("--overwrite"), std::string::npos) << other.status().message();
  o.output = dir.File("f5.ltm");
  o.tolerance = 0;  // stops only when a pass does not lower the error at all (an LBG fixed point)
  RunOk(o);
  EXPECT_LE(CountsOf(o.output).final_passes, 5u);
  EXPECT_GT(CountsOf(o.output).final_passes, 2u);
}

// Interrupted (Progress cancellation) after the m-th progress report — one per pass here
// (the rows fit one pass block), then the evaluation, then the encoding — the rerun
// resumes and writes the same content as an uninterrupted run.
TEST(CpcaDenseFirst, ResumesAfterInterruptionWithTheSameContent) {
  TempDir dir;
  const Rows rows = AffineRows(kK, kS, kD, kN, 0.05, 21);
  WriteInput(dir.File("in.ltm"), rows, 300, 300);
  const CpcaResult full = RunOk(Options(dir.File("in.ltm"), dir.File("full.ltm"), DenseFirst::kOn));
  const auto ref = Hashes(dir.File("full.ltm"));
  const DenseCounts c = CountsOf(dir.File("full.ltm"));
  ASSERT_GE(c.final_passes, 1u);
  // After: the first dense pass, the last dense pass, the first final pass, the evaluation.
  for (uint64_t m : {uint64_t{1}, c.dense_passes, c.dense_passes + 1, c.dense_passes + c.final_passes + 1}) {
    const std::string out = dir.File("cut" + std::to_string(m) + ".ltm");
    std::atomic<uint64_t> reports{0};
    Progress cut;
    cut.update = [&](uint64_t, uint64_t, const char*) { ++reports; };
    cut.cancelled = [&] { return reports.load() >= m; };
    auto first = RunCpca(Options(dir.File("in.ltm"), out, DenseFirst::kOn), cut);
    ASSERT_FALSE(first.ok()) << "not interrupted after report " << m;
    EXPECT_EQ(first.status().code(), StatusCode::kCancelled);
    EXPECT_TRUE(std::filesystem::exists(CpcaCheckpointPath(out)));
    const CpcaResult resumed = RunOk(Options(dir.File("in.ltm"), out, DenseFirst::kOn));
    EXPECT_TRUE(resumed.resumed) << "after report " << m;
    EXPECT_EQ(resumed.iterations, full.iterations);
    EXPECT_EQ(resumed.rows_streamed, full.rows_streamed);
    EXPECT_EQ(Hashes(out), ref) << "interrupted after report " << m;
    EXPECT_FALSE(std::filesystem::exists(CpcaCheckpointPath(out)));
  }
}

}  // namespace
}  // namespace ltb::stages
