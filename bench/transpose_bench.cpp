// ltb_transpose_bench: input and checks for the `ltbake transpose` benchmark
// (bench/run_transpose.sh). Every element is a pure function of its position,
//   M[r][c] = a float in [-1, 1) from splitmix64(seed + r * cols + c),
// so the .ltm input, the raw stream fed to the HDF5 baseline and the checks all agree on
// the matrix without storing a second copy of it.
//
//   ltb_transpose_bench make PATH --rows R --cols C [--chunk-bytes 8M]
//       Writes an R x C f32 row-block container (layout rows, raw encoding, chunks of
//       about --chunk-bytes), sealed (Finish() fdatasyncs). One JSON line.
//   ltb_transpose_bench raw --rows R --cols C
//       The same matrix to stdout, row-major f32 (for bench/h5py_transpose.py convert).
//   ltb_transpose_bench check PATH [--samples K]
//       Reads K random columns (plus the first and last) of a transposed container
//       (layout cols) and compares every element with M. One JSON line; exit 1 on a
//       mismatch.
//   ltb_transpose_bench panel-read PATH [--col0 C] [--panel-cols N] [--jobs J] [--prefetch-rows K]
//       Reads what one `ltbake transpose` panel reads: columns [C, C+N) of every row of a
//       row-block container, one pread per row into a 32-row tile, J threads taking row
//       blocks from a shared counter (as the stage does; N defaults to its 2043 columns
//       at 65536 rows and --mem-limit 1GiB). --prefetch-rows K: before each tile, also
//       keep posix_fadvise(WILLNEED) issued for the same column range of the next K rows
//       (within the row block), to see whether a deeper I/O queue helps when the input is
//       not cached.
//       Evict the file first to measure the disk. One JSON line.
#include <fcntl.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <nlohmann/json.hpp>
#include <string>
#include <thread>
#include <vector>

#include "format/array_spec.h"
#include "format/chunk_codec.h"
#include "format/io/container_reader.h"
#include "format/io/container_writer.h"
#include "stages/common/quantity.h"

