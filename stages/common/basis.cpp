#include "stages/common/basis.h"

#include <xxhash.h>

#include <algorithm>
#include <cstring>
#include <filesystem>

#include "format/version.h"

namespace ltb::stages {

nlohmann::json PixelCubemapCols(uint64_t r) { return {{"kind", "cubemap"}, {"cube_res", r}, {"basis", "pixel"}}; }

nlohmann::json WaveletCubemapCols(uint64_t r, const std::string& filter) {
  uint64_t depth = 0;
  while ((uint64_t{1} << depth) < r) ++depth;
  return {{"kind", "cubemap"}, {"cube_res", r},  {"basis", "wavelet"},
          {"filter", filter},  {"depth", depth}, {"layout", "mallat per face"}};
}

nlohmann::json ImageRows(uint64_t w, uint64_t h) { return {{"kind", "image"}, {"width", w}, {"height", h}}; }
nlohmann::json GenericAxis() { return {{"kind", "generic"}}; }

Result<std::optional<CubemapCols>> ReadCubemapCols(const format::Metadata& meta) {
  const auto& j = meta.json;
  if (!j.contains("basis") || !j["basis"].is_object() || !j["basis"].contains("cols"))
    return std::optional<CubemapCols>{};
  const auto& c = j["basis"]["cols"];
  if (!c.is_object() || c.value("kind", "") != "cubemap") return std::optional<CubemapCols>{};
  CubemapCols out;
  if (!c.contains("cube_res") || !c["cube_res"].is_number_unsigned()) {
    return InvalidArgument("metadata basis.cols is a cubemap without a valid cube_res");
  }
  out.cube_res = c["cube_res"].get<uint64_t>();
  out.basis = c.value("basis", "");
  out.filter = c.value("filter", "");
  if (!IsPowerOfTwo(out.cube_res) || out.cube_res > (1u << 16)) {
    return InvalidArgument("metadata basis.cols.cube_res is " + std::to_string(out.cube_res) +
                           "; it must be a power of two");
  }
  uint64_t want = 6 * out.cube_res * out.cube_res;
  if (meta.matrix().cols != want) {
    return InvalidArgument("metadata says the columns are a cubemap with R = " + std::to_string(out.cube_res) +
                           " (6·R² = " + std::to_string(want) + " columns) but the matrix has " +
                           std::to_string(meta.matrix().cols));
  }
  return std::optional<CubemapCols>{out};
}

std::optional<ImageSize> ReadImageRows(const format::Metadata& meta) {
  const auto& j = meta.json;
  if (!j.contains("basis") || !j["basis"].is_object() || !j["basis"].contains("rows")) return std::nullopt;
  const auto& r = j["basis"]["rows"];
  if (!r.is_object() || r.value("kind", "") != "image") return std::nullopt;
  if (!r.contains("width") || !r.contains("height") || !r["width"].is_number_unsigned() ||
      !r["height"].is_number_unsigned()) {
    return std::nullopt;
  }
  ImageSize s{r["width"].get<uint64_t>(), r["height"].get<uint64_t>()};
  if (s.width * s.height != meta.matrix().rows) return std::nullopt;
  return s;
}

Status RefuseCpcaOutput(const io::ContainerReader& in, const std::string& stage) {
  if (!in.metadata().json.contains("cpca")) return Status::Ok();
  return FailedPrecondition(in.path() +
                            ": is a cpca output (cluster means, bases and per-row weights), not a "
                            "transport matrix; " +
                            stage +
                            " takes the matrix itself (rows.ltm and what follows it). "
                            "Use cpca.ltm with `ltbake relight` or `ltbake convert`");
}

Status RequireCompleteF32Matrix(const io::ContainerReader& in) {
  const format::ArraySpec& a = in.metadata().matrix();
  if (a.dtype != format::DType::kF32) {
    return FailedPrecondition(in.path() + ": matrix dtype is " + std::string(format::DTypeName(a.dtype)) +
                              "; expected f32");
  }
  if (!in.complete()) {
    uint64_t committed = 0, expected = 0;
    for (uint32_t i = 0; i < in.metadata().arrays.size(); ++i) {
      committed += in.committed(i);
      expected += in.metadata().arrays[i].ChunkCount();
    }
    return FailedPrecondition(in.path() + ": is incomplete (" + std::to_string(committed) + " of " +
                              std::to_string(expected) +
                              " chunks); finish the stage that writes it first (rerun it to resume)");
  }
  return Status::Ok();
}

std::string Fingerprint(const io::ContainerReader& reader) { return io::IndexFingerprint(reader); }

nlohmann::json Provenance(const std::string& stage, const nlohmann::json& parameters,
                          const std::vector<const io::ContainerReader*>& inputs) {
  nlohmann::json in = nlohmann::json::array();
  for (const auto* r : inputs) {
    in.push_back({{"file", std::filesystem::path(r->path()).filename().string()}, {"fingerprint", Fingerprint(*r)}});
  }
  return {
      {"tool", std::string("ltbake ") + kToolVersion}, {"stage", stage}, {"parameters", parameters}, {"inputs", in}};
}

format::ArraySpec PassThroughSpec(const format::ArraySpec& in) {
  format::ArraySpec out = in;
  if (in.layout == format::Layout::kRows) {
    out.block = format::BlockForTargetBytes(in.rows, in.cols, in.dtype, in.layout, kSideTableChunkBytes);
  }
  return out;
}

Result<std::vector<std::byte>> ReadLines(const io::ContainerReader& in, uint32_t arr, uint64_t l0, uint64_t l1,
                                         const io::ReadOptions& options) {
  const format::ArraySpec& src = in.metadata().arrays.at(arr);
  const bool rows = src.layout == format::Layout::kRows;
  const uint64_t lines = rows ? src.rows : src.cols;
  const uint64_t line = (rows ? src.cols : src.rows) * format::DTypeSize(src.dtype);
  if (l0 > l1 || l1 > lines) {
    return InvalidArgument(in.path() + ": lines " + std::to_string(l0) + ".." + std::to_string(l1) + " of \"" +
                           src.name + "\", which has " + std::to_string(lines));
  }
  std::vector<std::byte> buf((l1 - l0) * line);
  for (uint64_t ic = l0 / src.block; ic * src.block < l1; ++ic) {
    LTB_ASSIGN_OR_RETURN(io::Chunk chunk, in.ReadChunk(arr, ic, options));
    const uint64_t i0 = ic * src.block, a = std::max(i0, l0), b = std::min(i0 + src.block, l1);
    std::memcpy(buf.data() + (a - l0) * line, chunk.bytes().data() + (a - i0) * line, (b - a) * line);
  }
  return buf;
}

Status CopyArray(const io::ContainerReader& in, uint32_t arr, io::ContainerWriter& out, uint64_t* chunks_written) {
  return CopyArray(in, arr, out, arr, chunks_written);
}

Status CopyArray(const io::ContainerReader& in, uint32_t arr, io::ContainerWriter& out, uint32_t dst_arr,
                 uint64_t* chunks_written) {
  const format::ArraySpec& src = in.metadata().arrays[arr];
  const format::ArraySpec& dst = out.metadata().arrays[dst_arr];
  if (src.layout != dst.layout || src.rows != dst.rows || src.cols != dst.cols || src.dtype != dst.dtype) {
    return Internal("CopyArray: array \"" + src.name + "\" changes shape, dtype or layout");
  }
  const uint64_t lines = src.layout == format::Layout::kRows ? src.rows : src.cols;
  format::EncodeOptions eo;
  eo.zstd = true;
  for (uint64_t c : out.Missing(dst_arr)) {
    if (src.block == dst.block) {
      LTB_ASSIGN_OR_RETURN(io::Chunk chunk, in.ReadChunk(arr, c));
      LTB_RETURN_IF_ERROR(out.Put(dst_arr, c, chunk.bytes(), eo));
    } else {
      const uint64_t l0 = c * dst.block, l1 = std::min(lines, l0 + dst.block);
      LTB_ASSIGN_OR_RETURN(std::vector<std::byte> buf, ReadLines(in, arr, l0, l1));
      LTB_RETURN_IF_ERROR(out.Put(dst_arr, c, format::ByteSpan(buf.data(), buf.size()), eo));
    }
    if (chunks_written) ++*chunks_written;
  }
  return Status::Ok();
}

bool KeptByCompressedOutputs(const std::string& name) { return name == "mask" || name == "reflectance"; }

}  // namespace ltb::stages
