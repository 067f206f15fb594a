// Column-transform cost: the adaptive depth search (ColumnCompressor::Choose, every depth,
// selection and the image-domain error) beside one plain full-depth forward transform of
// the same columns, in the same process, on the same in-memory data, one thread each.
// Repetitions alternate the two; medians and their ratio are printed as one JSON line,
// in wall time and in this thread's CPU time (steadier on a shared machine).
//
// usage: ltb_column_transform_bench COLS.ltm [--filter legall53] [--terms N] [--columns K] [--reps 5]
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <ctime>
#include <string>
#include <vector>

#include "format/io/container_reader.h"
#include "stages/column_transform/column_compressor.h"
#include "stages/common/basis.h"

using namespace ltb;

namespace {

double Median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v.size() % 2 ? v[v.size() / 2] : 0.5 * (v[v.size() / 2 - 1] + v[v.size() / 2]);
}

double ThreadCpuSeconds() {
  timespec ts{};
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
  return static_cast<double>(ts.tv_sec) + 1e-9 * static_cast<double>(ts.tv_nsec);
}

int Fail(const std::string& s) {
  std::fprintf(stderr, "column_transform_bench: %s\n", s.c_str());
  return 1;
}

}  // namespace

int main(int argc, char** argv) {
  if (argc < 2)
    return Fail("usage: ltb_column_transform_bench COLS.ltm [--filter F] [--terms N] [--columns K] [--reps R]");
  std::string path = argv[1], filter_name = "legall53";
  uint64_t terms = 0, max_columns = 0;
  int reps = 5;
  for (int i = 2; i + 1 < argc; i += 2) {
    std::string k = argv[i], v = argv[i + 1];
    if (k == "--filter")
      filter_name = v;
    else if (k == "--terms")
      terms = std::stoull(v);
    else if (k == "--columns")
      max_columns = std::stoull(v);
    else if (k == "--reps")
      reps = std::stoi(v);
    else
      return Fail("unknown option " + k);
  }
  auto filter = wavelet::ParseFilter(filter_name);
  if (!filter.ok()) return Fail(filter.status().message());
  auto in = io::ContainerReader::Open(path);
  if (!in.ok()) return Fail(in.status().message());
  const auto& a = in->metadata().matrix();
  auto image = stages::ReadImageRows(in->metadata());
  if (!image || a.layout != format::Layout::kCols) return Fail(path + ": needs column blocks of an image");
  const uint64_t w = image->width, h = image->height, pixels = w * h;
  if (terms == 0) terms = std::max<uint64_t>(1, pixels / 20);
  // Load the columns (skipping empty ones, which the stage skips too).
  std::vector<float> data;
  uint64_t ncols = 0;
  for (uint64_t c = 0; c < a.ChunkCount() && (max_columns == 0 || ncols < max_columns); ++c) {
    auto chunk = in->ReadChunk(0, c);
    if (!chunk.ok()) return Fail(chunk.status().message());
    auto v = chunk->as<float>();
    for (uint64_t k = 0; k < chunk->extent().cols && (max_columns == 0 || ncols < max_columns); ++k) {
      const float* col = v.data() + k * pixels;
      bool any = false;
      for (uint64_t p = 0; p < pixels && !any; ++p) any = col[p] != 0.0f;
      if (!any) continue;
      data.insert(data.end(), col, col + pixels);
      ++ncols;
    }
  }
  const int depth = wavelet::MaxDepth(w, h);
  auto comp = stages::ColumnCompressor::Create(*filter, w, h, 0, depth);
  if (!comp.ok()) return Fail(comp.status().message());
  constexpr size_t L = stages::ColumnCompressor::kLanes;
  std::vector<float> lanes(pixels * L), scratch(wavelet::ScratchSize(w, h, L));
  double sink = 0;
  auto plain = [&] {
    for (uint64_t c0 = 0; c0 < ncols; c0 += L) {
      size_t n = std::min<uint64_t>(L, ncols - c0);
      std::fill(lanes.begin(), lanes.end(), 0.0f);
      for (size_t k = 0; k < n; ++k) {
        const float* col = data.data() + (c0 + k) * pixels;
        for (uint64_t p = 0; p < pixels; ++p) lanes[p * L + k] = col[p];
      }
      wavelet::Forward2D(*filter, lanes.data(), w, h, L, depth, scratch.data());
      sink += lanes[0];
    }
  };
  std::vector<stages::ColumnChoice> out(L);
  stages::Selection sel[L];
  for (auto& s : sel) s.terms = terms;
  uint64_t kept = 0;
  auto adaptive = [&] {
    kept = 0;
    for (uint64_t c0 = 0; c0 < ncols; c0 += L) {
      size_t n = std::min<uint64_t>(L, ncols - c0);
      const float* cols[L];
      for (size_t k = 0; k < n; ++k) cols[k] = data.data() + (c0 + k) * pixels;
      Status s = comp->Choose(cols, n, sel, nullptr, out.data());
      if (!s.ok()) std::abort();
      for (size_t k = 0; k < n; ++k) kept += out[k].index.size();
    }
  };
  using clock = std::chrono::steady_clock;
  std::vector<double> tp, ta, cp, ca;
  for (int r = 0; r < reps; ++r) {
    auto t0 = clock::now();
    double c0 = ThreadCpuSeconds();
    plain();
    auto t1 = clock::now();
    double c1 = ThreadCpuSeconds();
    adaptive();
    auto t2 = clock::now();
    double c2 = ThreadCpuSeconds();
    tp.push_back(std::chrono::duration<double>(t1 - t0).count());
    ta.push_back(std::chrono::duration<double>(t2 - t1).count());
    cp.push_back(c1 - c0);
    ca.push_back(c2 - c1);
  }
  double mp = Median(tp), ma = Median(ta), mcp = Median(cp), mca = Median(ca);
  std::printf(
      "{\"file\": \"%s\", \"filter\": \"%s\", \"image\": [%llu, %llu], \"depths\": %d, \"columns\": %llu, \"terms\": "
      "%llu, "
      "\"reps\": %d, \"plain_forward_s\": %.4f, \"adaptive_s\": %.4f, \"ratio\": %.3f, \"plain_min_s\": %.4f, "
      "\"adaptive_min_s\": %.4f, \"plain_cpu_s\": %.4f, \"adaptive_cpu_s\": %.4f, \"cpu_ratio\": %.3f, \"kept\": "
      "%llu, \"sink\": %g}\n",
      path.c_str(), filter_name.c_str(), static_cast<unsigned long long>(w), static_cast<unsigned long long>(h),
      depth + 1, static_cast<unsigned long long>(ncols), static_cast<unsigned long long>(terms), reps, mp, ma, ma / mp,
      *std::min_element(tp.begin(), tp.end()), *std::min_element(ta.begin(), ta.end()), mcp, mca, mca / mcp,
      static_cast<unsigned long long>(kept), sink);
  return 0;
}
