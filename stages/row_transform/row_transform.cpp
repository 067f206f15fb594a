#include "stages/row_transform/row_transform.h"

#include <atomic>
#include <cstring>
#include <filesystem>
#include <vector>

#include "format/io/container_reader.h"
#include "format/io/container_writer.h"
#include "stages/common/basis.h"
#include "stages/common/parallel_for.h"

namespace ltb::stages {

using namespace ltb::format;

namespace {

// Rows transformed together: each pixel of a face becomes a vector of kLanes values (one
// per matrix row), so every filter tap is one contiguous vector operation.
constexpr uint64_t kLanes = 16;

bool RowIsZero(const float* row, uint64_t n) {
  const uint32_t* bits = reinterpret_cast<const uint32_t*>(row);
  for (uint64_t i = 0; i < n; ++i)
    if (bits[i] != 0) return false;
  return true;
}

}  // namespace

size_t RowBlockScratchSize(uint64_t r) { return 6 * r * r * kLanes + wavelet::ScratchSize(r, r, kLanes); }

void TransformRowBlock(wavelet::Filter filter, uint64_t r, float* data, uint64_t rows, float* scratch,
                       uint64_t* zero_rows) {
  const uint64_t cols = 6 * r * r;
  const int depth = wavelet::MaxDepth(r, r);
  float* lanes = scratch;                       // [column][lane]
  float* work = scratch + cols * kLanes;        // wavelet scratch
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
    // Gather: lanes[c * n + k] = row batch[k], column c.
    for (uint64_t k = 0; k < n; ++k) {
      const float* row = data + batch[k] * cols;
      for (uint64_t c = 0; c < cols; ++c) lanes[c * n + k] = row[c];
    }
    for (uint64_t face = 0; face < 6; ++face) {
      wavelet::Forward2D(filter, lanes + face * r * r * n, r, r, n, depth, work);
    }
    for (uint64_t k = 0; k < n; ++k) {
      float* row = data + batch[k] * cols;
      for (uint64_t c = 0; c < cols; ++c) row[c] = lanes[c * n + k];
    }
  }
}

Result<RowTransformResult> RunRowTransform(const RowTransformOptions& o, const Progress& progress) {
  LTB_ASSIGN_OR_RETURN(io::ContainerReader in, io::ContainerReader::Open(o.input));
  const Metadata& meta = in.metadata();
  const ArraySpec& a = meta.matrix();
  auto cube = ReadCubemapCols(meta);
  if (!cube.ok()) return cube.status().WithContext(o.input);
  if (!cube->has_value()) {
    return FailedPrecondition(o.input + ": its columns are not declared a cubemap (basis.cols is " +
                              meta.json.value("basis", nlohmann::json::object()).value("cols", nlohmann::json()).dump() +
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
    return FailedPrecondition(o.input + ": is stored in column blocks; row-transform needs row blocks — run it "
                              "before `ltbake transpose`, on the output of `ltbake sample`");
  }
  if (a.dtype != DType::kF32) {
    return FailedPrecondition(o.input + ": matrix dtype is " + std::string(DTypeName(a.dtype)) + "; expected f32");
  }
  if (!in.complete()) {
    return FailedPrecondition(o.input + ": is incomplete (" + std::to_string(in.committed(0)) + " of " +
                              std::to_string(a.ChunkCount()) +
                              " chunks); finish the stage that writes it first (rerun it to resume)");
  }

  nlohmann::json out_meta = meta.json;
  out_meta["basis"]["cols"] = WaveletCubemapCols(cc.cube_res, wavelet::FilterName(o.filter));
  out_meta["provenance"] =
      Provenance("row-transform", {{"filter", wavelet::FilterName(o.filter)}, {"zstd", o.zstd}}, {&in});
  io::WriterOptions wo;
  wo.overwrite_mismatch = o.overwrite;
  LTB_ASSIGN_OR_RETURN(io::ContainerWriter out, io::ContainerWriter::Open(o.output, out_meta, wo));

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
      LTB_RETURN_IF_ERROR(out.Append(it.array, it.chunk, z));
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
    buf.assign(values.begin(), values.end());
    scratch.resize(RowBlockScratchSize(cc.cube_res));
    uint64_t zr = 0;
    TransformRowBlock(o.filter, cc.cube_res, buf.data(), chunk.extent().rows, scratch.data(), &zr);
    zero_rows += zr;
    LTB_RETURN_IF_ERROR(out.Put(0, it.chunk, ByteSpan(reinterpret_cast<const std::byte*>(buf.data()), buf.size() * 4), eo));
    written++;
    return Status::Ok();
  });
  result.chunks_written = written;
  result.zero_chunks = zero_chunks;
  result.zero_rows = zero_rows;
  LTB_RETURN_IF_ERROR(s);
  LTB_RETURN_IF_ERROR(out.Finish());
  return result;
}

}  // namespace ltb::stages
