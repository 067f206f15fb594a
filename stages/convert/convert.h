// `ltbake convert IN OUT`: .npy (2-D float32/float64, C order) to .ltm, and any .ltm
// matrix back to a dense float32 .npy in its logical (rows × columns) order. Outputs of
// column-transform and quantize are decoded (dequantized, inverse column transform) to the
// row-transformed basis they came from; cpca outputs decode to their approximation (mean +
// weighted directions per row) in the row basis of the matrix they were made from.
#pragma once

#include <cstdint>
#include <string>

#include "format/array_spec.h"
#include "format/progress.h"
#include "format/status.h"

namespace ltb::stages {

struct ConvertOptions {
  std::string input;
  std::string output;
  int jobs = 2;
  uint64_t mem_limit = 1ull << 30;    // bytes of buffers across all workers
  uint64_t chunk_bytes = 8ull << 20;  // target size of one chunk (npy -> ltm)
  format::Layout layout = format::Layout::kRows;
  bool zstd = false;       // try zstd per chunk, keep it where it saves >= 10%
  bool overwrite = false;  // replace an existing output written with other parameters
  // Declares the columns a pixel-basis cubemap with faces of R×R texels (0: generic).
  uint64_t cube_res = 0;
  // Declares the rows the pixels of a W×H image, y·W + x (0: generic).
  uint64_t image_width = 0, image_height = 0;
  // .ltm -> .npy of a row-transformed matrix: also invert the row transform, so the .npy
  // is in the pixel basis of the cubemap (column-transformed inputs are always decoded
  // to the row-transformed basis first).
  bool pixel_basis = false;
};

struct ConvertResult {
  uint64_t channels = 0;  // a colour channel set's .npy: its leading axis (docs/COLOUR.md); else 0
  uint64_t rows = 0, cols = 0;
  uint64_t chunks_total = 0;
  uint64_t chunks_written = 0;
  uint64_t chunks_already_committed = 0;  // resumed
  uint64_t discarded_tail_bytes = 0;
  uint64_t zero_chunks = 0;
  uint64_t zstd_chunks = 0;
  uint64_t bytes_out = 0;
  // Set when --overwrite restarted an output whose committed chunks no longer match the
  // input: the check's message (which chunk, which values).
  std::string restarted_because;
};

Result<ConvertResult> RunConvert(const ConvertOptions& options, const Progress& progress);

}  // namespace ltb::stages
