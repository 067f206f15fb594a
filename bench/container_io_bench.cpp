// ltm_io_bench: write and read throughput of the .ltm container, for comparison with dd
// on the same disk (bench/run_container_io.sh drives it). One JSON line per run.
//
//   ltm_io_bench write PATH [--bytes N] [--chunk-bytes M] [--sync-each-chunk]
//       Writes a container of about N bytes of random f32 (rows x 6144 columns, raw
//       encoding, chunks of about M bytes) and seals it (Finish() fdatasyncs).
//       A producer thread prepares and checksums chunks while the main thread appends.
//   ltm_io_bench read PATH [--no-verify] [--threads T] [--prefetch K]
//       Reads every chunk through ContainerReader::ReadChunk (zero-copy mmap, checksum
//       verified unless --no-verify), sums its floats, and reports time, throughput and
//       its own peak RSS. Default: one thread, no prefetch (the plain loop a stage
//       would write). --threads T: T threads read chunks concurrently. --prefetch K:
//       posix_fadvise(WILLNEED) the next K chunks before reading each one.
//   ltm_io_bench evict PATH      fdatasync + posix_fadvise(DONTNEED) on the whole file
//   ltm_io_bench resident PATH   bytes of PATH in the page cache (mincore)
//   ltm_io_bench gen --bytes N   N bytes of the same random data to stdout (for dd)
#include <fcntl.h>
#include <sys/mman.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <deque>
#include <fstream>
#include <mutex>
#include <nlohmann/json.hpp>
#include <optional>
#include <span>
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
constexpr uint64_t kCols = 6144;  // R = 32: 6 * 32 * 32 cubemap texels per row
constexpr uint64_t kRowBytes = kCols * sizeof(float);
constexpr int kPoolBuffers = 4;

[[noreturn]] void Die(const std::string& msg) {
  std::fprintf(stderr, "ltm_io_bench: %s\n", msg.c_str());
  std::exit(1);
}

double Seconds(Clock::time_point a, Clock::time_point b) { return std::chrono::duration<double>(b - a).count(); }

uint64_t SplitMix64(uint64_t& s) {
  uint64_t z = (s += 0x9e3779b97f4a7c15ull);
  z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ull;
  z = (z ^ (z >> 27)) * 0x94d049bb133111ebull;
  return z ^ (z >> 31);
}

// A float uniform in [-1, 1) from the top 24 bits of x.
float ToFloat(uint64_t x) { return static_cast<float>(x >> 40) * (2.0f / 16777216.0f) - 1.0f; }

void FillRandom(std::vector<float>& v, uint64_t seed) {
  uint64_t s = seed;
  for (size_t i = 0; i + 1 < v.size(); i += 2) {
    uint64_t x = SplitMix64(s);
    v[i] = ToFloat(x);
    v[i + 1] = ToFloat(x << 24);
  }
  if (v.size() % 2) v.back() = ToFloat(SplitMix64(s));
}

// Makes chunk `chunk` differ from every other chunk that used the same pool buffer:
// overwrites 16 words spread over the buffer with values derived from the chunk index.
void Tweak(std::vector<float>& v, uint64_t chunk, size_t floats) {
  uint64_t s = chunk * 0x2545f4914f6cdd1dull + 1;
  for (size_t k = 0; k < 16; ++k) v[(floats - 1) * k / 15] = ToFloat(SplitMix64(s));
}

// Peak resident set size of this process in KiB (VmHWM), and the current one (VmRSS).
std::pair<long, long> RssKiB() {
  std::ifstream f("/proc/self/status");
  std::string line;
  long hwm = -1, rss = -1;
  while (std::getline(f, line)) {
    if (line.rfind("VmHWM:", 0) == 0) hwm = std::atol(line.c_str() + 6);
    if (line.rfind("VmRSS:", 0) == 0) rss = std::atol(line.c_str() + 6);
  }
  if (hwm < 0) {
    rusage ru{};
    getrusage(RUSAGE_SELF, &ru);
    hwm = ru.ru_maxrss;
  }
  return {hwm, rss};
}

// Sizes as every ltbake size flag reads them (stages/common/quantity.h).
uint64_t ParseBytes(const std::string& s) {
  auto bytes = ltb::stages::ParseByteSize(s);
  if (!bytes.ok()) Die(bytes.status().message());
  return *bytes;
}

struct Args {
  std::string mode, path;
  uint64_t bytes = 4ull << 30;
  uint64_t chunk_bytes = 8ull << 20;
  bool verify = true;
  int threads = 1;
  uint64_t prefetch = 0;
  bool sync_each_chunk = false;
};

