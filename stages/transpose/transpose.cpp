#include "stages/transpose/transpose.h"

#include <fcntl.h>
#include <sys/mman.h>
#include <unistd.h>
#include <xxhash.h>

#if defined(__AVX2__)
#include <immintrin.h>
#endif

#include <algorithm>
#include <atomic>
#include <condition_variable>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <deque>
#include <map>
#include <memory>
#include <mutex>
#include <set>
#include <thread>
#include <vector>

#include "format/chunk_codec.h"
#include "format/content_hash.h"
#include "format/io/container_reader.h"
#include "format/io/container_writer.h"
#include "format/io/file.h"
#include "stages/common/basis.h"
#include "stages/common/parallel_for.h"

namespace ltb::stages {

using namespace ltb::format;

namespace {

constexpr uint64_t kMinChunkBytes = 64 << 10;  // group columns only when one is smaller
constexpr uint64_t kTileRows = 32;             // rows gathered before transposing into a panel
constexpr uint64_t kFixedOverhead = 2 << 20;   // writer state, stacks, small buffers
// Row blocks whose panel segments are queued (WILLNEED) ahead of the readers: 16 blocks of
// 21 rows at R = 64 keep ~340 small reads in flight. In a 2 GiB cgroup (R = 64, cold cache)
// 1 block (each its own, the earlier way) took 19.4-23.4 s in single runs against 16.1-18.0 s
// for 16; 64, 256 and 1024 were no faster (big_bake_r64.md has the run).
constexpr uint64_t kPrefetchBlocks = 16;

// A panel: output chunks [first_chunk, first_chunk + chunks), columns [col0, col0 + cols),
// stored column-major (column c at data + (c - col0) * rows).
struct Panel {
  uint64_t first_chunk = 0, chunks = 0;
  uint64_t col0 = 0, cols = 0;
};

// A float buffer on a 4096-byte boundary (std::vector's is only 16-byte aligned). Buffers
// of 2 MiB or more sit on 2 MiB boundaries and ask for transparent huge pages: filling a
// column-major panel writes a short run into each of thousands of columns 256 KiB apart
// (at 65536 rows), one 4 KiB page each, which with small pages is a TLB miss per run.
class AlignedFloats {
 public:
  bool resize(uint64_t n) {
    constexpr uint64_t kHuge = 2 << 20;
    const uint64_t bytes = std::max<uint64_t>(4096, (n * 4 + 4095) / 4096 * 4096);
    const uint64_t align = bytes >= kHuge ? kHuge : 4096;
    data_.reset(static_cast<float*>(std::aligned_alloc(align, (bytes + align - 1) / align * align)));
    if (data_ != nullptr && align == kHuge) (void)::madvise(data_.get(), bytes, MADV_HUGEPAGE);  // a hint only
    return data_ != nullptr;
  }
  float* data() const { return data_.get(); }

 private:
  struct Free {
    void operator()(float* p) const { std::free(p); }
  };
  std::unique_ptr<float, Free> data_;
};

// Hands filled panel buffers to the writer thread and free ones back.
class PanelQueue {
 public:
  void PushFilled(size_t slot, Panel p) {
    std::lock_guard<std::mutex> l(mu_);
    filled_.push_back({slot, p});
    cv_.notify_all();
  }
  bool PopFilled(size_t* slot, Panel* p) {
    std::unique_lock<std::mutex> l(mu_);
    cv_.wait(l, [&] { return !filled_.empty() || closed_; });
    if (filled_.empty()) return false;
    *slot = filled_.front().first;
    *p = filled_.front().second;
    filled_.pop_front();
    return true;
  }
  void Release(size_t slot) {
    std::lock_guard<std::mutex> l(mu_);
    busy_[slot] = false;
    cv_.notify_all();
  }
  void Acquire(size_t slot) {
    std::unique_lock<std::mutex> l(mu_);
    cv_.wait(l, [&] { return !busy_[slot] || failed_; });
    busy_[slot] = true;
  }
  void Close() {
    std::lock_guard<std::mutex> l(mu_);
    closed_ = true;
    cv_.notify_all();
  }
  void Fail() {
    std::lock_guard<std::mutex> l(mu_);
    failed_ = true;
    closed_ = true;
    cv_.notify_all();
  }

