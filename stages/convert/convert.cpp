#include "stages/convert/convert.h"

#include <atomic>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <limits>
#include <mutex>
#include <optional>
#include <span>
#include <thread>
#include <vector>

#include "format/content_hash.h"
#include "format/io/atomic_file.h"
#include "format/io/container_reader.h"
#include "format/io/container_writer.h"
#include "format/io/file.h"
#include "format/io/file_lock.h"
#include "format/io/mapped_region.h"
#include "format/npy.h"
#include "format/version.h"
#include "stages/column_transform/column_codec.h"
#include "stages/common/basis.h"
#include "stages/common/channels.h"
#include "stages/common/parallel_for.h"
#include "stages/cpca/cpca_model.h"

namespace ltb::stages {

using namespace ltb::format;
using io::File;

namespace {

// --basis pixels: inverts the row transform of decoded rows (a no-op without the flag).
struct RowInverse {
  std::optional<wavelet::Filter> filter;
  uint64_t cube_res = 0;

  static Result<RowInverse> For(const ConvertOptions& o, const io::ContainerReader& reader) {
    RowInverse inv;
    if (!o.pixel_basis) return inv;
    auto cube = ReadCubemapCols(reader.metadata());
    if (!cube.ok()) return cube.status().WithContext(o.input);
    if (!cube->has_value() || (*cube)->basis != "wavelet") {
      return FailedPrecondition(o.input + ": --basis pixels needs row-transformed (wavelet-basis cubemap) columns");
    }
    LTB_ASSIGN_OR_RETURN(wavelet::Filter f, wavelet::ParseFilter((*cube)->filter));
    inv.filter = f;
    inv.cube_res = (*cube)->cube_res;
    return inv;
  }

