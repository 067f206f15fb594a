// `ltbake sample SCENE.toml -o raw.ltm`: ray-cast the light transport matrix T of a scene
// with Embree (DESIGN.md "The math in one paragraph"), written as row blocks with per-row
// side tables (mask, position, normal). docs/SAMPLE.md describes the estimator.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "format/io/manifest.h"
#include "format/progress.h"
#include "format/status.h"
#include "stages/wavelet/wavelet.h"

namespace ltb::stages {

// Sparse precomputation (`sample --sparse`, docs/SPARSE.md; Huang & Ramamoorthi 2010):
// about a quarter of the rows are traced densely (adaptively in angle), the rest on a few
// feature texels and reconstructed from their dense neighbours.
struct SparseOptions {
  bool enabled = false;
  // --sparse auto: a pilot measures a full, a dense and a sparse row's cost on this scene and
  // the bake goes sparse only when that is predicted faster by the margin (default 0.8: at
  // least 1.25x); else the full bake. --sparse (force): sparse regardless.
  bool automatic = false;
  std::optional<double> auto_margin;  // --sparse-margin (hidden; tests pin the decision with it)
  double dense_fraction = 0.25;       // --dense-fraction: dense rows / rows that see geometry
  double initial_fraction = 0.05;     // the first, uniformly random dense rows
  std::optional<double> radius;       // --radius (scene units); default 0.04 × the rows' bounding-box diagonal
  std::optional<uint32_t> features;   // --features per sparse row; default max(350 · 6R² / 6144, 4 · neighbours)
  uint32_t neighbours = 16;           // --neighbours: dense rows a sparse row combines, at most
  double lambda = 1e-3;               // --l1-lambda: λ / λ_max of the L1-regularised fit
  double max_residual = 0.15;         // --max-residual: a worse fit traces the row in full instead
};

struct SampleOptions {
  std::string scene;
  std::string output;
  // Override the scene's [sampling] values when set.
  std::optional<uint32_t> cube_res, spp, bounces;
  std::optional<uint64_t> seed;
  uint64_t chunk_rows = 0;  // rows per chunk; 0 picks ~2 MiB chunks
  int jobs = 2;
  bool overwrite = false;
  // Memory budget (--mem-limit) for the chunks waiting to be written; 0: no budget given.
  // The queue between the tracing threads and the writer thread holds at most a quarter of
  // it, capped at kMaxWriteQueueBytes, and at least one chunk.
  uint64_t mem_limit = 0;
  // Write the matrix chunks with O_DIRECT (io::WriterOptions::direct_io), from one writer
  // thread that encodes and writes while the tracing threads keep tracing.
  bool direct_io = true;
  // Fused sample + row-transform (`ltbake run` when the raw matrix is not kept): each row
  // block is wavelet-transformed before it is written, so no raw file exists. The output
  // is the row-transform's output: same content_hash, same basis metadata.
  std::optional<wavelet::Filter> row_filter;
  bool row_zstd = false;  // zstd for the transformed matrix chunks (row-transform --zstd)
  // The visibility field of the triple-product path (docs/TRIPLE.md) instead of T: vertex
  // mode only, no bounces, no fused row-transform; each row is V(x, ω) per texel (the
  // fraction of the texel's solid angle above the horizon and unoccluded), Haar-transformed
  // per face in the layout of stages/wavelet/haar_face.h and stored sparse + zstd.
  bool visibility = false;
  // Write shard `index` of `count` (io::ShardPath(output, ...)) instead of the whole output.
  io::ShardSpec shard;
  SparseOptions sparse;
  // Converged sampling (--tolerance, docs/SAMPLE.md "Converged sampling"): the matrix is
  // sampled to an estimated relative RMS error of `tolerance`, each texel of each row at
  // spp, and where its error needs it again at 2·spp, 4·spp, ... (`max_levels` levels in
  // all: at most spp·2^(max_levels−1); stages/sample/converged.h). Unset: spp everywhere.
  std::optional<double> tolerance;
  uint32_t max_levels = 5;
  // --channel r|g|b (0, 1, 2): bake the scene as that colour channel sees it (every
  // material's channel value, vertex colours multiplying the albedo), one container per
  // channel (docs/COLOUR.md); -1: the monochrome bake.
  int channel = -1;
  // --channels rgb: the three channels' containers (OUT.r.ltm, OUT.g.ltm, OUT.b.ltm) from one
  // pass, each the same file as --channel c bakes (docs/COLOUR.md).
  bool rgb = false;
  // --factor K (vertex mode): bake the BRDF in-out factorisation's K terms, OUT.k0.ltm ..
  // OUT.k{K−1}.ltm, for glossy vertices seen from any view (docs/GLOSSY.md); 0: no.
  uint32_t factor = 0;
  // --factor-term t: only term t of the K, into `output` as given (a recipe's step per term).
  std::optional<uint32_t> factor_term;
  // --factor-grid I,V: the parabolic maps' cells a side for the incident and the view
  // directions (docs/GLOSSY.md); finer for narrow lobes, coarser for speed.
  uint32_t factor_incident_res = 96, factor_view_res = 32;
};

// OUT.ltm -> OUT.k3.ltm: term k of a factored bake.
std::string FactorPath(const std::string& output, uint32_t k);

// What a sparse bake did, per phase (phase 1: the dense rows; phase 2: the sparse rows).
struct SparseStats {
  uint64_t dense_rows = 0, sparse_rows = 0;
  uint64_t fallback_rows = 0;           // sparse rows traced like dense rows: no dense neighbour, or a failed fit
  uint64_t iterations = 0;              // dense-row placement rounds
  uint64_t entries_total = 0;           // rows that see geometry × 6R²
  uint64_t entries_traced[2] = {0, 0};  // the whole bake's
  uint64_t rays[2] = {0, 0};            // traced by this run
  uint64_t total_rays[2] = {0, 0};      // traced for the whole bake (earlier runs included)
  double seconds[2] = {0, 0};           // wall seconds of this run
  double radius = 0;
  uint32_t features = 0;
  double traced_fraction() const {
    return entries_total ? static_cast<double>(entries_traced[0] + entries_traced[1]) / entries_total : 0.0;
  }
};

// What `sample --sparse auto` decided and why (the output's provenance "sparse_auto").
struct SparseAuto {
  bool sparse = false;   // the decision: sparse, or the full bake
  bool resumed = false;  // read from the output an earlier run started, not measured now
  std::string reason;
  uint64_t pilot_rows = 0, pilot_dense_rows = 0;
  double pilot_seconds = 0;                            // wall
  double full_row = 0, dense_row = 0, sparse_row = 0;  // thread CPU seconds per row
  double fallback_fraction = 0;                        // pilot sparse rows traced like dense rows
  double predicted_full = 0, predicted_sparse = 0;     // thread CPU seconds of the whole bake
  double margin = 0.8;
};

struct SampleResult {
  uint64_t rows = 0, valid_rows = 0;  // rows that see geometry (image) or all vertices
  uint32_t cube_res = 0, spp = 0, bounces = 0;
  uint64_t chunks_total = 0, chunks_written = 0, chunks_already_committed = 0;
  uint64_t rays = 0;                   // occlusion + bounce rays traced by this run
  uint64_t texels_below_horizon = 0;   // (row, texel) pairs skipped without tracing
  uint64_t samples_below_horizon = 0;  // samples in partly visible texels that needed no ray
  uint64_t degenerate_triangles = 0;
  uint64_t bytes_direct = 0;       // payload bytes written with O_DIRECT
  std::string direct_fallback;     // why direct writes were off or stopped, if asked for
  uint64_t write_queue_bytes = 0;  // the write queue's bound
  uint64_t write_queue_waits = 0;  // times a tracing thread waited for room in it
  double seconds = 0;
  std::optional<SparseStats> sparse;
  std::optional<SparseAuto> sparse_auto;  // --sparse auto: the decision (the bake is sparse or full by it)
  // A converged bake (--tolerance): rows that see geometry by the highest level a texel of
  // theirs went to (index = level) in this run, and the largest estimated error of a row.
  std::vector<uint64_t> level_histogram;
  double max_rel_error = 0;
  uint64_t pilot_rows = 0;    // rows of the pilot pass (their rays are in `rays`)
  double pilot_rms_norm = 0;  // the RMS row norm N it estimated
  // Whether the pilot predicts the tolerance is reachable within --max-levels, and the
  // least error it predicts the levels can reach.
  bool tolerance_reachable = true;
  double least_error = 0;
  // A factored bake: per glossy material, the relative L2 error of ρ·cos with K = 1..max(K, 8).
  std::vector<std::pair<std::string, std::vector<double>>> factor_errors;
};

// The phase-1 checkpoint of a sparse bake, beside its output (removed once the output is sealed).
std::string SparseCheckpointPath(const std::string& output);

inline constexpr uint64_t kMaxWriteQueueBytes = 64ull << 20;

// XXH3 of the scene file and every mesh file it names: the scene part of sample's key.
Result<std::string> SceneHash(const std::string& scene_path);

Result<SampleResult> RunSample(const SampleOptions& options, const Progress& progress);

// Benchmark baseline: builds the same scene and generates exactly the occlusion rays
// RunSample traces (direct term), in the same batches and the same Embree call
// (rtcOccludedNp, coherent), but only traces them: no transport bookkeeping, no
// output. trace_thread_seconds sums the (wall) time threads spent inside Embree;
// trace_cpu_seconds estimates the CPU time of those calls, robust to the threads being
// preempted by other processes: each work item's thread CPU time times the share of its
// wall time spent inside Embree (a per-call CPU clock costs ~20% of the calls themselves).
struct BareTraceResult {
  uint64_t rays = 0;
  double trace_thread_seconds = 0;
  double trace_cpu_seconds = 0;
  double wall_seconds = 0;
};
Result<BareTraceResult> TraceBare(const SampleOptions& options);

}  // namespace ltb::stages