Args ParseArgs(int argc, char** argv) {
  if (argc < 2) {
    Die("usage: ltm_io_bench write PATH [--bytes N] [--chunk-bytes M] [--sync-each-chunk]\n"
        "       ltm_io_bench read PATH [--no-verify] [--threads T] [--prefetch K]\n"
        "       ltm_io_bench evict PATH | resident PATH | gen --bytes N");
  }
  Args a;
  a.mode = argv[1];
  int i = 2;
  if (a.mode != "gen") {
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
    if (f == "--bytes")
      a.bytes = ParseBytes(next());
    else if (f == "--chunk-bytes")
      a.chunk_bytes = ParseBytes(next());
    else if (f == "--no-verify")
      a.verify = false;
    else if (f == "--threads")
      a.threads = std::max(1, std::atoi(next().c_str()));
    else if (f == "--prefetch")
      a.prefetch = std::strtoull(next().c_str(), nullptr, 10);
    else if (f == "--sync-each-chunk")
      a.sync_each_chunk = true;
    else
      Die("unknown flag " + f);
  }
  return a;
}

// A bounded queue of pool buffer slots between the producer and the writer.
struct Ready {
  uint64_t chunk;
  int slot;
  ltb::format::EncodedChunk encoded;
};

int Write(const Args& a) {
  ltb::format::ArraySpec spec;
  spec.name = "matrix";
  spec.dtype = ltb::format::DType::kF32;
  spec.cols = kCols;
  spec.rows = a.bytes / kRowBytes;
  if (spec.rows == 0) Die("--bytes is smaller than one row (" + std::to_string(kRowBytes) + " bytes)");
  spec.layout = ltb::format::Layout::kRows;
  spec.block = ltb::format::BlockForTargetBytes(spec.rows, spec.cols, spec.dtype, spec.layout, a.chunk_bytes);
  nlohmann::json meta = {{"arrays", {spec.ToJson()}}, {"note", "ltm_io_bench random f32"}};
  const uint64_t chunks = spec.ChunkCount();
  const size_t chunk_floats = spec.block * kCols;

  // The random pool, filled once before timing starts.
  std::vector<std::vector<float>> pool(kPoolBuffers, std::vector<float>(chunk_floats));
  for (int b = 0; b < kPoolBuffers; ++b) FillRandom(pool[b], 0x1234567ull + b);

  std::remove(a.path.c_str());
  auto t0 = Clock::now();
  ltb::io::WriterOptions wo;
  wo.sync_each_chunk = a.sync_each_chunk;
  auto w = ltb::io::ContainerWriter::Open(a.path, meta, wo);
  if (!w.ok()) Die(w.status().message());

  std::mutex mu;
  std::condition_variable cv;
  std::deque<int> free_slots;
  for (int b = 0; b < kPoolBuffers; ++b) free_slots.push_back(b);
  std::deque<Ready> ready;
  bool failed = false;
  double producer_busy = 0;

  std::thread producer([&] {
    ltb::format::EncodeOptions eo;
    eo.zstd = false;  // raw: the I/O path, not the compressor, is measured
    for (uint64_t i = 0; i < chunks; ++i) {
      int slot;
      {
        std::unique_lock<std::mutex> lock(mu);
        cv.wait(lock, [&] { return !free_slots.empty() || failed; });
        if (failed) return;
        slot = free_slots.front();
        free_slots.pop_front();
      }
      auto p0 = Clock::now();
      uint64_t n = spec.ChunkBytes(i);
      Tweak(pool[slot], i, n / sizeof(float));
      ltb::format::ByteSpan data(reinterpret_cast<const std::byte*>(pool[slot].data()), n);
      ltb::format::EncodedChunk enc = ltb::format::EncodeChunk(data, eo);  // checksums the chunk
      producer_busy += Seconds(p0, Clock::now());
      {
        std::lock_guard<std::mutex> lock(mu);
        ready.push_back({i, slot, std::move(enc)});
      }
      cv.notify_all();
    }
  });

  double append_seconds = 0;
  for (uint64_t done = 0; done < chunks; ++done) {
    std::optional<Ready> r;
    {
      std::unique_lock<std::mutex> lock(mu);
      cv.wait(lock, [&] { return !ready.empty(); });
      r.emplace(std::move(ready.front()));
      ready.pop_front();
    }
    auto a0 = Clock::now();
    ltb::Status s = w->Append(0, r->chunk, r->encoded);
    append_seconds += Seconds(a0, Clock::now());
    if (!s.ok()) {
      {
        std::lock_guard<std::mutex> lock(mu);
        failed = true;
      }
      cv.notify_all();
      producer.join();
      Die(s.message());
    }
    {
      std::lock_guard<std::mutex> lock(mu);
      free_slots.push_back(r->slot);
    }
    cv.notify_all();
  }
  producer.join();
  auto f0 = Clock::now();
  ltb::Status s = w->Finish();
  if (!s.ok()) Die(s.message());
  auto t1 = Clock::now();

  struct stat st {};
  ::stat(a.path.c_str(), &st);
  uint64_t payload = spec.rows * kRowBytes;
  double secs = Seconds(t0, t1);
  auto [hwm, rss] = RssKiB();
  nlohmann::json out = {{"mode", "write"},
                        {"path", a.path},
                        {"bytes", payload},
                        {"file_bytes", static_cast<uint64_t>(st.st_size)},
                        {"rows", spec.rows},
                        {"cols", spec.cols},
                        {"chunks", chunks},
                        {"chunk_bytes", spec.ChunkBytes(0)},
                        {"sync_each_chunk", a.sync_each_chunk},
                        {"seconds", secs},
                        {"append_seconds", append_seconds},
                        {"finish_seconds", Seconds(f0, t1)},
                        {"producer_busy_seconds", producer_busy},
                        {"gb_per_s", static_cast<double>(payload) / secs / 1e9},
                        {"file_gb_per_s", static_cast<double>(st.st_size) / secs / 1e9},
                        {"peak_rss_kib", hwm}};
  std::printf("%s\n", out.dump().c_str());
  return 0;
}