  // `n` rows of `cols` values each, in place.
  void operator()(float* rows_data, uint64_t n, uint64_t cols) const {
    if (!filter) return;
    std::vector<float> scratch(wavelet::ScratchSize(cube_res, cube_res, 1));
    const int depth = wavelet::MaxDepth(cube_res, cube_res);
    for (uint64_t r = 0; r < n; ++r)
      for (uint64_t face = 0; face < 6; ++face)
        wavelet::Inverse2D(*filter, rows_data + r * cols + face * cube_res * cube_res, cube_res, cube_res, 1, depth,
                           scratch.data());
  }
};

struct NpyInput {
  File file;
  NpyHeader header;
  uint64_t rows = 0, cols = 0;
};

Result<NpyInput> OpenNpy(const std::string& path) {
  NpyInput in;
  LTB_RETURN_IF_ERROR(io::RequireRegularFile(path, "convert reads a .npy or .ltm file"));
  LTB_ASSIGN_OR_RETURN(in.file, File::Open(path, File::Mode::kRead));
  LTB_ASSIGN_OR_RETURN(uint64_t size, in.file.Size());
  std::vector<std::byte> head(std::min<uint64_t>(size, kMaxNpyHeaderBytes + 12));
  LTB_RETURN_IF_ERROR(in.file.ReadAt(0, head));
  auto h = ParseNpyHeader(head);
  if (!h.ok()) return h.status().WithContext(path);
  in.header = *h;
  const NpyHeader& hd = in.header;
  if (hd.itemsize == 0) {
    return InvalidArgument(path + ": dtype '" + hd.descr +
                           "' is not supported; convert accepts little-endian float32 ('<f4') or float64 ('<f8') — "
                           "save with arr.astype('<f4')");
  }
  if (hd.fortran_order) {
    return InvalidArgument(path + ": array is in Fortran (column-major) order; save it with np.ascontiguousarray(arr)");
  }
  if (hd.shape.size() != 2) {
    std::string shape;
    for (uint64_t d : hd.shape) shape += (shape.empty() ? "" : ", ") + std::to_string(d);
    return InvalidArgument(path + ": array has shape (" + shape + "), " + std::to_string(hd.shape.size()) +
                           "-D; convert needs a 2-D matrix (reshape to (1, N) or (N, 1))");
  }
  in.rows = hd.shape[0];
  in.cols = hd.shape[1];
  if (in.rows == 0 || in.cols == 0 || in.rows > kMaxDim || in.cols > kMaxDim) {
    return InvalidArgument(path + ": shape (" + std::to_string(in.rows) + ", " + std::to_string(in.cols) +
                           ") is empty or beyond " + std::to_string(kMaxDim) + " per axis");
  }
  // Checked: a shape whose size passes 2^64 is named as such, never as a wrapped size.
  auto data = NpyDataBytes(hd);
  if (!data.ok()) return data.status().WithContext(path);
  uint64_t bytes;
  if (AddOverflows(*data, hd.data_offset, &bytes) || bytes != size) {
    return InvalidArgument(path + ": shape (" + std::to_string(in.rows) + ", " + std::to_string(in.cols) + ") of '" +
                           hd.descr + "' needs " + std::to_string(*data) + " bytes of data after the " +
                           std::to_string(hd.data_offset) + "-byte header, the file has " + std::to_string(size) +
                           " bytes in all (truncated or damaged?)");
  }
  return in;
}

// Converts f64 values to f32; a finite value beyond the f32 range is an error.
Status NarrowToF32(const double* src, float* dst, uint64_t n, const std::string& path, uint64_t first_element,
                   uint64_t cols, bool col_major, uint64_t rows) {
  for (uint64_t k = 0; k < n; ++k) {
    double v = src[k];
    if (std::isfinite(v) && std::fabs(v) > static_cast<double>(std::numeric_limits<float>::max())) {
      uint64_t e = first_element + k;
      uint64_t r = col_major ? e % rows : e / cols, c = col_major ? e / rows : e % cols;
      char buf[64];
      std::snprintf(buf, sizeof buf, "%.17g", v);
      return InvalidArgument(path + ": value " + buf + " at row " + std::to_string(r) + ", column " +
                             std::to_string(c) + " is beyond the float32 range; scale the matrix first");
    }
    dst[k] = static_cast<float>(v);
  }
  return Status::Ok();
}

// The output's metadata: the matrix array, the bases --cube-res and --image-size name (checked
// against the input's shape) and the source's provenance.
Result<nlohmann::json> NpyMetadata(const ConvertOptions& o, const NpyInput& in, const ArraySpec& spec) {
  nlohmann::json rows_basis = GenericAxis(), cols_basis = GenericAxis();
  if (o.cube_res != 0) {
    if (!IsPowerOfTwo(o.cube_res) || o.cube_res > (1u << 16)) {
      return InvalidArgument("--cube-res " + std::to_string(o.cube_res) + " is not a power of two");
    }
    if (in.cols != 6 * o.cube_res * o.cube_res) {
      return InvalidArgument(o.input + ": has " + std::to_string(in.cols) + " columns; a cubemap with --cube-res " +
                             std::to_string(o.cube_res) +
                             " needs 6·R² = " + std::to_string(6 * o.cube_res * o.cube_res));
    }
    cols_basis = PixelCubemapCols(o.cube_res);
  }
  if (o.image_width != 0 || o.image_height != 0) {
    if (o.image_width * o.image_height != in.rows) {
      return InvalidArgument(o.input + ": has " + std::to_string(in.rows) + " rows; an image of " +
                             std::to_string(o.image_width) + "x" + std::to_string(o.image_height) + " needs " +
                             std::to_string(o.image_width * o.image_height));
    }
    rows_basis = ImageRows(o.image_width, o.image_height);
  }
  return nlohmann::json{
      {"arrays", {spec.ToJson()}},
      {"basis", {{"rows", rows_basis}, {"cols", cols_basis}}},
      {"provenance",
       {{"tool", std::string("ltbake ") + kToolVersion},
        {"stage", "convert"},
        {"parameters",
         {{"source", std::filesystem::path(o.input).filename().string()},
          {"source_dtype", in.header.descr},
          {"source_bytes", in.header.data_offset + in.rows * in.cols * in.header.itemsize},
          {"zstd", o.zstd}}}}},
  };
}

// One chunk's values from the input, in the output's layout (a column layout reads the whole
// input's mapping, `whole`).
Status ReadNpyChunk(const NpyInput& in, const ArraySpec& spec, const io::MappedRegion& whole, const std::string& input,
                    uint64_t chunk, std::vector<float>& values) {
  ChunkExtent e = spec.Extent(chunk);
  uint64_t n = e.Elements();
  values.assign(n, 0.0f);
  uint64_t item = in.header.itemsize;
  if (spec.layout == Layout::kRows) {
    uint64_t first = e.row0 * in.cols;
    uint64_t offset = in.header.data_offset + first * item;
    if (item == 4) {
      return in.file.ReadAt(offset, MutableByteSpan(reinterpret_cast<std::byte*>(values.data()), n * 4));
    }
    std::vector<double> src(n);
    LTB_RETURN_IF_ERROR(in.file.ReadAt(offset, MutableByteSpan(reinterpret_cast<std::byte*>(src.data()), n * 8)));
    return NarrowToF32(src.data(), values.data(), n, input, first, in.cols, false, in.rows);
  }
  const std::byte* base = whole.bytes().data() + in.header.data_offset;
  for (uint64_t c = 0; c < e.cols; ++c) {
    for (uint64_t r = 0; r < in.rows; ++r) {
      const std::byte* p = base + (r * in.cols + e.col0 + c) * item;
      if (item == 4) {
        std::memcpy(&values[c * in.rows + r], p, 4);
      } else {
        double v;
        std::memcpy(&v, p, 8);
        LTB_RETURN_IF_ERROR(
            NarrowToF32(&v, &values[c * in.rows + r], 1, input, r * in.cols + e.col0 + c, in.cols, false, in.rows));
      }
    }
  }
  return Status::Ok();
}

Result<ConvertResult> NpyToLtm(const ConvertOptions& o, const Progress& progress) {
  LTB_ASSIGN_OR_RETURN(NpyInput in, OpenNpy(o.input));
  int jobs = std::max(1, o.jobs);
  // Buffers per worker: f32 chunk + source bytes + zstd bound: about 3-4 chunk sizes.
  uint64_t chunk_bytes = std::max<uint64_t>(1, std::min(o.chunk_bytes, o.mem_limit / (4 * jobs)));
  ArraySpec spec;
  spec.name = "matrix";
  spec.dtype = DType::kF32;
  spec.rows = in.rows;
  spec.cols = in.cols;
  spec.layout = o.layout;
  spec.block = BlockForTargetBytes(in.rows, in.cols, DType::kF32, o.layout, chunk_bytes);
  LTB_RETURN_IF_ERROR(spec.Validate().WithContext(o.output));

  LTB_ASSIGN_OR_RETURN(const nlohmann::json meta, NpyMetadata(o, in, spec));
  io::WriterOptions wo;
  wo.overwrite_mismatch = o.overwrite;
  LTB_ASSIGN_OR_RETURN(io::ContainerWriter writer, io::ContainerWriter::Open(o.output, meta, wo));

  // Column blocks gather strided values: map the input once for that.
  io::MappedRegion whole;
  if (o.layout == Layout::kCols) {
    LTB_ASSIGN_OR_RETURN(
        whole,
        io::MappedRegion::Map(in.file.fd(), 0, in.header.data_offset + in.rows * in.cols * in.header.itemsize, false));
  }
  auto read_chunk = [&](uint64_t chunk, std::vector<float>& values) -> Status {
    return ReadNpyChunk(in, spec, whole, o.input, chunk, values);
  };

  ConvertResult result;
  // A resumed output is this input's only if its committed chunks hold this input's values
  // (the metadata names the source by file name and size, not by content): a changed
  // .npy is refused, or with --overwrite converted again from the start.
  if (writer.resume_info().resumed) {
    std::vector<uint64_t> committed;
    for (uint64_t c = 0; c < spec.ChunkCount(); ++c) {
      if (writer.Has(0, c)) committed.push_back(c);
    }
    Status same = ParallelFor(committed, jobs, progress, "chunks checked", [&](uint64_t chunk) -> Status {
      std::vector<float> values;
      LTB_RETURN_IF_ERROR(read_chunk(chunk, values));
      return writer.CheckResumedChunk(0, chunk,
                                      ByteSpan(reinterpret_cast<const std::byte*>(values.data()), values.size() * 4));
    });
    if (!same.ok()) {
      if (!o.overwrite || same.code() != StatusCode::kFailedPrecondition) return same;
      result.restarted_because = same.message().substr(0, same.message().find("; remove it"));
      LTB_RETURN_IF_ERROR(writer.Discard());
      LTB_ASSIGN_OR_RETURN(writer, io::ContainerWriter::Open(o.output, meta, wo));
    }
  }

  result.rows = in.rows;
  result.cols = in.cols;
  result.chunks_total = spec.ChunkCount();
  result.chunks_already_committed = writer.resume_info().committed_chunks;
  result.discarded_tail_bytes = writer.resume_info().discarded_tail_bytes;
  std::vector<uint64_t> missing = writer.Missing(0);

  EncodeOptions eo;
  eo.zstd = o.zstd;
  std::atomic<uint64_t> zeros{0}, zstds{0}, written{0};
  Status s = ParallelFor(missing, jobs, progress, "chunks", [&](uint64_t chunk) -> Status {
    ChunkExtent e = spec.Extent(chunk);
    uint64_t n = e.Elements();
    std::vector<float> values;
    LTB_RETURN_IF_ERROR(read_chunk(chunk, values));
    const ByteSpan bytes(reinterpret_cast<const std::byte*>(values.data()), n * 4);
    EncodedChunk enc = EncodeChunk(bytes, eo);
    if (enc.encoding == Encoding::kZero) zeros++;
    if (enc.encoding == Encoding::kZstd) zstds++;
    LTB_RETURN_IF_ERROR(writer.Append(0, chunk, enc, ChunkHashSum(writer.metadata().arrays[0], e, bytes)));
    written++;
    return Status::Ok();
  });
  result.chunks_written = written;
  result.zero_chunks = zeros;
  result.zstd_chunks = zstds;
  if (!s.ok()) {
    // Bad input found part way: a file this run created cannot be finished, so it goes.
    // An interrupted run keeps its file so the next run resumes it.
    if (s.code() == StatusCode::kInvalidArgument && !writer.resume_info().resumed) (void)writer.Discard();
    return s;
  }
  LTB_RETURN_IF_ERROR(writer.Finish());
  LTB_ASSIGN_OR_RETURN(File out, File::Open(o.output, File::Mode::kRead));
  LTB_ASSIGN_OR_RETURN(result.bytes_out, out.Size());
  return result;
}

// Where one matrix's values go inside a .npy being written (a channel set's output): the
// file and the byte offset of the matrix's first value.
struct NpySlot {
  const File* file = nullptr;
  uint64_t offset = 0;
};

// A .npy output of shape `shape`: its own file, written beside the output and renamed on
// Commit (OUT never holds a partial matrix), with the header and the full length (zero
// chunks need no write); or, given a slot, that slot in a file someone else commits.
class NpyOutput {
 public:
  static Result<NpyOutput> Open(const std::string& path, const std::vector<uint64_t>& shape, const NpySlot* slot) {
    NpyOutput n;
    if (slot != nullptr) {
      n.slot_ = *slot;
      return n;
    }
    const std::vector<std::byte> header = EncodeNpyHeader("<f4", shape);
    uint64_t values = 1;
    for (uint64_t d : shape) values *= d;
    const uint64_t total = header.size() + values * 4;
    LTB_ASSIGN_OR_RETURN(io::AtomicFile atomic, io::AtomicFile::Create(path));
    LTB_RETURN_IF_ERROR(atomic.file().WriteAt(0, header));
    LTB_RETURN_IF_ERROR(atomic.file().Truncate(total));
    n.atomic_.emplace(std::move(atomic));
    n.slot_ = {nullptr, header.size()};  // file() is the atomic file
    return n;
  }
  const File& file() const { return atomic_ ? atomic_->file() : *slot_.file; }
  uint64_t data_offset() const { return slot_.offset; }
  Status Commit() { return atomic_ ? atomic_->Commit() : Status::Ok(); }

