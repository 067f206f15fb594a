// What the rows and columns of a matrix are, as recorded in container metadata under
// "basis" (docs/METADATA.md), and the provenance block every stage writes.
#pragma once

#include <cstdint>
#include <cstring>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <vector>

#include "format/array_spec.h"
#include "format/bits.h"
#include "format/io/container_reader.h"
#include "format/io/container_writer.h"
#include "format/status.h"

namespace ltb::stages {

// {"kind": "cubemap", "cube_res": R, "basis": "pixel"} or, after row-transform,
// {"kind": "cubemap", "cube_res": R, "basis": "wavelet", "filter": F, "depth": log2 R}.
nlohmann::json PixelCubemapCols(uint64_t cube_res);
nlohmann::json WaveletCubemapCols(uint64_t cube_res, const std::string& filter);
// {"kind": "image", "width": W, "height": H}; {"kind": "generic"}.
nlohmann::json ImageRows(uint64_t width, uint64_t height);
nlohmann::json GenericAxis();

struct CubemapCols {
  uint64_t cube_res = 0;
  std::string basis;   // "pixel" or "wavelet"
  std::string filter;  // for "wavelet"
};
// The cubemap description of the columns, or nullopt when the columns are not a cubemap.
// Fails when the description is malformed or disagrees with the matrix width.
Result<std::optional<CubemapCols>> ReadCubemapCols(const format::Metadata& meta);

struct ImageSize {
  uint64_t width = 0, height = 0;
};
// The image the rows are the pixels of, when they are.
std::optional<ImageSize> ReadImageRows(const format::Metadata& meta);

// A stage's input: its matrix must be f32 and every chunk of every array committed.
Status RequireCompleteF32Matrix(const io::ContainerReader& in);
// Refuses a cpca.ltm (cluster means, bases and weights are not a transport matrix).
Status RefuseCpcaOutput(const io::ContainerReader& in, const std::string& stage);

// Side tables a stage passes through: a rows-layout side table in as few chunks as fit
// kSideTableChunkBytes (each chunk costs ~170 bytes of frame and index), others as they are.
inline constexpr uint64_t kSideTableChunkBytes = 16ull << 20;
format::ArraySpec PassThroughSpec(const format::ArraySpec& in);
// Copies array `arr` of `in` into array `dst` of `out` (by default the same index), whose
// spec may have another block than the input's (same layout, shape and dtype); skips
// chunks `out` already has; zstd where it saves.
Status CopyArray(const io::ContainerReader& in, uint32_t arr, io::ContainerWriter& out, uint64_t* chunks_written);
Status CopyArray(const io::ContainerReader& in, uint32_t arr, io::ContainerWriter& out, uint32_t dst,
                 uint64_t* chunks_written);

// Lines [l0, l1) of array `arr` (rows of a rows-layout array, columns of a cols-layout
// one), whatever its block: a per-column table read for a matrix chunk's columns whether
// the table is chunked like the matrix (column-transform) or in one chunk (quantize).
Result<std::vector<std::byte>> ReadLines(const io::ContainerReader& in, uint32_t arr, uint64_t l0, uint64_t l1,
                                         const io::ReadOptions& options = {});
template <class T>
Result<std::vector<T>> ReadLinesAs(const io::ContainerReader& in, uint32_t arr, uint64_t l0, uint64_t l1,
                                   const io::ReadOptions& options = {}) {
  LTB_ASSIGN_OR_RETURN(std::vector<std::byte> b, ReadLines(in, arr, l0, l1, options));
  std::vector<T> v(b.size() / sizeof(T));
  if (!v.empty()) std::memcpy(v.data(), b.data(), v.size() * sizeof(T));
  return v;
}

// The row side tables the outputs of column-transform and quantize keep: what relighting
// reads ("mask", the pixels a surface covers; "reflectance", a colour bake's per-row
// albedo). Per-row geometry ("position", "normal") and the sampling diagnostics
// ("sparse_*", "sample_*") stay in the outputs of sample, row-transform and transpose,
// where sparse reconstruction, CPCA and `inspect` read them (docs/COLUMN-TRANSFORM.md).
bool KeptByCompressedOutputs(const std::string& name);

// {"tool", "stage", "parameters", "inputs": [{"file", "fingerprint"}]}
nlohmann::json Provenance(const std::string& stage, const nlohmann::json& parameters,
                          const std::vector<const io::ContainerReader*>& inputs);
// Identifies a sealed container's stored content (metadata + every chunk's checksum and
// encoding) without reading payloads: equal fingerprints mean equal stored bytes.
std::string Fingerprint(const io::ContainerReader& reader);

}  // namespace ltb::stages
