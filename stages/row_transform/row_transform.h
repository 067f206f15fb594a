// `ltbake row-transform IN -o OUT --filter F`: per matrix row and per cube face, the 2D
// wavelet transform of the R×R face to full depth (log2 R steps), in the Mallat layout
// of pywt.coeffs_to_array. Input: row blocks whose columns are a pixel-basis cubemap.
#pragma once

#include <cstdint>
#include <string>

#include "format/io/manifest.h"
#include "format/progress.h"
#include "format/status.h"
#include "stages/wavelet/wavelet.h"

namespace ltb::stages {

struct RowTransformOptions {
  std::string input;
  std::string output;
  wavelet::Filter filter = wavelet::Filter::kHaar;
  int jobs = 2;
  bool zstd = false;
  bool overwrite = false;
  // Write the output's row blocks with O_DIRECT (io::WriterOptions::direct_io).
  bool direct_io = true;
  // Write shard `index` of `count` (io::ShardPath(output, ...)) instead of the whole output.
  io::ShardSpec shard;
};

struct RowTransformResult {
  uint64_t rows = 0, cube_res = 0;
  uint64_t chunks_total = 0, chunks_written = 0, chunks_already_committed = 0;
  uint64_t zero_chunks = 0;     // all-zero input chunks, passed through without work
  uint64_t zero_rows = 0;       // all-zero rows inside other chunks, skipped
  uint64_t bytes_direct = 0;    // output payload bytes written with O_DIRECT
  std::string direct_fallback;  // why direct writes were off or stopped, if asked for
};

Result<RowTransformResult> RunRowTransform(const RowTransformOptions& options, const Progress& progress);

// The transform of one row block: `rows` rows of 6·R² values (row-major), from src to
// dst (TransformRows; src == dst allowed, no other overlap) or in place
// (TransformRowBlock). All-zero rows are counted in *zero_rows and written as zeros. A
// row's result depends only on its own values, the filter and R (not on the other rows of
// the block). Exposed for benchmarks and tests. Scratch: see RowBlockScratchSize.
size_t RowBlockScratchSize(uint64_t cube_res);
void TransformRows(wavelet::Filter filter, uint64_t cube_res, const float* src, float* dst, uint64_t rows,
                   float* scratch, uint64_t* zero_rows);
void TransformRowBlock(wavelet::Filter filter, uint64_t cube_res, float* rows_data, uint64_t rows, float* scratch,
                       uint64_t* zero_rows);

}  // namespace ltb::stages