 private:
  std::optional<io::AtomicFile> atomic_;
  NpySlot slot_;
};

// A cpca output decodes to its approximation, N × D, in the stored row basis (or, with
// --basis pixels, with the row transform inverted).
Result<ConvertResult> CpcaToNpy(const ConvertOptions& o, const io::ContainerReader& reader, const Progress& progress,
                                const NpySlot* slot) {
  LTB_ASSIGN_OR_RETURN(CpcaModel model, CpcaModel::Load(reader, o.mem_limit));
  LTB_ASSIGN_OR_RETURN(RowInverse to_pixels, RowInverse::For(o, reader));
  const uint64_t rows = model.rows(), cols = model.dims();
  ConvertResult result;
  result.rows = rows;
  result.cols = cols;
  result.chunks_total = model.row_chunks();
  LTB_ASSIGN_OR_RETURN(NpyOutput npy, NpyOutput::Open(o.output, {rows, cols}, slot));
  const File& out = npy.file();
  const uint64_t data_offset = npy.data_offset(), total = data_offset + rows * cols * 4;
  Status s;
  std::vector<uint64_t> chunks(model.row_chunks());
  for (uint64_t i = 0; i < chunks.size(); ++i) chunks[i] = i;
  if (s.ok()) {
    s = ParallelFor(chunks, o.jobs, progress, "chunks", [&](uint64_t c) -> Status {
      std::vector<float> v;
      LTB_RETURN_IF_ERROR(model.DecodeChunk(reader, c, &v));
      const ChunkExtent e = model.row_extent(c);
      to_pixels(v.data(), e.rows, cols);
      return out.WriteAt(data_offset + e.row0 * cols * 4, BytesOf(v));
    });
  }
  LTB_RETURN_IF_ERROR(s);
  LTB_RETURN_IF_ERROR(npy.Commit());
  result.chunks_written = chunks.size();
  result.bytes_out = total;
  return result;
}

Result<ConvertResult> LtmToNpy(const ConvertOptions& o, const Progress& progress, const NpySlot* slot = nullptr) {
  LTB_ASSIGN_OR_RETURN(io::ContainerReader reader, io::ContainerReader::Open(o.input));
  if (CpcaModel::IsCpca(reader.metadata())) return CpcaToNpy(o, reader, progress, slot);
  const ArraySpec& a = reader.metadata().matrix();
  std::optional<ColumnCodec> codec;
  if (ColumnCodec::IsColumnTransformed(reader.metadata())) {
    LTB_ASSIGN_OR_RETURN(ColumnCodec c, ColumnCodec::FromMetadata(reader.metadata(), o.input));
    codec = std::move(c);
  } else if (a.dtype != DType::kF32) {
    return InvalidArgument(o.input + ": matrix dtype is " + DTypeName(a.dtype) + "; convert to .npy handles f32");
  }
  LTB_ASSIGN_OR_RETURN(RowInverse to_pixels, RowInverse::For(o, reader));
  uint64_t missing = a.ChunkCount() - reader.committed(0);
  if (missing > 0) {
    uint64_t first = 0;
    while (reader.Find(0, first) != nullptr) ++first;
    return FailedPrecondition(o.input + ": incomplete: " + std::to_string(missing) + " of " +
                              std::to_string(a.ChunkCount()) + " chunks missing (first: chunk " +
                              std::to_string(first) + "); rerun the stage that writes it to resume");
  }
  ConvertResult result;
  result.rows = a.rows;
  result.cols = a.cols;
  result.chunks_total = a.ChunkCount();

  LTB_ASSIGN_OR_RETURN(NpyOutput npy, NpyOutput::Open(o.output, {a.rows, a.cols}, slot));
  const File& out = npy.file();
  const uint64_t data_offset = npy.data_offset(), total = data_offset + a.rows * a.cols * 4;

  std::vector<uint64_t> chunks;
  for (uint64_t i = 0; i < a.ChunkCount(); ++i) {
    if (reader.Find(0, i)->header.encoding == static_cast<uint16_t>(Encoding::kZero)) {
      result.zero_chunks++;
      continue;
    }
    chunks.push_back(i);
  }
  Status s;
  if (a.layout == Layout::kRows) {
    s = ParallelFor(chunks, o.jobs, progress, "chunks", [&](uint64_t i) -> Status {
      LTB_ASSIGN_OR_RETURN(io::Chunk c, reader.ReadChunk(0, i));
      if (!to_pixels.filter) return out.WriteAt(data_offset + c.extent().row0 * a.cols * 4, c.bytes());
      auto v = c.as<float>();
      std::vector<float> rows_data(v.begin(), v.end());
      to_pixels(rows_data.data(), c.extent().rows, a.cols);
      return out.WriteAt(data_offset + c.extent().row0 * a.cols * 4,
                         ByteSpan(reinterpret_cast<const std::byte*>(rows_data.data()), rows_data.size() * 4));
    });
  } else {
    // Column blocks: assemble bands of whole rows in memory, one write per band.
    uint64_t band = std::max<uint64_t>(1, std::min(a.rows, (o.mem_limit / 2) / (a.cols * 4)));
    std::vector<float> buf;
    for (uint64_t r0 = 0; r0 < a.rows && s.ok(); r0 += band) {
      uint64_t nr = std::min(band, a.rows - r0);
      buf.assign(nr * a.cols, 0.0f);
      io::ReadOptions ro;
      ro.verify_checksum = r0 == 0;  // each chunk is verified once, on the first band
      s = ParallelFor(chunks, o.jobs, Progress{}, "chunks", [&](uint64_t i) -> Status {
        const ChunkExtent e = a.Extent(i);
        std::span<const float> v;
        io::Chunk c;
        std::vector<float> decoded;
        if (codec) {
          LTB_RETURN_IF_ERROR(codec->DecodeChunk(reader, i, &decoded, ro));
          v = decoded;
        } else {
          LTB_ASSIGN_OR_RETURN(c, reader.ReadChunk(0, i, ro));
          v = c.as<float>();
        }
        for (uint64_t col = 0; col < e.cols; ++col)
          for (uint64_t r = 0; r < nr; ++r) buf[r * a.cols + e.col0 + col] = v[col * a.rows + r0 + r];
        return Status::Ok();
      });
      if (s.ok()) to_pixels(buf.data(), nr, a.cols);
      if (s.ok()) {
        s = out.WriteAt(data_offset + r0 * a.cols * 4,
                        ByteSpan(reinterpret_cast<const std::byte*>(buf.data()), buf.size() * 4));
      }
      progress.Report(r0 + nr, a.rows, "rows");
      if (s.ok() && progress.Cancelled()) s = Cancelled("interrupted; no output written");
    }
  }
  LTB_RETURN_IF_ERROR(s);
  LTB_RETURN_IF_ERROR(npy.Commit());
  result.chunks_written = a.ChunkCount();
  result.bytes_out = total;
  return result;
}

// A set (colour channels, a factored bake's terms) -> one .npy of shape (members, rows,
// cols): member m is [m] (docs/COLOUR.md).
Result<ConvertResult> SetToNpy(const ConvertOptions& o, const std::vector<SetMember>& members,
                               const Progress& progress) {
  std::vector<std::string> files;  // a colour factored bake's terms are colour sets: term-major, r, g, b
  for (const SetMember& m : members) {
    LTB_ASSIGN_OR_RETURN(std::vector<SetMember> inner, ChannelFiles(m.path));
    if (inner.empty()) files.push_back(m.path);
    for (const SetMember& i : inner) files.push_back(i.path);
  }
  std::vector<std::pair<uint64_t, uint64_t>> shapes;
  for (const std::string& f : files) {
    LTB_ASSIGN_OR_RETURN(io::ContainerReader r, io::ContainerReader::Open(f));
    if (CpcaModel::IsCpca(r.metadata())) {
      LTB_ASSIGN_OR_RETURN(CpcaModel m, CpcaModel::Load(r, o.mem_limit));
      shapes.emplace_back(m.rows(), m.dims());
    } else {
      shapes.emplace_back(r.metadata().matrix().rows, r.metadata().matrix().cols);
    }
    if (shapes.back() != shapes.front()) {
      return InvalidArgument(f + ": is " + std::to_string(shapes.back().first) + " x " +
                             std::to_string(shapes.back().second) + " but " + files.front() + " is " +
                             std::to_string(shapes.front().first) + " x " + std::to_string(shapes.front().second) +
                             ": the channels of a set must have one shape");
    }
  }
  const auto [rows, cols] = shapes.front();
  LTB_ASSIGN_OR_RETURN(NpyOutput npy, NpyOutput::Open(o.output, {files.size(), rows, cols}, nullptr));
  ConvertResult result;
  for (size_t c = 0; c < files.size(); ++c) {
    ConvertOptions oc = o;
    oc.input = files[c];
    const NpySlot slot{&npy.file(), npy.data_offset() + c * rows * cols * 4};
    LTB_ASSIGN_OR_RETURN(ConvertResult one, LtmToNpy(oc, progress, &slot));
    result.chunks_total += one.chunks_total;
    result.chunks_written += one.chunks_written;
    result.zero_chunks += one.zero_chunks;
  }
  LTB_RETURN_IF_ERROR(npy.Commit());
  result.channels = files.size();
  result.rows = rows;
  result.cols = cols;
  result.bytes_out = npy.data_offset() + files.size() * rows * cols * 4;
  return result;
}

}  // namespace

Result<ConvertResult> RunConvert(const ConvertOptions& o, const Progress& progress) {
  const bool to_ltm = o.input.ends_with(".npy") && o.output.ends_with(".ltm");
  const bool to_npy = o.input.ends_with(".ltm") && o.output.ends_with(".npy");
  if (to_ltm || to_npy) {
    // Held for the whole conversion (the container writer shares it): a second convert into
    // the same output stops here, before it removes or opens anything.
    LTB_ASSIGN_OR_RETURN(io::FileLock lock, io::LockOutput(o.output));
    if (to_ltm) return NpyToLtm(o, progress);
    LTB_ASSIGN_OR_RETURN(std::vector<SetMember> members, ChannelFiles(o.input));
    return members.empty() ? LtmToNpy(o, progress) : SetToNpy(o, members, progress);
  }
  return InvalidArgument("convert " + o.input + " " + o.output +
                         ": supported conversions are .npy -> .ltm, .ltm -> .npy and an environment map (.exr, .hdr) "
                         "-> .npy cubemap with --cube-res R (by file extension)");
}

}  // namespace ltb::stages
