#include "stages/transpose/transpose.h"

#include <fcntl.h>

#include <algorithm>
#include <atomic>
#include <condition_variable>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <deque>
#include <memory>
#include <mutex>
#include <thread>
#include <vector>

#include "format/chunk_codec.h"
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

// A panel: output chunks [first_chunk, first_chunk + chunks), columns [col0, col0 + cols),
// stored column-major (column c at data + (c - col0) * rows).
struct Panel {
  uint64_t first_chunk = 0, chunks = 0;
  uint64_t col0 = 0, cols = 0;
};

// A float buffer on a 4096-byte boundary (std::vector's is only 16-byte aligned).
class AlignedFloats {
 public:
  bool resize(uint64_t n) {
    data_.reset(static_cast<float*>(std::aligned_alloc(4096, std::max<uint64_t>(4096, (n * 4 + 4095) / 4096 * 4096))));
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

}  // namespace

Result<TransposeResult> RunTranspose(const TransposeOptions& o, const Progress& progress) {
  LTB_ASSIGN_OR_RETURN(io::ContainerReader in, io::ContainerReader::Open(o.input));
  LTB_RETURN_IF_ERROR(RefuseCpcaOutput(in, "transpose"));
  const Metadata& meta = in.metadata();
  const ArraySpec& a = meta.matrix();
  if (a.layout != Layout::kRows) {
    return FailedPrecondition(o.input +
                              ": is already stored in column blocks; transpose takes row blocks (the "
                              "output of `ltbake row-transform`)");
  }
  LTB_RETURN_IF_ERROR(RequireCompleteF32Matrix(in));
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

  ArraySpec out_spec = a;
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
  result.panel_cols = std::min(cols, panel_chunks * block);
  for (const ArraySpec& s : meta.arrays) result.chunks_total += s.ChunkCount();
  result.chunks_already_committed = out.resume_info().committed_chunks;

  EncodeOptions eo;
  eo.zstd = o.zstd;

  // Side tables are copied as they are.
  for (uint32_t arr = 1; arr < meta.arrays.size(); ++arr) {
    for (uint64_t c : out.Missing(arr)) {
      LTB_ASSIGN_OR_RETURN(io::Chunk chunk, in.ReadChunk(arr, c));
      LTB_RETURN_IF_ERROR(out.Put(arr, c, chunk.bytes(), eo));
      result.chunks_written++;
    }
  }

  // Panels: runs of consecutive missing output chunks, at most panel_chunks long.
  std::vector<Panel> panels;
  for (uint64_t c : out.Missing(0)) {
    if (!panels.empty() && panels.back().first_chunk + panels.back().chunks == c &&
        panels.back().chunks < panel_chunks) {
      panels.back().chunks++;
    } else {
      panels.push_back({c, 1, 0, 0});
    }
  }
  for (Panel& p : panels) {
    p.col0 = p.first_chunk * block;
    p.cols = std::min(cols, (p.first_chunk + p.chunks) * block) - p.col0;
  }
  result.panels = panels.size();

  // Input row blocks to read: all but the all-zero ones (they leave the panel zero).
  std::vector<uint64_t> in_chunks;
  for (uint64_t i = 0; i < a.ChunkCount(); ++i) {
    if (in.Find(0, i)->header.encoding != static_cast<uint16_t>(Encoding::kZero)) in_chunks.push_back(i);
  }

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

  // The checksum pass runs beside the panels (it reads the input sequentially while they
  // read column ranges; both share the page cache). Panel filling stops if it fails, and
  // the output, possibly built from damaged input, is removed.
  std::atomic<bool> verify_failed{false};
  std::atomic<uint64_t> verified{0};
  Status verify_status;  // written by the verifier thread, read after it is joined
  std::thread verifier;
  if (o.verify_input && !panels.empty()) {
    const uint64_t piece = std::clamp<uint64_t>(budget / (4 * jobs), 4096, 1 << 20);
    verifier = std::thread([&, piece] {
      std::vector<std::byte> buf(piece);
      verify_status = ParallelFor(in_chunks, 1, Progress{.update = nullptr, .cancelled = progress.cancelled}, "chunks",
                                  [&](uint64_t ci) -> Status {
                                    LTB_RETURN_IF_ERROR(in.VerifyChunk(0, ci, buf));
                                    verified += in.Find(0, ci)->header.payload_length;
                                    return Status::Ok();
                                  });
      if (!verify_status.ok()) verify_failed = true;
    });
  }

  PanelQueue queue;
  std::atomic<uint64_t> written{0}, zero_out{0}, bytes_written{0}, bytes_read{0}, cols_done{0};
  Status writer_status;  // written by the writer thread, read after it is joined
  std::atomic<bool> writer_failed{false};
  std::thread writer([&] {
    size_t slot;
    Panel p;
    while (queue.PopFilled(&slot, &p)) {
      for (uint64_t k = 0; k < p.chunks && writer_status.ok(); ++k) {
        uint64_t chunk = p.first_chunk + k;
        ChunkExtent e = out_spec.Extent(chunk);
        const float* data = buffers[slot].data() + (e.col0 - p.col0) * rows;
        EncodedChunk enc = EncodeChunk(ByteSpan(reinterpret_cast<const std::byte*>(data), e.cols * col_bytes), eo);
        writer_status = out.Append(0, chunk, enc);
        if (enc.encoding == Encoding::kZero) zero_out++;
        bytes_written += enc.payload.size();
        written++;
      }
      cols_done += p.cols;
      progress.Report(cols_done.load(), cols, "columns");
      queue.Release(slot);
      if (!writer_status.ok()) {
        writer_failed = true;
        queue.Fail();
        return;
      }
    }
  });

  Status status;
  for (size_t pi = 0; pi < panels.size() && status.ok(); ++pi) {
    const Panel& p = panels[pi];
    size_t slot = pi % 2;
    queue.Acquire(slot);
    if (writer_failed || verify_failed) break;
    if (progress.Cancelled()) {
      status = Cancelled("interrupted; committed columns are kept, rerun the same command to resume");
      break;
    }
    float* panel = buffers[slot].data();
    std::fill(panel, panel + p.cols * rows, 0.0f);
    status = ParallelFor(
        in_chunks, jobs, Progress{.update = nullptr, .cancelled = progress.cancelled}, "chunks",
        [&](uint64_t ci) -> Status {
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
            bytes_read += entry->header.payload_length;
          }
          uint64_t payload = entry->frame_offset + kFrameHeaderSize;
          if (src == nullptr) {
            // Start the reads of this block's column range for every row at once, so the disk
            // has them all queued instead of one small pread at a time (page cache, no RSS).
            for (uint64_t r = 0; r < e.rows; ++r) {
              ::posix_fadvise(in_file.fd(), static_cast<off_t>(payload + (r * cols + p.col0) * 4),
                              static_cast<off_t>(p.cols * 4), POSIX_FADV_WILLNEED);
            }
          }
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
                bytes_read += p.cols * 4;
              }
            }
            // Transpose the tile into the column-major panel.
            for (uint64_t c = 0; c < p.cols; ++c) {
              float* col = panel + c * rows + e.row0 + r0;
              for (uint64_t r = 0; r < nr; ++r) col[r] = tile[r * p.cols + c];
            }
          }
          return Status::Ok();
        });
    if (!status.ok()) break;
    queue.PushFilled(slot, p);
  }
  queue.Close();
  writer.join();
  if (verifier.joinable()) verifier.join();
  result.chunks_written += written;
  result.zero_chunks_out = zero_out;
  result.bytes_read = bytes_read;
  result.bytes_written = bytes_written;
  result.bytes_verified = verified;
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

}  // namespace ltb::stages
