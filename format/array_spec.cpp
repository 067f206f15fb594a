#include "format/array_spec.h"

#include <algorithm>
#include <set>
#include <tuple>

#include "format/json_text.h"

namespace ltb::format {

const char* DTypeName(DType t) {
  switch (t) {
    case DType::kF32:
      return "f32";
    case DType::kF64:
      return "f64";
    case DType::kU8:
      return "u8";
    case DType::kI32:
      return "i32";
    case DType::kU32:
      return "u32";
    case DType::kU64:
      return "u64";
  }
  return "?";
}

uint64_t DTypeSize(DType t) {
  switch (t) {
    case DType::kF32:
      return 4;
    case DType::kF64:
      return 8;
    case DType::kU8:
      return 1;
    case DType::kI32:
      return 4;
    case DType::kU32:
      return 4;
    case DType::kU64:
      return 8;
  }
  return 1;
}

Result<DType> ParseDType(const std::string& name) {
  for (DType t : {DType::kF32, DType::kF64, DType::kU8, DType::kI32, DType::kU32, DType::kU64}) {
    if (name == DTypeName(t)) return t;
  }
  return InvalidArgument("unknown dtype \"" + name + "\" (known: f32, f64, u8, i32, u32, u64)");
}

const char* LayoutName(Layout l) { return l == Layout::kRows ? "rows" : "cols"; }

uint64_t ArraySpec::ChunkCount() const {
  uint64_t extent = layout == Layout::kRows ? rows : cols;
  return (extent + block - 1) / block;
}

ChunkExtent ArraySpec::Extent(uint64_t chunk) const {
  ChunkExtent e;
  if (layout == Layout::kRows) {
    e.row0 = chunk * block;
    e.rows = std::min(block, rows - e.row0);
    e.cols = cols;
  } else {
    e.col0 = chunk * block;
    e.cols = std::min(block, cols - e.col0);
    e.rows = rows;
  }
  return e;
}

Status ArraySpec::Validate() const {
  std::string where = "array \"" + name + "\"";
  if (name.empty()) return InvalidArgument("array with an empty name");
  if (rows == 0 || cols == 0 || rows > kMaxDim || cols > kMaxDim) {
    return InvalidArgument(where + ": shape " + std::to_string(rows) + "x" + std::to_string(cols) + " is outside 1.." +
                           std::to_string(kMaxDim) + " per axis");
  }
  uint64_t extent = layout == Layout::kRows ? rows : cols;
  if (block == 0 || block > extent) {
    return InvalidArgument(where + ": block " + std::to_string(block) + " is outside 1.." + std::to_string(extent));
  }
  uint64_t other = layout == Layout::kRows ? cols : rows;
  uint64_t bytes;
  if (MulOverflows(block, other, &bytes) || MulOverflows(bytes, DTypeSize(dtype), &bytes) || bytes > kMaxChunkBytes) {
    return InvalidArgument(where + ": chunks of " + std::to_string(block) + " " + LayoutName(layout) +
                           " exceed the cap of " + std::to_string(kMaxChunkBytes) + " bytes per chunk");
  }
  return Status::Ok();
}

nlohmann::json ArraySpec::ToJson() const {
  return {{"name", name},
          {"dtype", DTypeName(dtype)},
          {"shape", {rows, cols}},
          {"layout", LayoutName(layout)},
          {"block", block}};
}

int Metadata::FindArray(const std::string& name) const {
  for (size_t i = 0; i < arrays.size(); ++i)
    if (arrays[i].name == name) return static_cast<int>(i);
  return -1;
}

namespace {

Result<uint64_t> GetUnsigned(const nlohmann::json& j, const std::string& where) {
  if (!j.is_number_unsigned()) return InvalidArgument(where + " must be a non-negative integer, got " + JsonText(j));
  return j.get<uint64_t>();
}

Result<ArraySpec> ParseArray(const nlohmann::json& j, size_t index) {
  std::string where = "metadata arrays[" + std::to_string(index) + "]";
  if (!j.is_object()) return InvalidArgument(where + " is not an object");
  for (const char* key : {"name", "dtype", "shape", "layout", "block"}) {
    if (!j.contains(key)) return InvalidArgument(where + " lacks \"" + key + "\"");
  }
  ArraySpec a;
  if (!j["name"].is_string()) return InvalidArgument(where + ".name is not a string");
  a.name = j["name"].get<std::string>();
  if (!j["dtype"].is_string()) return InvalidArgument(where + ".dtype is not a string");
  LTB_ASSIGN_OR_RETURN(a.dtype, ParseDType(j["dtype"].get<std::string>()));
  const auto& shape = j["shape"];
  if (!shape.is_array() || shape.size() != 2) return InvalidArgument(where + ".shape is not [rows, cols]");
  LTB_ASSIGN_OR_RETURN(a.rows, GetUnsigned(shape[0], where + ".shape[0]"));
  LTB_ASSIGN_OR_RETURN(a.cols, GetUnsigned(shape[1], where + ".shape[1]"));
  if (!j["layout"].is_string()) return InvalidArgument(where + ".layout is not a string");
  std::string layout = j["layout"].get<std::string>();
  if (layout == "rows")
    a.layout = Layout::kRows;
  else if (layout == "cols")
    a.layout = Layout::kCols;
  else
    return InvalidArgument(where + ".layout is \"" + layout + "\" (expected \"rows\" or \"cols\")");
  LTB_ASSIGN_OR_RETURN(a.block, GetUnsigned(j["block"], where + ".block"));
  LTB_RETURN_IF_ERROR(a.Validate().WithContext(where));
  return a;
}

}  // namespace

Result<Metadata> MetadataFromJson(nlohmann::json json) {
  if (!json.is_object()) return InvalidArgument("metadata is not a JSON object");
  if (!json.contains("arrays") || !json["arrays"].is_array() || json["arrays"].empty()) {
    return InvalidArgument("metadata lacks a non-empty \"arrays\" list");
  }
  if (json["arrays"].size() > kMaxArrays) {
    return InvalidArgument("metadata lists " + std::to_string(json["arrays"].size()) + " arrays; the cap is " +
                           std::to_string(kMaxArrays));
  }
  Metadata m;
  std::set<std::string> names;
  for (size_t i = 0; i < json["arrays"].size(); ++i) {
    LTB_ASSIGN_OR_RETURN(ArraySpec a, ParseArray(json["arrays"][i], i));
    if (!names.insert(a.name).second) return InvalidArgument("metadata names array \"" + a.name + "\" twice");
    m.arrays.push_back(std::move(a));
  }
  if (json.contains("shard")) {
    const auto& sj = json["shard"];
    const std::string where = "metadata shard";
    if (!sj.is_object() || !sj.contains("index") || !sj.contains("count") || !sj.contains("chunks") ||
        !sj["chunks"].is_array()) {
      return InvalidArgument(where + " is not {\"index\", \"count\", \"chunks\"}");
    }
    ShardInfo info;
    LTB_ASSIGN_OR_RETURN(info.index, GetUnsigned(sj["index"], where + ".index"));
    LTB_ASSIGN_OR_RETURN(info.count, GetUnsigned(sj["count"], where + ".count"));
    if (info.count == 0 || info.count > kMaxShards || info.index >= info.count) {
      return InvalidArgument(where + " is shard " + std::to_string(info.index) + " of " + std::to_string(info.count) +
                             " (expected index < count <= " + std::to_string(kMaxShards) + ")");
    }
    if (sj["chunks"].size() != m.arrays.size()) {
      return InvalidArgument(where + ".chunks lists " + std::to_string(sj["chunks"].size()) + " ranges for " +
                             std::to_string(m.arrays.size()) + " arrays");
    }
    for (size_t i = 0; i < m.arrays.size(); ++i) {
      const auto& r = sj["chunks"][i];
      const std::string rw = where + ".chunks[" + std::to_string(i) + "]";
      if (!r.is_array() || r.size() != 2) return InvalidArgument(rw + " is not [begin, end]");
      LTB_ASSIGN_OR_RETURN(uint64_t b, GetUnsigned(r[0], rw + "[0]"));
      LTB_ASSIGN_OR_RETURN(uint64_t e, GetUnsigned(r[1], rw + "[1]"));
      if (b > e || e > m.arrays[i].ChunkCount()) {
        return InvalidArgument(rw + " is [" + std::to_string(b) + ", " + std::to_string(e) + "), outside the " +
                               std::to_string(m.arrays[i].ChunkCount()) + " chunks of array \"" + m.arrays[i].name +
                               "\"");
      }
      info.chunks.emplace_back(b, e);
    }
    m.shard = std::move(info);
  }
  m.json = std::move(json);
  return m;
}

std::pair<uint64_t, uint64_t> ShardChunkRange(uint64_t chunk_count, uint64_t index, uint64_t count) {
  if (count == 0 || index >= count) return {chunk_count, chunk_count};  // owns nothing (callers check first)
  // 128-bit products: chunk counts and shard counts are capped, but stay exact anyway.
  auto at = [&](uint64_t i) { return static_cast<uint64_t>(static_cast<unsigned __int128>(chunk_count) * i / count); };
  return {at(index), at(index + 1)};
}

bool Metadata::Owns(uint32_t array, uint64_t chunk) const {
  if (!shard) return chunk < arrays.at(array).ChunkCount();
  const auto& [b, e] = shard->chunks.at(array);
  return chunk >= b && chunk < e;
}

uint64_t Metadata::OwnedChunks(uint32_t array) const {
  if (!shard) return arrays.at(array).ChunkCount();
  const auto& [b, e] = shard->chunks.at(array);
  return e - b;
}

Result<nlohmann::json> ShardMetadataJson(const nlohmann::json& whole, uint64_t index, uint64_t count,
                                         const std::vector<uint64_t>* bounds) {
  if (count == 0 || count > kMaxShards || index >= count) {
    return InvalidArgument("shard " + std::to_string(index) + " of " + std::to_string(count) +
                           ": expected 0 <= shard < nshards <= " + std::to_string(kMaxShards));
  }
  if (bounds != nullptr &&
      (bounds->size() != count + 1 || bounds->front() != 0 || !std::is_sorted(bounds->begin(), bounds->end()))) {
    return Internal("shard bounds: " + std::to_string(bounds->size()) + " chunk indices for " + std::to_string(count) +
                    " shards, not 0 and non-decreasing");
  }
  nlohmann::json j = whole;
  j.erase("shard");
  LTB_ASSIGN_OR_RETURN(Metadata m, MetadataFromJson(j));
  nlohmann::json ranges = nlohmann::json::array();
  for (const ArraySpec& a : m.arrays) {
    auto [b, e] = ShardChunkRange(a.ChunkCount(), index, count);
    if (bounds != nullptr && a.ChunkCount() == bounds->back())
      std::tie(b, e) = std::pair((*bounds)[index], (*bounds)[index + 1]);
    ranges.push_back({b, e});
  }
  j["shard"] = {{"index", index}, {"count", count}, {"chunks", ranges}};
  return j;
}

Result<Metadata> ParseMetadata(ByteSpan bytes) {
  const char* begin = reinterpret_cast<const char*>(bytes.data());
  auto j = ParseJson(std::string_view(begin, bytes.size()));
  if (!j.ok()) return DataLoss("metadata is not valid JSON: " + j.status().message());
  return MetadataFromJson(std::move(*j));
}

std::string SerializeMetadata(const nlohmann::json& json) { return JsonText(json); }

uint64_t BlockForTargetBytes(uint64_t rows, uint64_t cols, DType dtype, Layout layout, uint64_t target_bytes) {
  uint64_t extent = layout == Layout::kRows ? rows : cols;
  uint64_t other = layout == Layout::kRows ? cols : rows;
  uint64_t per = std::max<uint64_t>(1, other * DTypeSize(dtype));
  uint64_t block = std::max<uint64_t>(1, target_bytes / per);
  block = std::min(block, extent);
  // Never exceed the per-chunk cap.
  block = std::min(block, std::max<uint64_t>(1, kMaxChunkBytes / per));
  return block;
}

}  // namespace ltb::format