// Sums a chunk's floats; 16 independent accumulators vectorize without reassociating.
double SumFloats(std::span<const float> v) {
  float acc[16] = {};
  size_t n = v.size() / 16 * 16;
  for (size_t j = 0; j < n; j += 16)
    for (int k = 0; k < 16; ++k) acc[k] += v[j + k];
  for (size_t j = n; j < v.size(); ++j) acc[0] += v[j];
  double total = 0;
  for (float x : acc) total += x;
  return total;
}

// Reads every chunk of array 0 in order. With --threads T, T threads take chunks from a
// shared counter (still roughly in file order). With --prefetch K, before reading chunk
// i the caller asks the kernel (posix_fadvise WILLNEED on its own descriptor) to read
// chunks i+1..i+K ahead, using the frame offsets the reader exposes through Find().
int Read(const Args& a) {
  auto t0 = Clock::now();
  auto r = ltb::io::ContainerReader::Open(a.path);
  if (!r.ok()) Die(r.status().message());
  const ltb::format::ArraySpec& spec = r->metadata().matrix();
  const uint64_t chunks = spec.ChunkCount();
  ltb::io::ReadOptions ro;
  ro.verify_checksum = a.verify;
  ro.sequential = true;

  int prefetch_fd = -1;
  if (a.prefetch > 0) {
    prefetch_fd = ::open(a.path.c_str(), O_RDONLY | O_CLOEXEC);
    if (prefetch_fd < 0) Die(a.path + ": " + std::strerror(errno));
  }
  auto prefetch = [&](uint64_t chunk) {
    if (chunk >= chunks) return;
    const ltb::format::IndexEntry* e = r->Find(0, chunk);
    if (e == nullptr) return;
    ::posix_fadvise(prefetch_fd, static_cast<off_t>(e->frame_offset), static_cast<off_t>(e->header.FrameSize()),
                    POSIX_FADV_WILLNEED);
  };

  std::mutex mu;
  uint64_t next = 0, prefetched = 0;  // next chunk to read; chunks [0, prefetched) asked for
  double total = 0;
  uint64_t bytes = 0;
  long rss_max_during = 0;
  std::string error;
  auto worker = [&] {
    for (;;) {
      uint64_t i;
      {
        std::lock_guard<std::mutex> lock(mu);
        if (next >= chunks || !error.empty()) return;
        i = next++;
        if (a.prefetch > 0) {  // ask for chunks (i, i + K] not asked for yet
          uint64_t want = std::min(chunks, i + 1 + a.prefetch);
          for (prefetched = std::max(prefetched, i + 1); prefetched < want; ++prefetched) prefetch(prefetched);
        }
      }
      auto c = r->ReadChunk(0, i, ro);
      if (!c.ok()) {
        std::lock_guard<std::mutex> lock(mu);
        error = c.status().message();
        return;
      }
      double sum = SumFloats(c->as<float>());
      // Sample RSS while the chunk is mapped (VmHWM is updated lazily by the kernel).
      long rss = (i % 16 == 0 || i == chunks / 2) ? RssKiB().second : 0;
      std::lock_guard<std::mutex> lock(mu);
      total += sum;
      bytes += c->bytes().size();
      rss_max_during = std::max(rss_max_during, rss);
    }
  };
  std::vector<std::thread> threads;
  for (int t = 1; t < a.threads; ++t) threads.emplace_back(worker);
  worker();
  for (auto& t : threads) t.join();
  if (!error.empty()) Die(error);
  auto t1 = Clock::now();
  if (prefetch_fd >= 0) ::close(prefetch_fd);
  double secs = Seconds(t0, t1);
  auto [hwm, rss] = RssKiB();
  nlohmann::json out = {{"mode", "read"},
                        {"path", a.path},
                        {"verify_checksum", a.verify},
                        {"threads", a.threads},
                        {"prefetch_chunks", a.prefetch},
                        {"bytes", bytes},
                        {"file_bytes", r->file_size()},
                        {"chunks", chunks},
                        {"chunk_bytes", spec.ChunkBytes(0)},
                        {"seconds", secs},
                        {"gb_per_s", static_cast<double>(bytes) / secs / 1e9},
                        {"file_gb_per_s", static_cast<double>(r->file_size()) / secs / 1e9},
                        {"sum", total},
                        {"peak_rss_kib", std::max(hwm, rss_max_during)},
                        {"vm_hwm_kib", hwm},
                        {"rss_sampled_max_kib", rss_max_during},
                        {"rss_end_kib", rss}};
  std::printf("%s\n", out.dump().c_str());
  return 0;
}