 private:
  std::mutex mu_;
  std::condition_variable cv_;
  std::deque<std::pair<size_t, Panel>> filled_;
  bool busy_[2] = {false, false};
  bool closed_ = false, failed_ = false;
};

// What the input and --mem-limit make of a run.
struct TransposePlan {
  uint64_t rows = 0, cols = 0;
  uint64_t col_bytes = 0;     // one column of the output, in bytes
  uint64_t block = 0;         // columns per output chunk
  int jobs = 1;               // reader threads
  uint64_t budget = 0;        // --mem-limit less the fixed overhead
  uint64_t panel_chunks = 0;  // output chunks per full panel
};

// Checks the input (a complete f32 matrix in row blocks) and sizes the output chunks and
// the panels within --mem-limit.
Result<TransposePlan> PlanTranspose(const TransposeOptions& o, const io::ContainerReader& in) {
  LTB_RETURN_IF_ERROR(RefuseCpcaOutput(in, "transpose"));
  const Metadata& meta = in.metadata();
  const ArraySpec& a = meta.matrix();
  if (a.layout != Layout::kRows) {
    return FailedPrecondition(o.input +
                              ": is already stored in column blocks; transpose takes row blocks (the "
                              "output of `ltbake row-transform`)");
  }
  LTB_RETURN_IF_ERROR(RequireCompleteF32Matrix(in));
  TransposePlan plan;
  const uint64_t rows = a.rows, cols = a.cols;
  const uint64_t col_bytes = rows * 4;
  const uint64_t block = std::min<uint64_t>(cols, std::max<uint64_t>(1, kMinChunkBytes / col_bytes));

  // Budget: two panels + one read tile per reader + a fixed overhead.
  const int jobs = std::max(1, o.jobs);
  if (o.mem_limit <= kFixedOverhead) {
    return InvalidArgument("--mem-limit " + std::to_string(o.mem_limit) + " bytes is below the fixed overhead of " +
                           std::to_string(kFixedOverhead));
  }
  uint64_t budget = o.mem_limit - kFixedOverhead;
  // Per panel column: 2 panel copies (rows each) + each reader's tile (kTileRows each).
  uint64_t per_col = 2 * col_bytes + jobs * kTileRows * 4;
  uint64_t panel_chunks = budget / (per_col * block);
  if (panel_chunks == 0) {
    uint64_t need = kFixedOverhead + per_col * block;
    return InvalidArgument("--mem-limit " + std::to_string(o.mem_limit) + " bytes is too small: one output chunk of " +
                           std::to_string(block) + " column(s) × " + std::to_string(rows) +
                           " rows, double-buffered, "
                           "needs at least " +
                           std::to_string(need) + " bytes (" + std::to_string((need + (1 << 20) - 1) >> 20) + " MiB)");
  }
  // Several panels: each reads a segment of every row. Panels of whole 4 KiB pages
  // (a multiple of 1024 columns) read whole pages of rows whose length is a page multiple
  // in payloads on page boundaries (what row-transform and sample write with O_DIRECT), so
  // no page is read by two panels.
  constexpr uint64_t kPageCols = 1024;
  if (panel_chunks * block < cols && panel_chunks * block >= kPageCols && kPageCols % block == 0) {
    panel_chunks = panel_chunks * block / kPageCols * kPageCols / block;
  }
  plan.rows = rows;
  plan.cols = cols;
  plan.col_bytes = col_bytes;
  plan.block = block;
  plan.jobs = jobs;
  plan.budget = budget;
  plan.panel_chunks = panel_chunks;
  return plan;
}

// Panels: runs of consecutive missing output chunks, at most panel_chunks long.
std::vector<Panel> PlanPanels(const std::vector<uint64_t>& missing, const TransposePlan& plan) {
  std::vector<Panel> panels;
  for (uint64_t c : missing) {
    if (!panels.empty() && panels.back().first_chunk + panels.back().chunks == c &&
        panels.back().chunks < plan.panel_chunks) {
      panels.back().chunks++;
    } else {
      panels.push_back({c, 1, 0, 0});
    }
  }
  for (Panel& p : panels) {
    p.col0 = p.first_chunk * plan.block;
    p.cols = std::min(plan.cols, (p.first_chunk + p.chunks) * plan.block) - p.col0;
  }
  return panels;
}

// The counters the panel passes share between their threads.
struct PanelCounters {
  std::atomic<uint64_t> written{0}, zero_out{0}, bytes_written{0}, bytes_read{0}, cols_done{0};
};

// Checks one stored chunk's payload checksum reading it with O_DIRECT (the whole 4096-byte
// blocks around it, through `buf`, page-aligned, a multiple of 4096 bytes): the sequential
// pass then neither evicts the panels' pages from the page cache nor fills it. False when
// the direct read is refused or fails (the caller reads through the page cache instead).
bool VerifyDirect(const io::File& direct, const IndexEntry& e, std::byte* buf, uint64_t buf_size) {
  constexpr uint64_t kAlign = 4096;
  const uint64_t begin = e.frame_offset + kFrameHeaderSize, end = begin + e.header.payload_length;
  XXH3_state_t* st = XXH3_createState();
  if (st == nullptr) return false;
  XXH3_64bits_reset(st);
  bool ok = true;
  for (uint64_t at = begin / kAlign * kAlign; at < end && ok;) {
    const uint64_t want = std::min(buf_size, (end - at + kAlign - 1) / kAlign * kAlign);
    ssize_t n;
    do {
      n = ::pread(direct.fd(), buf, want, static_cast<off_t>(at));
    } while (n < 0 && errno == EINTR);
    if (n <= 0 || (static_cast<uint64_t>(n) < want && at + static_cast<uint64_t>(n) < end)) {
      ok = false;
      break;
    }
    const uint64_t lo = std::max(at, begin), hi = std::min(end, at + static_cast<uint64_t>(n));
    XXH3_64bits_update(st, buf + (lo - at), hi - lo);
    at += static_cast<uint64_t>(n);
  }
  const bool match = ok && XXH3_64bits_digest(st) == e.header.payload_checksum;
  XXH3_freeState(st);
  return match;
}

// The checksum pass: every stored input chunk's checksum, on its own thread, read with
// O_DIRECT where the file system takes it. A chunk whose direct read fails or mismatches is
// checked again through the page cache, which gives the error its file, chunk and offset.
class ChecksumPass {
 public:
  void Start(const io::ContainerReader& in, const std::vector<uint64_t>& in_chunks, uint64_t piece,
             const Progress& progress) {
    thread_ = std::thread([this, &in, &in_chunks, &progress, piece] {
      constexpr uint64_t kAlign = 4096;
      const uint64_t direct_size = std::max(kAlign, piece / kAlign * kAlign);
      std::unique_ptr<std::byte, void (*)(void*)> aligned(
          static_cast<std::byte*>(std::aligned_alloc(kAlign, direct_size)), std::free);
      std::map<std::string, io::File> direct;  // per holder file (a manifest's shards)
      std::vector<std::byte> buf(piece);
      status_ = ParallelFor(
          in_chunks, 1, Progress{.update = nullptr, .cancelled = progress.cancelled}, "chunks",
          [&](uint64_t ci) -> Status {
            const io::ContainerReader& holder = in.Holder(0, ci);
            auto it = direct.find(holder.path());
            if (it == direct.end()) {
              auto f = io::File::Open(holder.path(), io::File::Mode::kReadDirect);
              it = direct.emplace(holder.path(), f.ok() ? std::move(f).value() : io::File()).first;
            }
            const IndexEntry* e = in.Find(0, ci);
            if (!aligned || it->second.fd() < 0 || !VerifyDirect(it->second, *e, aligned.get(), direct_size)) {
              LTB_RETURN_IF_ERROR(in.VerifyChunk(0, ci, buf));
            }
            verified_ += e->header.payload_length;
            return Status::Ok();
          });
      if (!status_.ok()) failed_ = true;
    });
  }
  void Join() {
    if (thread_.joinable()) thread_.join();
  }
  bool failed() const { return failed_; }
  uint64_t verified() const { return verified_; }
  const Status& status() const { return status_; }  // once joined

