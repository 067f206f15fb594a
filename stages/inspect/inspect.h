// `ltbake inspect FILE --json` as a library call: the JSON object that describes a
// container or a stage manifest (shape, layout, chunks by encoding, bytes on disk,
// content_hash and value statistics, the stage summaries of column-transform, quantize and
// cpca outputs). The CLI (cli/cmd_inspect.cpp) prints it as JSON or text; the Python module
// returns it as a dict. docs/FORMAT.md and DESIGN.md list the keys.
#pragma once

#include <nlohmann/json.hpp>
#include <string>

#include "format/io/container_reader.h"
#include "format/progress.h"
#include "format/status.h"

namespace ltb::stages {

struct InspectOptions {
  // Read every chunk: statistics, content_hash recomputed (a record that differs is a
  // problem), a quantized matrix's nonzeros. Without it (the CLI's default): content_hash
  // only as the writer recorded it, and only the index's byte counts.
  bool content = true;
  bool chunk_list = false;  // "chunk_list": every committed chunk frame
  int jobs = 2;
};

// Fails only when the file cannot be opened (or a chunk cannot be read with `content`);
// damage found while opening is listed under "problems".
Result<nlohmann::json> InspectContainer(const std::string& path, const InspectOptions& options,
                                        const Progress& progress);

// The "sparse" block of a sparse bake (docs/SPARSE.md) or a row-block container derived
// from it, from its side tables; null when the container has none.
Result<nlohmann::json> SummarizeSparse(const io::ContainerReader& reader);

// The "converged" block of a converged bake (sample --tolerance, docs/SAMPLE.md) or a
// row-block container derived from it: total rays, rows by the highest level a texel of
// theirs took, the rows' estimated errors; null when the container has no such side tables.
Result<nlohmann::json> SummarizeConverged(const io::ContainerReader& reader);

}  // namespace ltb::stages
