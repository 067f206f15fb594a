// Internal to the sample stage (stages/sample/sample.h is its public header): what the full
// bake (sample.cpp) and the sparse bake (sparse.cpp, docs/SPARSE.md) share — the prepared
// scene, the row blocking and the output's metadata.
#pragma once

#include <cstdint>
#include <memory>
#include <nlohmann/json.hpp>

#include "format/array_spec.h"
#include "format/io/container_writer.h"
#include "format/progress.h"
#include "format/status.h"
#include "stages/sample/sample.h"
#include "stages/sample/sampler.h"
#include "stages/sample/scene.h"
#include "stages/sample/scene_geometry.h"

namespace ltb::stages::sample_internal {

// The parsed scene, its Embree geometry and the effective sampling parameters.
struct Prepared {
  sample::SceneDesc scene;
  sample::Geometry geo;
  uint32_t r = 0, spp = 0, bounces = 0;
  uint64_t seed = 0, rows = 0;
  // A monochrome bake of a scene with colour: T is baked with each material's scalar albedo
  // and ks, and the "reflectance" side table holds each row's tint × vertex colour
  // (docs/COLOUR.md).
  bool reflectance = false;
  // A factored bake in colour (`--channels rgb --factor K`, or one channel of one with
  // --channel): every channel's terms from one set of rays on the original scene.
  bool rgb_factor = false;
};

Result<std::unique_ptr<Prepared>> Prepare(const SampleOptions& o, const Progress& progress);

// An array in row blocks of `block` rows (the matrix and every side table).
format::ArraySpec RowArray(const char* name, format::DType t, uint64_t rows, uint64_t cols, uint64_t block);

// Rows per chunk: --chunk-rows, else about 2 MiB of matrix per block.
uint64_t BlockRows(const SampleOptions& o, uint64_t rows, uint64_t cols);

// The output's metadata: the four arrays (matrix, mask, position, normal) in row blocks,
// the row and column bases, and the provenance with the effective sampling parameters.
nlohmann::json SampleMetadata(const SampleOptions& o, const Prepared& p, uint64_t block);

// With p.reflectance, appends the "reflectance" side table (rows × 3 f32, row blocks) to
// the metadata's arrays (after every other array: the sparse bake's come first).
void AddReflectance(const Prepared& p, uint64_t block, nlohmann::json* meta);
// Writes the reflectance table's missing chunks: per row, its material's tint times its
// vertex colour, or with `lobe` (terms 1..K−1 of a factored bake) its lobe's colour ks_rgb
// over its largest channel (0 for a row that sees no geometry).
Status WriteReflectance(const Prepared& p, const sample::Sampler& sampler, uint64_t block, io::ContainerWriter& out,
                        bool lobe, const Progress& progress);

// `sample --sparse` (sparse.cpp): the whole stage once the scene is prepared. With --sparse
// auto the pilot decides first (sparse_auto.cpp); when it picks the full bake, returns no
// result and *full holds the decision, for the caller's full bake to record.
Result<std::optional<SampleResult>> RunSparseSample(const SampleOptions& o, const Prepared& p, const Progress& progress,
                                                    SparseAuto* full);

}  // namespace ltb::stages::sample_internal