namespace {

using Clock = std::chrono::steady_clock;
constexpr uint64_t kSeed = 0x5eed1e55ull;

[[noreturn]] void Die(const std::string& msg) {
  std::fprintf(stderr, "ltb_transpose_bench: %s\n", msg.c_str());
  std::exit(1);
}

double Seconds(Clock::time_point a, Clock::time_point b) { return std::chrono::duration<double>(b - a).count(); }

inline uint64_t Mix(uint64_t z) {
  z += 0x9e3779b97f4a7c15ull;
  z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ull;
  z = (z ^ (z >> 27)) * 0x94d049bb133111ebull;
  return z ^ (z >> 31);
}

// M[r][c] for a matrix with `cols` columns.
inline float Value(uint64_t r, uint64_t c, uint64_t cols) {
  return static_cast<float>(Mix(kSeed + r * cols + c) >> 40) * (2.0f / 16777216.0f) - 1.0f;
}

void FillRows(float* dst, uint64_t row0, uint64_t nrows, uint64_t cols) {
  for (uint64_t r = 0; r < nrows; ++r)
    for (uint64_t c = 0; c < cols; ++c) dst[r * cols + c] = Value(row0 + r, c, cols);
}

// Sizes as every ltbake size flag reads them (stages/common/quantity.h).
uint64_t ParseBytes(const std::string& s) {
  auto bytes = ltb::stages::ParseByteSize(s);
  if (!bytes.ok()) Die(bytes.status().message());
  return *bytes;
}

struct Args {
  std::string mode, path;
  uint64_t rows = 65536, cols = 24576;
  uint64_t chunk_bytes = 8ull << 20;
  uint64_t samples = 6;
  uint64_t col0 = 0, panel_cols = 2043, prefetch_rows = 0;
  int jobs = 2;
};

Args ParseArgs(int argc, char** argv) {
  if (argc < 2) {
    Die("usage: ltb_transpose_bench make PATH --rows R --cols C [--chunk-bytes 8M]\n"
        "       ltb_transpose_bench raw --rows R --cols C\n"
        "       ltb_transpose_bench check PATH [--samples K]\n"
        "       ltb_transpose_bench panel-read PATH [--col0 C] [--panel-cols N] [--jobs J] [--prefetch-rows K]");
  }
  Args a;
  a.mode = argv[1];
  int i = 2;
  if (a.mode != "raw") {
    if (argc < 3) Die(a.mode + ": needs a PATH");
    a.path = argv[2];
    i = 3;
  }
  for (; i < argc; ++i) {
    std::string f = argv[i];
    auto next = [&]() -> std::string {
      if (i + 1 >= argc) Die(f + " needs a value");
      return argv[++i];
    };
    if (f == "--rows")
      a.rows = std::strtoull(next().c_str(), nullptr, 10);
    else if (f == "--cols")
      a.cols = std::strtoull(next().c_str(), nullptr, 10);
    else if (f == "--chunk-bytes")
      a.chunk_bytes = ParseBytes(next());
    else if (f == "--samples")
      a.samples = std::strtoull(next().c_str(), nullptr, 10);
    else if (f == "--col0")
      a.col0 = std::strtoull(next().c_str(), nullptr, 10);
    else if (f == "--panel-cols")
      a.panel_cols = std::strtoull(next().c_str(), nullptr, 10);
    else if (f == "--prefetch-rows")
      a.prefetch_rows = std::strtoull(next().c_str(), nullptr, 10);
    else if (f == "--jobs")
      a.jobs = std::max(1, std::atoi(next().c_str()));
    else
      Die("unknown flag " + f);
  }
  if (a.rows == 0 || a.cols == 0) Die("--rows and --cols must be positive");
  return a;
}

int Make(const Args& a) {
  ltb::format::ArraySpec spec;
  spec.name = "matrix";
  spec.dtype = ltb::format::DType::kF32;
  spec.rows = a.rows;
  spec.cols = a.cols;
  spec.layout = ltb::format::Layout::kRows;
  spec.block = ltb::format::BlockForTargetBytes(spec.rows, spec.cols, spec.dtype, spec.layout, a.chunk_bytes);
  nlohmann::json meta = {{"arrays", {spec.ToJson()}},
                         {"note", "ltb_transpose_bench: M[r][c] = f(splitmix64(seed + r*cols + c))"}};
  std::remove(a.path.c_str());
  auto t0 = Clock::now();
  auto w = ltb::io::ContainerWriter::Open(a.path, meta);
  if (!w.ok()) Die(w.status().message());
  ltb::format::EncodeOptions eo;
  eo.zstd = false;
  std::vector<float> buf(spec.block * spec.cols);
  for (uint64_t i = 0; i < spec.ChunkCount(); ++i) {
    ltb::format::ChunkExtent e = spec.Extent(i);
    FillRows(buf.data(), e.row0, e.rows, spec.cols);
    ltb::Status s = w->Put(
        0, i, ltb::format::ByteSpan(reinterpret_cast<const std::byte*>(buf.data()), e.rows * spec.cols * sizeof(float)),
        eo);
    if (!s.ok()) Die(s.message());
  }
  ltb::Status s = w->Finish();
  if (!s.ok()) Die(s.message());
  nlohmann::json out = {{"mode", "make"},
                        {"path", a.path},
                        {"rows", spec.rows},
                        {"cols", spec.cols},
                        {"block_rows", spec.block},
                        {"chunks", spec.ChunkCount()},
                        {"payload_bytes", spec.rows * spec.cols * 4},
                        {"seconds", Seconds(t0, Clock::now())}};
  std::printf("%s\n", out.dump().c_str());
  return 0;
}

int Raw(const Args& a) {
  const uint64_t band = std::max<uint64_t>(1, (8ull << 20) / (a.cols * 4));
  std::vector<float> buf(band * a.cols);
  for (uint64_t r0 = 0; r0 < a.rows; r0 += band) {
    uint64_t n = std::min(band, a.rows - r0);
    FillRows(buf.data(), r0, n, a.cols);
    const char* p = reinterpret_cast<const char*>(buf.data());
    size_t left = n * a.cols * 4;
    while (left > 0) {
      ssize_t k = ::write(1, p, left);
      if (k < 0) {
        if (errno == EINTR) continue;
        return 1;  // the reader went away
      }
      p += k;
      left -= static_cast<size_t>(k);
    }
  }
  return 0;
}

int Check(const Args& a) {
  auto r = ltb::io::ContainerReader::Open(a.path);
  if (!r.ok()) Die(r.status().message());
  const ltb::format::ArraySpec& spec = r->metadata().matrix();
  if (spec.layout != ltb::format::Layout::kCols) Die(a.path + ": not in column blocks");
  std::vector<uint64_t> cols = {0, spec.cols - 1};
  uint64_t s = 0x243f6a8885a308d3ull;
  for (uint64_t k = 0; k < a.samples; ++k) cols.push_back(Mix(s += 0x9e3779b97f4a7c15ull) % spec.cols);
  uint64_t checked = 0, mismatches = 0;
  for (uint64_t c : cols) {
    uint64_t chunk = c / spec.block;
    auto ch = r->ReadChunk(0, chunk);
    if (!ch.ok()) Die(ch.status().message());
    ltb::format::ChunkExtent e = ch->extent();
    auto v = ch->as<float>();
    const float* col = v.data() + (c - e.col0) * spec.rows;
    for (uint64_t row = 0; row < spec.rows; ++row) {
      float want = Value(row, c, spec.cols);
      if (std::memcmp(&col[row], &want, 4) != 0) ++mismatches;
      ++checked;
    }
  }
  nlohmann::json out = {{"mode", "check"},     {"path", a.path},           {"rows", spec.rows},
                        {"cols", spec.cols},   {"block_cols", spec.block}, {"columns_checked", cols},
                        {"elements", checked}, {"mismatches", mismatches}, {"ok", mismatches == 0}};
  std::printf("%s\n", out.dump().c_str());
  return mismatches == 0 ? 0 : 1;
}

int PanelRead(const Args& a) {
  auto r = ltb::io::ContainerReader::Open(a.path);
  if (!r.ok()) Die(r.status().message());
  const ltb::format::ArraySpec& spec = r->metadata().matrix();
  if (spec.layout != ltb::format::Layout::kRows || spec.dtype != ltb::format::DType::kF32) Die("needs f32 row blocks");
  if (a.col0 + a.panel_cols > spec.cols) Die("--col0 + --panel-cols beyond the last column");
  int fd = ::open(a.path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) Die(a.path + ": " + std::strerror(errno));
  constexpr uint64_t kTile = 32;
  const uint64_t seg = a.panel_cols * 4, cols = spec.cols;
  std::atomic<uint64_t> next{0}, bytes{0}, calls{0}, advised{0};
  auto t0 = Clock::now();
  auto worker = [&] {
    std::vector<float> tile(kTile * a.panel_cols);
    for (;;) {
      uint64_t ci = next.fetch_add(1);
      if (ci >= spec.ChunkCount()) return;
      const ltb::format::IndexEntry* e = r->Find(0, ci);
      if (e->header.encoding != static_cast<uint16_t>(ltb::format::Encoding::kRaw)) Die("needs raw chunks");
      ltb::format::ChunkExtent ex = spec.Extent(ci);
      uint64_t payload = e->frame_offset + ltb::format::kFrameHeaderSize;
      auto off = [&](uint64_t row) { return static_cast<off_t>(payload + (row * cols + a.col0) * 4); };
      uint64_t advised_to = 0;  // rows [0, advised_to) of this block have been advised
      for (uint64_t r0 = 0; r0 < ex.rows; r0 += kTile) {
        uint64_t nr = std::min(kTile, ex.rows - r0);
        if (a.prefetch_rows > 0) {  // keep the next K rows (within this row block) in flight
          for (uint64_t want = std::min(ex.rows, r0 + nr + a.prefetch_rows); advised_to < want; ++advised_to) {
            ::posix_fadvise(fd, off(advised_to), static_cast<off_t>(seg), POSIX_FADV_WILLNEED);
            advised++;
          }
        }
        for (uint64_t row = r0; row < r0 + nr; ++row) {
          char* dst = reinterpret_cast<char*>(tile.data() + (row - r0) * a.panel_cols);
          size_t done = 0;
          while (done < seg) {
            ssize_t k = ::pread(fd, dst + done, seg - done, off(row) + static_cast<off_t>(done));
            if (k <= 0) Die("pread failed");
            done += static_cast<size_t>(k);
          }
          calls++;
          bytes += seg;
        }
      }
    }
  };
  std::vector<std::thread> threads;
  for (int t = 1; t < a.jobs; ++t) threads.emplace_back(worker);
  worker();
  for (auto& t : threads) t.join();
  double secs = Seconds(t0, Clock::now());
  ::close(fd);
  nlohmann::json out = {{"mode", "panel-read"},
                        {"path", a.path},
                        {"col0", a.col0},
                        {"panel_cols", a.panel_cols},
                        {"segment_bytes", seg},
                        {"jobs", a.jobs},
                        {"prefetch_rows", a.prefetch_rows},
                        {"preads", calls.load()},
                        {"fadvise_calls", advised.load()},
                        {"bytes", bytes.load()},
                        {"seconds", secs},
                        {"gb_per_s", bytes.load() / secs / 1e9}};
  std::printf("%s\n", out.dump().c_str());
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  Args a = ParseArgs(argc, argv);
  if (a.mode == "make") return Make(a);
  if (a.mode == "raw") return Raw(a);
  if (a.mode == "check") return Check(a);
  if (a.mode == "panel-read") return PanelRead(a);
  Die("unknown mode '" + a.mode + "' (make, raw, check, panel-read)");
}