 private:
  std::atomic<bool> failed_{false};
  std::atomic<uint64_t> verified_{0};
  Status status_;  // written by the verifier thread, read after it is joined
  std::thread thread_;
};

// The writer thread: encodes and appends the column chunks of each filled panel, then
// hands its buffer back to the readers.
class PanelWriter {
 public:
  void Start(io::ContainerWriter& out, const ArraySpec& out_spec, const TransposePlan& plan, const EncodeOptions& eo,
             const AlignedFloats* buffers, PanelQueue& queue, PanelCounters& n, const Progress& progress) {
    thread_ = std::thread([this, &out, &out_spec, &plan, &eo, buffers, &queue, &n, &progress] {
      size_t slot;
      Panel p;
      while (queue.PopFilled(&slot, &p)) {
        for (uint64_t k = 0; k < p.chunks && status_.ok(); ++k) {
          uint64_t chunk = p.first_chunk + k;
          ChunkExtent e = out_spec.Extent(chunk);
          const float* data = buffers[slot].data() + (e.col0 - p.col0) * plan.rows;
          const ByteSpan bytes(reinterpret_cast<const std::byte*>(data), e.cols * plan.col_bytes);
          EncodedChunk enc = EncodeChunk(bytes, eo);
          status_ = out.Append(0, chunk, enc, ChunkHashSum(out_spec, e, bytes));
          if (enc.encoding == Encoding::kZero) n.zero_out++;
          n.bytes_written += enc.payload.size();
          n.written++;
        }
        n.cols_done += p.cols;
        progress.Report(n.cols_done.load(), plan.cols, "columns");
        queue.Release(slot);
        if (!status_.ok()) {
          failed_ = true;
          queue.Fail();
          return;
        }
      }
    });
  }
  void Join() { thread_.join(); }
  bool failed() const { return failed_; }
  const Status& status() const { return status_; }  // once joined

