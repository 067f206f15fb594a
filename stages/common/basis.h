// What the rows and columns of a matrix are, as recorded in container metadata under
// "basis" (docs/METADATA.md), and the provenance block every stage writes.
#pragma once

#include <cstdint>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>

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
// Copies array `arr` of `in` into `out`, whose spec for it may have another block than the
// input's (same layout, shape and dtype); skips chunks `out` already has; zstd where it saves.
Status CopyArray(const io::ContainerReader& in, uint32_t arr, io::ContainerWriter& out, uint64_t* chunks_written);

// {"tool", "stage", "parameters", "inputs": [{"file", "fingerprint"}]}
nlohmann::json Provenance(const std::string& stage, const nlohmann::json& parameters,
                          const std::vector<const io::ContainerReader*>& inputs);
// Identifies a sealed container's stored content (metadata + every chunk's checksum and
// encoding) without reading payloads: equal fingerprints mean equal stored bytes.
std::string Fingerprint(const io::ContainerReader& reader);

}  // namespace ltb::stages