uint64_t ResidentBytes(int fd, uint64_t size) {
  if (size == 0) return 0;
  void* p = ::mmap(nullptr, size, PROT_READ, MAP_SHARED, fd, 0);
  if (p == MAP_FAILED) Die(std::string("mmap: ") + std::strerror(errno));
  const uint64_t page = static_cast<uint64_t>(::sysconf(_SC_PAGESIZE));
  std::vector<unsigned char> vec((size + page - 1) / page);
  if (::mincore(p, size, vec.data()) != 0) Die(std::string("mincore: ") + std::strerror(errno));
  ::munmap(p, size);
  uint64_t pages = 0;
  for (unsigned char c : vec) pages += c & 1;
  return pages * page;
}

int Evict(const Args& a, bool evict) {
  int fd = ::open(a.path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) Die(a.path + ": " + std::strerror(errno));
  struct stat st {};
  ::fstat(fd, &st);
  uint64_t size = static_cast<uint64_t>(st.st_size);
  uint64_t before = ResidentBytes(fd, size);
  if (evict) {
    // Dirty pages cannot be dropped: write them back first.
    if (::fdatasync(fd) != 0) Die(a.path + ": fdatasync: " + std::strerror(errno));
    int rc = ::posix_fadvise(fd, 0, 0, POSIX_FADV_DONTNEED);
    if (rc != 0) Die(a.path + ": posix_fadvise: " + std::strerror(rc));
  }
  uint64_t after = ResidentBytes(fd, size);
  ::close(fd);
  nlohmann::json out = {{"mode", evict ? "evict" : "resident"},
                        {"path", a.path},
                        {"file_bytes", size},
                        {"resident_bytes_before", before},
                        {"resident_bytes", after}};
  std::printf("%s\n", out.dump().c_str());
  return 0;
}

int Gen(const Args& a) {
  std::vector<float> buf(a.chunk_bytes / sizeof(float));
  FillRandom(buf, 0x1234567ull);
  uint64_t left = a.bytes;
  for (uint64_t i = 0; left > 0; ++i) {
    Tweak(buf, i, buf.size());
    size_t n = std::min<uint64_t>(left, buf.size() * sizeof(float));
    const char* p = reinterpret_cast<const char*>(buf.data());
    size_t done = 0;
    while (done < n) {
      ssize_t k = ::write(1, p + done, n - done);
      if (k < 0) {
        if (errno == EINTR) continue;
        return 1;  // the reader went away
      }
      done += static_cast<size_t>(k);
    }
    left -= n;
  }
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  Args a = ParseArgs(argc, argv);
  if (a.mode == "write") return Write(a);
  if (a.mode == "read") return Read(a);
  if (a.mode == "evict") return Evict(a, true);
  if (a.mode == "resident") return Evict(a, false);
  if (a.mode == "gen") return Gen(a);
  Die("unknown mode '" + a.mode + "' (write, read, evict, resident, gen)");
}
