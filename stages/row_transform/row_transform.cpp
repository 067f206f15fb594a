#include "stages/row_transform/row_transform.h"

#include <algorithm>
#include <atomic>
#include <cstring>
#include <filesystem>
#include <vector>

#if defined(__AVX2__)
#include <immintrin.h>
#endif

#include "format/io/container_reader.h"
#include "format/io/container_writer.h"
#include "format/json_text.h"
#include "stages/common/basis.h"
#include "stages/common/parallel_for.h"
#include "stages/wavelet/face_kernel.h"

namespace ltb::stages {

using namespace ltb::format;

namespace {

// Rows transformed together: each pixel of a face becomes a vector of kLanes values (one
// per matrix row), so every filter tap is one contiguous vector operation.
constexpr uint64_t kLanes = 16;

#if defined(__AVX2__)
// Transposes the 8×8 block whose rows start at src[0..7] (8 floats each) into dst rows
// dst + i * dst_stride (8 floats each).
inline void Transpose8x8(const float* const* src, float* dst, size_t dst_stride) {
  __m256 r0 = _mm256_loadu_ps(src[0]), r1 = _mm256_loadu_ps(src[1]), r2 = _mm256_loadu_ps(src[2]),
         r3 = _mm256_loadu_ps(src[3]), r4 = _mm256_loadu_ps(src[4]), r5 = _mm256_loadu_ps(src[5]),
         r6 = _mm256_loadu_ps(src[6]), r7 = _mm256_loadu_ps(src[7]);
  __m256 t0 = _mm256_unpacklo_ps(r0, r1), t1 = _mm256_unpackhi_ps(r0, r1), t2 = _mm256_unpacklo_ps(r2, r3),
         t3 = _mm256_unpackhi_ps(r2, r3), t4 = _mm256_unpacklo_ps(r4, r5), t5 = _mm256_unpackhi_ps(r4, r5),
         t6 = _mm256_unpacklo_ps(r6, r7), t7 = _mm256_unpackhi_ps(r6, r7);
  __m256 u0 = _mm256_shuffle_ps(t0, t2, 0x44), u1 = _mm256_shuffle_ps(t0, t2, 0xEE),
         u2 = _mm256_shuffle_ps(t1, t3, 0x44), u3 = _mm256_shuffle_ps(t1, t3, 0xEE),
         u4 = _mm256_shuffle_ps(t4, t6, 0x44), u5 = _mm256_shuffle_ps(t4, t6, 0xEE),
         u6 = _mm256_shuffle_ps(t5, t7, 0x44), u7 = _mm256_shuffle_ps(t5, t7, 0xEE);
  _mm256_storeu_ps(dst + 0 * dst_stride, _mm256_permute2f128_ps(u0, u4, 0x20));
  _mm256_storeu_ps(dst + 1 * dst_stride, _mm256_permute2f128_ps(u1, u5, 0x20));
  _mm256_storeu_ps(dst + 2 * dst_stride, _mm256_permute2f128_ps(u2, u6, 0x20));
  _mm256_storeu_ps(dst + 3 * dst_stride, _mm256_permute2f128_ps(u3, u7, 0x20));
  _mm256_storeu_ps(dst + 4 * dst_stride, _mm256_permute2f128_ps(u0, u4, 0x31));
  _mm256_storeu_ps(dst + 5 * dst_stride, _mm256_permute2f128_ps(u1, u5, 0x31));
  _mm256_storeu_ps(dst + 6 * dst_stride, _mm256_permute2f128_ps(u2, u6, 0x31));
  _mm256_storeu_ps(dst + 7 * dst_stride, _mm256_permute2f128_ps(u3, u7, 0x31));
}
#endif

// lanes[c * n + k] = rows[k][c] for k < n, c < cols. Moves bits only (no arithmetic).
void Gather(float* const* rows, uint64_t n, uint64_t cols, float* lanes) {
#if defined(__AVX2__)
  if (n % 8 == 0 && cols % 8 == 0) {
    for (uint64_t k0 = 0; k0 < n; k0 += 8)
      for (uint64_t c0 = 0; c0 < cols; c0 += 8) {
        const float* src[8];
        for (int i = 0; i < 8; ++i) src[i] = rows[k0 + i] + c0;
        Transpose8x8(src, lanes + c0 * n + k0, n);
      }
    return;
  }
#endif
  constexpr uint64_t kTile = 64;
  for (uint64_t c0 = 0; c0 < cols; c0 += kTile) {
    uint64_t c1 = std::min(cols, c0 + kTile);
    for (uint64_t k = 0; k < n; ++k)
      for (uint64_t c = c0; c < c1; ++c) lanes[c * n + k] = rows[k][c];
  }
}

// rows[k][c] = lanes[c * n + k].
void Scatter(const float* lanes, uint64_t n, uint64_t cols, float* const* rows) {
#if defined(__AVX2__)
  if (n % 8 == 0 && cols % 8 == 0) {
    for (uint64_t c0 = 0; c0 < cols; c0 += 8)
      for (uint64_t k0 = 0; k0 < n; k0 += 8) {
        const float* src[8];
        for (int i = 0; i < 8; ++i) src[i] = lanes + (c0 + i) * n + k0;
        float tmp[64];
        Transpose8x8(src, tmp, 8);
        for (int i = 0; i < 8; ++i) std::memcpy(rows[k0 + i] + c0, tmp + i * 8, 32);
      }
    return;
  }
#endif
  constexpr uint64_t kTile = 64;
  for (uint64_t c0 = 0; c0 < cols; c0 += kTile) {
    uint64_t c1 = std::min(cols, c0 + kTile);
    for (uint64_t k = 0; k < n; ++k)
      for (uint64_t c = c0; c < c1; ++c) rows[k][c] = lanes[c * n + k];
  }
}

bool RowIsZero(const float* row, uint64_t n) {
  const uint32_t* bits = reinterpret_cast<const uint32_t*>(row);
  uint64_t i = 0;
  for (; i + 64 <= n; i += 64) {  // a vector OR per 256 bytes, one branch
    uint32_t any = 0;
    for (int k = 0; k < 64; ++k) any |= bits[i + k];
    if (any != 0) return false;
  }
  for (; i < n; ++i)
    if (bits[i] != 0) return false;
  return true;
}

}  // namespace

size_t RowBlockScratchSize(uint64_t r) {
  return std::max<size_t>(6 * r * r * kLanes + wavelet::ScratchSize(r, r, kLanes), wavelet::FaceScratchSize(r));
}

namespace {

// The generic path (any filter and R): kLanes rows at a time as the lanes of
// wavelet::Forward2D, through a transpose in and out. In place.
void TransformRowBlockLanes(wavelet::Filter filter, uint64_t r, float* data, uint64_t rows, float* scratch,
                            uint64_t* zero_rows) {
  const uint64_t cols = 6 * r * r;
  const int depth = wavelet::MaxDepth(r, r);
  float* lanes = scratch;                 // [column][lane]
  float* work = scratch + cols * kLanes;  // wavelet scratch
  std::vector<uint64_t> batch;
  batch.reserve(kLanes);
  uint64_t next = 0;
  while (next < rows) {
    batch.clear();
    while (next < rows && batch.size() < kLanes) {
      float* row = data + next * cols;
      if (RowIsZero(row, cols)) {
        ++*zero_rows;  // the transform of zero is zero: nothing to do
      } else {
        batch.push_back(next);
      }
      ++next;
    }
    if (batch.empty()) continue;
    const uint64_t n = batch.size();
    float* ptrs[kLanes];
    for (uint64_t k = 0; k < n; ++k) ptrs[k] = data + batch[k] * cols;
    Gather(ptrs, n, cols, lanes);
    for (uint64_t face = 0; face < 6; ++face) {
      wavelet::Forward2D(filter, lanes + face * r * r * n, r, r, n, depth, work);
    }
    Scatter(lanes, n, cols, ptrs);
  }
}

}  // namespace

void TransformRows(wavelet::Filter filter, uint64_t r, const float* src, float* dst, uint64_t rows, float* scratch,
                   uint64_t* zero_rows) {
  const uint64_t cols = 6 * r * r;
  if (!wavelet::HasFaceKernel(filter, r)) {  // decided by (filter, R) alone: every row takes the same path
    if (src != dst) std::memcpy(dst, src, rows * cols * sizeof(float));
    TransformRowBlockLanes(filter, r, dst, rows, scratch, zero_rows);
    return;
  }
  // Straight from src to dst, face after face, each run of non-zero rows in one call (the
  // kernel requests the lines of the faces ahead): bit-identical to the lanes path
  // (face_kernel.h), without the transposes and copies.
  for (uint64_t i = 0; i < rows;) {
    uint64_t end = i;
    while (end < rows && !RowIsZero(src + end * cols, cols)) ++end;
    if (end > i) wavelet::ForwardFaces(filter, r, 6 * (end - i), src + i * cols, dst + i * cols, scratch);
    if (end < rows) {  // row `end` is all zero, and so is its transform
      ++*zero_rows;
      if (dst != src) std::memset(dst + end * cols, 0, cols * sizeof(float));
    }
    i = end + 1;
  }
}

void TransformRowBlock(wavelet::Filter filter, uint64_t r, float* data, uint64_t rows, float* scratch,
                       uint64_t* zero_rows) {
  TransformRows(filter, r, data, data, rows, scratch, zero_rows);
}

Result<RowTransformResult> RunRowTransform(const RowTransformOptions& o, const Progress& progress) {
  LTB_ASSIGN_OR_RETURN(io::ContainerReader in, io::ContainerReader::Open(o.input));
  LTB_RETURN_IF_ERROR(RefuseCpcaOutput(in, "row-transform"));
  const Metadata& meta = in.metadata();
  const ArraySpec& a = meta.matrix();
  auto cube = ReadCubemapCols(meta);
  if (!cube.ok()) return cube.status().WithContext(o.input);
  if (!cube->has_value()) {
    return FailedPrecondition(
        o.input + ": its columns are not declared a cubemap (basis.cols is " +
        JsonText(meta.json.value("basis", nlohmann::json::object()).value("cols", nlohmann::json())) +
        "); row-transform needs pixel-basis cubemap columns: produce the matrix with `ltbake sample` "
        "or declare it with `ltbake convert IN.npy OUT.ltm --cube-res R`");
  }
  const CubemapCols& cc = **cube;
  if (cc.basis == "wavelet") {
    return FailedPrecondition(o.input + ": is already row-transformed (filter " + cc.filter +
                              "); row-transform takes the raw pixel-basis matrix from `ltbake sample`");
  }
  if (cc.basis != "pixel") {
    return FailedPrecondition(o.input + ": columns are in basis \"" + cc.basis + "\"; row-transform needs \"pixel\"");
  }
  if (a.layout != Layout::kRows) {
    return FailedPrecondition(o.input +
                              ": is stored in column blocks; row-transform needs row blocks — run it "
                              "before `ltbake transpose`, on the output of `ltbake sample`");
  }
  LTB_RETURN_IF_ERROR(RequireCompleteF32Matrix(in));

  nlohmann::json out_meta = meta.json;
  out_meta["basis"]["cols"] = WaveletCubemapCols(cc.cube_res, wavelet::FilterName(o.filter));
  out_meta["provenance"] =
      Provenance("row-transform", {{"filter", wavelet::FilterName(o.filter)}, {"zstd", o.zstd}}, {&in});
  io::WriterOptions wo;
  wo.overwrite_mismatch = o.overwrite;
  wo.direct_io = o.direct_io;
  LTB_ASSIGN_OR_RETURN(io::ContainerWriter out, io::OpenStageOutput(o.output, out_meta, wo, o.shard));

  RowTransformResult result;
  result.rows = a.rows;
  result.cube_res = cc.cube_res;
  for (const ArraySpec& s : meta.arrays) result.chunks_total += s.ChunkCount();
  result.chunks_already_committed = out.resume_info().committed_chunks;

  struct Item {
    uint32_t array;
    uint64_t chunk;
  };
  std::vector<Item> items;
  for (uint32_t arr = 0; arr < meta.arrays.size(); ++arr)
    for (uint64_t c : out.Missing(arr)) items.push_back({arr, c});

  EncodeOptions eo;
  eo.zstd = o.zstd;
  std::atomic<uint64_t> written{0}, zero_chunks{0}, zero_rows{0};
  Status s = ParallelFor(items, o.jobs, progress, "chunks", [&](const Item& it) -> Status {
    const IndexEntry* entry = in.Find(it.array, it.chunk);
    if (entry->header.encoding == static_cast<uint16_t>(Encoding::kZero)) {
      EncodedChunk z;
      z.encoding = Encoding::kZero;
      z.decoded_length = entry->header.decoded_length;
      z.checksum = Checksum({});
      LTB_RETURN_IF_ERROR(out.Append(it.array, it.chunk, z, 0));  // zeros add nothing to content_hash
      if (it.array == 0) zero_chunks++;
      written++;
      return Status::Ok();
    }
    LTB_ASSIGN_OR_RETURN(io::Chunk chunk, in.ReadChunk(it.array, it.chunk));
    if (it.array != 0) {  // side tables (mask, positions, ...) pass through unchanged
      LTB_RETURN_IF_ERROR(out.Put(it.array, it.chunk, chunk.bytes(), eo));
      written++;
      return Status::Ok();
    }
    thread_local std::vector<float> buf, scratch;
    auto values = chunk.as<float>();
    buf.resize(values.size());
    scratch.resize(RowBlockScratchSize(cc.cube_res));
    uint64_t zr = 0;
    // Straight from the mapped chunk into the output buffer: no copy first.
    TransformRows(o.filter, cc.cube_res, values.data(), buf.data(), chunk.extent().rows, scratch.data(), &zr);
    zero_rows += zr;
    LTB_RETURN_IF_ERROR(
        out.Put(0, it.chunk, ByteSpan(reinterpret_cast<const std::byte*>(buf.data()), buf.size() * 4), eo));
    written++;
    return Status::Ok();
  });
  result.chunks_written = written;
  const io::DirectIoStats ds = out.direct_io_stats();
  result.bytes_direct = ds.direct_bytes;
  result.direct_fallback = ds.fallback_reason;
  result.zero_chunks = zero_chunks;
  result.zero_rows = zero_rows;
  LTB_RETURN_IF_ERROR(s);
  LTB_RETURN_IF_ERROR(out.Finish());
  return result;
}

}  // namespace ltb::stages
