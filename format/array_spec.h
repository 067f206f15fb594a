// The arrays a container holds (array 0 is the matrix; others are side tables), as
// described by the "arrays" list of the JSON metadata, and their chunk geometry.
#pragma once

#include <cstdint>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "format/bytes.h"
#include "format/status.h"

namespace ltb::format {

enum class DType : uint8_t { kF32, kF64, kU8, kI32, kU32, kU64 };
const char* DTypeName(DType t);
uint64_t DTypeSize(DType t);
Result<DType> ParseDType(const std::string& name);

// kRows: chunk i holds rows [i*block, ...) with all columns, row-major.
// kCols: chunk i holds columns [i*block, ...) with all rows, column-major (each column
//        contiguous, e.g. one W×H image per column).
enum class Layout : uint8_t { kRows, kCols };
const char* LayoutName(Layout l);

// Caps applied to every spec read from a file, before any size is used.
inline constexpr uint64_t kMaxDim = 1ull << 40;
inline constexpr uint64_t kMaxChunkBytes = 16ull << 30;
inline constexpr uint64_t kMaxArrays = 255;
inline constexpr uint64_t kMaxShards = 1u << 16;

struct ChunkExtent {
  uint64_t row0 = 0, rows = 0;  // rows covered
  uint64_t col0 = 0, cols = 0;  // columns covered
  uint64_t Elements() const { return rows * cols; }
};

struct ArraySpec {
  std::string name;
  DType dtype = DType::kF32;
  uint64_t rows = 0;
  uint64_t cols = 0;
  Layout layout = Layout::kRows;
  uint64_t block = 1;  // rows (kRows) or columns (kCols) per chunk

  uint64_t ChunkCount() const;
  ChunkExtent Extent(uint64_t chunk) const;
  uint64_t ChunkBytes(uint64_t chunk) const { return Extent(chunk).Elements() * DTypeSize(dtype); }
  // Checks dimensions against caps and the chunk size against kMaxChunkBytes.
  Status Validate() const;
  nlohmann::json ToJson() const;
};

// A shard file holds a slice of a stage's output: the same arrays (full shapes), but only
// the chunks it owns, chunks [begin, end) of each array (docs/FORMAT.md "Shard files").
// The slices of shards 0..count-1 partition every array; a stage manifest joins them.
struct ShardInfo {
  uint64_t index = 0;
  uint64_t count = 1;
  std::vector<std::pair<uint64_t, uint64_t>> chunks;  // per array: [begin, end)
};

// The chunks of an array of `chunk_count` chunks that shard `index` of `count` owns:
// [floor(index·C/count), floor((index+1)·C/count)). Contiguous and a partition.
std::pair<uint64_t, uint64_t> ShardChunkRange(uint64_t chunk_count, uint64_t index, uint64_t count);

struct Metadata {
  nlohmann::json json;             // the whole metadata object, unknown keys kept
  std::vector<ArraySpec> arrays;   // parsed from json["arrays"]
  std::optional<ShardInfo> shard;  // parsed from json["shard"] when this is a shard file
  const ArraySpec& matrix() const { return arrays.front(); }
  // Index of the array with this name, or -1.
  int FindArray(const std::string& name) const;
  // Whether this file is meant to hold the chunk (always, for a whole file).
  bool Owns(uint32_t array, uint64_t chunk) const;
  // The chunks this file is meant to hold: ChunkCount() for a whole file.
  uint64_t OwnedChunks(uint32_t array) const;
};

// The metadata of shard `index` of `count` of the output whose metadata is `whole`:
// `whole` plus a "shard" key with the chunk ranges of each array: ShardChunkRange's, or with
// `bounds` (count + 1 non-decreasing chunk indices, bounds[0] = 0) [bounds[index],
// bounds[index + 1]) for every array of bounds.back() chunks (a stage that balances its shards
// by their work; the others keep ShardChunkRange's).
Result<nlohmann::json> ShardMetadataJson(const nlohmann::json& whole, uint64_t index, uint64_t count,
                                         const std::vector<uint64_t>* bounds = nullptr);

// Parses and validates metadata bytes. Unknown keys are kept (forward compatibility).
Result<Metadata> ParseMetadata(ByteSpan bytes);
// Validates json and builds Metadata (used by writers before creating a file).
Result<Metadata> MetadataFromJson(nlohmann::json json);
// Serialized form written to the file (compact, sorted keys, deterministic).
std::string SerializeMetadata(const nlohmann::json& json);

// Picks a block size so that chunks hold about target_bytes.
uint64_t BlockForTargetBytes(uint64_t rows, uint64_t cols, DType dtype, Layout layout, uint64_t target_bytes);

}  // namespace ltb::format