 private:
  Status status_;  // written by the writer thread, read after it is joined
  std::atomic<bool> failed_{false};
  std::thread thread_;
};

// What the panel passes read, and for whom.
struct PanelSource {
  const TransposeOptions& o;
  const io::ContainerReader& in;
  const TransposePlan& plan;
  const std::vector<uint64_t>& in_chunks;  // the stored (not all-zero) input row blocks
  const Progress& progress;
};

// The tile (nr rows of `cols` floats) into the column-major panel: column c's nr values at
// out + c * rows. In 8 × 8 blocks (AVX2: eight row loads, an in-register transpose, eight
// column stores) so that each column run is written whole, not one float per pass.
void TransposeTile(const float* tile, uint64_t nr, uint64_t cols, float* out, uint64_t rows) {
  uint64_t c0 = 0;
#if defined(__AVX2__)
  const uint64_t nr8 = nr / 8 * 8;
  if (nr8 > 0) {
    for (; c0 + 8 <= cols; c0 += 8) {
      for (uint64_t r = nr8; r < nr; ++r)
        for (uint64_t j = 0; j < 8; ++j) out[(c0 + j) * rows + r] = tile[r * cols + c0 + j];
      for (uint64_t r0 = 0; r0 < nr8; r0 += 8) {
        __m256 v[8];
        for (int i = 0; i < 8; ++i) v[i] = _mm256_loadu_ps(tile + (r0 + i) * cols + c0);
        const __m256 a0 = _mm256_unpacklo_ps(v[0], v[1]), a1 = _mm256_unpackhi_ps(v[0], v[1]);
        const __m256 a2 = _mm256_unpacklo_ps(v[2], v[3]), a3 = _mm256_unpackhi_ps(v[2], v[3]);
        const __m256 a4 = _mm256_unpacklo_ps(v[4], v[5]), a5 = _mm256_unpackhi_ps(v[4], v[5]);
        const __m256 a6 = _mm256_unpacklo_ps(v[6], v[7]), a7 = _mm256_unpackhi_ps(v[6], v[7]);
        const __m256 b0 = _mm256_shuffle_ps(a0, a2, 0x44), b1 = _mm256_shuffle_ps(a0, a2, 0xee);
        const __m256 b2 = _mm256_shuffle_ps(a1, a3, 0x44), b3 = _mm256_shuffle_ps(a1, a3, 0xee);
        const __m256 b4 = _mm256_shuffle_ps(a4, a6, 0x44), b5 = _mm256_shuffle_ps(a4, a6, 0xee);
        const __m256 b6 = _mm256_shuffle_ps(a5, a7, 0x44), b7 = _mm256_shuffle_ps(a5, a7, 0xee);
        const __m256 t[8] = {_mm256_permute2f128_ps(b0, b4, 0x20), _mm256_permute2f128_ps(b1, b5, 0x20),
                             _mm256_permute2f128_ps(b2, b6, 0x20), _mm256_permute2f128_ps(b3, b7, 0x20),
                             _mm256_permute2f128_ps(b0, b4, 0x31), _mm256_permute2f128_ps(b1, b5, 0x31),
                             _mm256_permute2f128_ps(b2, b6, 0x31), _mm256_permute2f128_ps(b3, b7, 0x31)};
        for (int j = 0; j < 8; ++j) _mm256_storeu_ps(out + (c0 + j) * rows + r0, t[j]);
      }
    }
  }
#endif
  for (uint64_t c = c0; c < cols; ++c) {
    float* col = out + c * rows;
    for (uint64_t r = 0; r < nr; ++r) col[r] = tile[r * cols + c];
  }
}

// Fills one panel (column-major, zeroed first) from every stored input row block, `jobs`
// blocks at a time: each reader reads the panel's column range of each row of its block
// into a tile, then transposes the tile into the panel.
Status FillPanel(const PanelSource& src, const Panel& p, float* panel, PanelCounters& n) {
  const TransposeOptions& o = src.o;
  const io::ContainerReader& in = src.in;
  const TransposePlan& plan = src.plan;
  const Progress& progress = src.progress;
  const ArraySpec& a = in.metadata().matrix();
  const uint64_t rows = plan.rows, cols = plan.cols;
  std::fill(panel, panel + p.cols * rows, 0.0f);
  // Queue the reads of this panel's segments of raw row blocks ahead of the readers, so the
  // disk has many small reads in flight instead of one block's few (page cache, no RSS).
  auto prefetch = [&](uint64_t k) {
    if (k >= src.in_chunks.size()) return;
    const uint64_t ci = src.in_chunks[k];
    const IndexEntry* entry = in.Find(0, ci);
    if (entry->header.encoding != static_cast<uint16_t>(Encoding::kRaw)) return;
    const int fd = in.Holder(0, ci).file().fd();
    const uint64_t payload = entry->frame_offset + kFrameHeaderSize;
    for (uint64_t r = 0; r < a.Extent(ci).rows; ++r) {
      ::posix_fadvise(fd, static_cast<off_t>(payload + (r * cols + p.col0) * 4), static_cast<off_t>(p.cols * 4),
                      POSIX_FADV_WILLNEED);
    }
  };
  constexpr uint64_t ahead = kPrefetchBlocks;
  std::vector<uint64_t> order(src.in_chunks.size());
  for (uint64_t k = 0; k < order.size(); ++k) order[k] = k;
  for (uint64_t k = 0; k + 1 < ahead; ++k) prefetch(k);
  return ParallelFor(
      order, plan.jobs, Progress{.update = nullptr, .cancelled = progress.cancelled}, "chunks",
      [&](uint64_t k) -> Status {
        prefetch(k + ahead - 1);
        const uint64_t ci = src.in_chunks[k];
        const IndexEntry* entry = in.Find(0, ci);
        const io::File& in_file = in.Holder(0, ci).file();  // a manifest's chunks live in its shards
        ChunkExtent e = a.Extent(ci);
        thread_local std::vector<float> tile;
        tile.resize(kTileRows * p.cols);
        std::vector<std::byte> decoded;  // zstd chunks are decoded whole
        const float* src = nullptr;
        io::Chunk whole;
        if (entry->header.encoding != static_cast<uint16_t>(Encoding::kRaw)) {  // zstd, sparse: decoded whole
          LTB_ASSIGN_OR_RETURN(whole, in.ReadChunk(0, ci));
          src = whole.as<float>().data();
          n.bytes_read += entry->header.payload_length;
        }
        uint64_t payload = entry->frame_offset + kFrameHeaderSize;
        for (uint64_t r0 = 0; r0 < e.rows; r0 += kTileRows) {
          uint64_t nr = std::min(kTileRows, e.rows - r0);
          for (uint64_t r = 0; r < nr; ++r) {
            float* dst = tile.data() + r * p.cols;
            if (src != nullptr) {
              std::memcpy(dst, src + (r0 + r) * cols + p.col0, p.cols * 4);
            } else {
              uint64_t off = payload + ((r0 + r) * cols + p.col0) * 4;
              Status s = in_file.ReadAt(off, MutableByteSpan(reinterpret_cast<std::byte*>(dst), p.cols * 4));
              if (!s.ok()) return s.WithContext(o.input + ": chunk " + std::to_string(ci));
              n.bytes_read += p.cols * 4;
            }
          }
          TransposeTile(tile.data(), nr, p.cols, panel + e.row0 + r0, rows);
        }
        return Status::Ok();
      });
}

// Fills the panels in turn, each into the buffer the writer has handed back, and hands it
// to the writer; stops when the writer or the checksum pass failed, on cancellation, or at
// a read error (returned).
Status FillPanels(const PanelSource& src, const std::vector<Panel>& panels, const AlignedFloats* buffers,
                  PanelQueue& queue, const PanelWriter& writer, const ChecksumPass& checksum, PanelCounters& n) {
  Status status;
  for (size_t pi = 0; pi < panels.size() && status.ok(); ++pi) {
    const Panel& p = panels[pi];
    size_t slot = pi % 2;
    queue.Acquire(slot);
    if (writer.failed() || checksum.failed()) break;
    if (src.progress.Cancelled()) {
      status = Cancelled("interrupted; committed columns are kept, rerun the same command to resume");
      break;
    }
    status = FillPanel(src, p, buffers[slot].data(), n);
    if (!status.ok()) break;
    queue.PushFilled(slot, p);
  }
  return status;
}

// Copies the side tables' missing chunks as they are; returns how many.
Result<uint64_t> CopySideTables(const io::ContainerReader& in, io::ContainerWriter& out, const EncodeOptions& eo) {
  uint64_t written = 0;
  for (uint32_t arr = 1; arr < in.metadata().arrays.size(); ++arr) {
    for (uint64_t c : out.Missing(arr)) {
      LTB_ASSIGN_OR_RETURN(io::Chunk chunk, in.ReadChunk(arr, c));
      LTB_RETURN_IF_ERROR(out.Put(arr, c, chunk.bytes(), eo));
      written++;
    }
  }
  return written;
}

// Input row blocks to read: all but the all-zero ones (they leave the panel zero).
std::vector<uint64_t> StoredInputChunks(const io::ContainerReader& in) {
  std::vector<uint64_t> in_chunks;
  for (uint64_t i = 0; i < in.metadata().matrix().ChunkCount(); ++i) {
    if (in.Find(0, i)->header.encoding != static_cast<uint16_t>(Encoding::kZero)) in_chunks.push_back(i);
  }
  return in_chunks;
}

// Seals the output; or, when the checksum pass found the input damaged, removes it (its
// columns may come from the damaged input) and says so.
Result<TransposeResult> Seal(io::ContainerWriter& out, const Status& verify_status, const Status& status,
                             const Status& writer_status, TransposeResult result) {
  const io::DirectIoStats ds = out.direct_io_stats();
  result.bytes_direct = ds.direct_bytes;
  result.padding_bytes = ds.padding_bytes;
  result.direct_fallback = ds.fallback_reason;
  if (!verify_status.ok() && verify_status.code() != StatusCode::kCancelled) {
    const std::string written_path = out.path();
    (void)out.Discard();  // removed before the output's lock is released
    return verify_status.WithContext("input checksum pass (" + written_path +
                                     " removed: it may hold columns built from the "
                                     "damaged input); repair or regenerate the input and rerun");
  }
  LTB_RETURN_IF_ERROR(verify_status);
  LTB_RETURN_IF_ERROR(status);
  LTB_RETURN_IF_ERROR(writer_status);
  LTB_RETURN_IF_ERROR(out.Finish());
  return result;
}

}  // namespace

Result<TransposeResult> RunTranspose(const TransposeOptions& o, const Progress& progress) {
  LTB_ASSIGN_OR_RETURN(io::ContainerReader in, io::ContainerReader::Open(o.input));
  LTB_ASSIGN_OR_RETURN(const TransposePlan plan, PlanTranspose(o, in));
  const Metadata& meta = in.metadata();
  const uint64_t rows = plan.rows, cols = plan.cols, block = plan.block;

  ArraySpec out_spec = meta.matrix();
  out_spec.layout = Layout::kCols;
  out_spec.block = block;
  nlohmann::json out_meta = meta.json;
  out_meta["arrays"][0] = out_spec.ToJson();
  out_meta["provenance"] = Provenance("transpose", {{"block_cols", block}, {"zstd", o.zstd}}, {&in});
  io::WriterOptions wo;
  wo.overwrite_mismatch = o.overwrite;
  wo.direct_io = o.direct_io;
  LTB_ASSIGN_OR_RETURN(io::ContainerWriter out, io::OpenStageOutput(o.output, out_meta, wo, o.shard));

  TransposeResult result;
  result.rows = rows;
  result.cols = cols;
  result.block_cols = block;
  result.panel_cols = std::min(cols, plan.panel_chunks * block);
  for (const ArraySpec& s : meta.arrays) result.chunks_total += s.ChunkCount();
  result.chunks_already_committed = out.resume_info().committed_chunks;

  EncodeOptions eo;
  eo.zstd = o.zstd;
  // Side tables are copied as they are.
  LTB_ASSIGN_OR_RETURN(result.chunks_written, CopySideTables(in, out, eo));
  const std::vector<Panel> panels = PlanPanels(out.Missing(0), plan);
  result.panels = panels.size();
  const std::vector<uint64_t> in_chunks = StoredInputChunks(in);

  const uint64_t panel_floats = result.panel_cols * rows;
  // Page-aligned, so direct writes take each column chunk from the panel without a copy.
  // Allocated before the checksum thread starts: a failure returns with no thread to join.
  AlignedFloats buffers[2];
  for (int b = 0; b < (panels.size() > 1 ? 2 : 1); ++b) {
    if (!buffers[b].resize(panel_floats)) {
      return InvalidArgument("cannot allocate a panel buffer of " + std::to_string(panel_floats * 4) +
                             " bytes; lower --mem-limit");
    }
  }

  // With more than one panel, each reads short, strided segments of every row, which the
  // kernel's readahead has no use for: it is turned off for the input (a precaution; this
  // kernel showed no readahead excess on such reads, docs/TRANSPOSE.md), and the panels'
  // WILLNEED hints still queue exactly their segments.
  if (panels.size() > 1) {
    std::set<int> fds;  // one per holder file (a manifest's shards)
    for (uint64_t ci : in_chunks) fds.insert(in.Holder(0, ci).file().fd());
    for (int fd : fds) ::posix_fadvise(fd, 0, 0, POSIX_FADV_RANDOM);
  }
  // The checksum pass runs beside the panels (it reads the input sequentially while they
  // read column ranges; both share the page cache). Panel filling stops if it fails, and
  // the output, possibly built from damaged input, is removed.
  ChecksumPass checksum;
  if (o.verify_input && !panels.empty()) {
    checksum.Start(in, in_chunks, std::clamp<uint64_t>(plan.budget / (4 * plan.jobs), 4096, 1 << 20), progress);
  }
  PanelQueue queue;
  PanelCounters counters;
  PanelWriter writer;
  writer.Start(out, out_spec, plan, eo, buffers, queue, counters, progress);
  const Status status =
      FillPanels(PanelSource{o, in, plan, in_chunks, progress}, panels, buffers, queue, writer, checksum, counters);
  queue.Close();
  writer.Join();
  checksum.Join();
  result.chunks_written += counters.written;
  result.zero_chunks_out = counters.zero_out;
  result.bytes_read = counters.bytes_read;
  result.bytes_written = counters.bytes_written;
  result.bytes_verified = checksum.verified();
  return Seal(out, checksum.status(), status, writer.status(), std::move(result));
}

}  // namespace ltb::stages
