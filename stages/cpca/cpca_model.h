// A `cpca` output (cpca.ltm, docs/CPCA.md): the cluster means and principal directions,
// and per row a cluster id and S weights. Reading it is used by convert (decode), relight
// and inspect; writing it by `ltbake cpca` (stages/cpca/cpca.h), with the layout below.
//
// Arrays: 0 "cluster_vectors" (K·(S+1) × D f32, row k·(S+1) the mean of cluster k, rows
// k·(S+1)+1+i its direction i), "cluster_id" (N × 1 u32) and, for S > 0, "weights"
// (N × S f32); cluster_id and weights share one row block, so their chunk c covers the
// same rows. Metadata "cpca" holds K, S, N, D and the error; "basis" describes the decoded
// N × D matrix (rows: the input's rows, cols: the input's column basis).
#pragma once

#include <cstdint>
#include <functional>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <vector>

#include "format/array_spec.h"
#include "format/io/container_reader.h"
#include "format/io/container_writer.h"
#include "format/status.h"

namespace ltb::stages {

inline constexpr const char* kCpcaVectorsArray = "cluster_vectors";
inline constexpr const char* kCpcaIdArray = "cluster_id";
inline constexpr const char* kCpcaWeightsArray = "weights";

// The arrays of a cpca output for K clusters of S directions over N rows of D dimensions,
// as `ltbake cpca` writes them and CpcaModel::Load checks them: the vectors in row blocks
// of about 4 MiB; ids and weights sharing a row block of about 4 MiB of weights, a
// multiple of row_align rows (the encoder's unit).
struct CpcaLayout {
  uint64_t k = 0, s = 0, n = 0, d = 0;
  format::ArraySpec vectors, ids, weights;  // weights are stored only when S > 0
  static CpcaLayout For(uint64_t k, uint64_t s, uint64_t n, uint64_t d, uint64_t row_align);
};

// What the "cpca" metadata block records about the fit besides the layout.
struct CpcaFitInfo {
  uint64_t iterations = 0;
  std::vector<uint64_t> growth_levels;
  uint64_t seed = 0;
  double squared_error = 0, squared_norm = 0;  // of the stored approximation, Σ ‖x‖²
  uint64_t empty_clusters = 0;
  // Dense-first fits (recorded as "dense_first" in the block; absent otherwise): the rows
  // the growth levels ran on, their passes, and the passes on all rows after them.
  bool dense_first = false;
  uint64_t dense_rows = 0, dense_passes = 0, final_passes = 0;
};

// An output's metadata: the arrays, the input's basis, the "cpca" block and provenance.
nlohmann::json CpcaOutputMetadata(const CpcaLayout& layout, const CpcaFitInfo& fit, const nlohmann::json& basis,
                                  const nlohmann::json& provenance);

// Writes the missing chunks of cluster_vectors: vector(c, i, out) fills the D values of
// cluster c's mean (i = 0) or of its direction i − 1. Returns the chunks written.
Result<uint64_t> WriteCpcaVectors(io::ContainerWriter& out, const CpcaLayout& layout,
                                  const std::function<void(uint64_t c, uint64_t i, float* out)>& vector);

// Fills the ids (rows) and weights (rows × S) of rows [row0, row0 + rows).
using CpcaRowEncoder = std::function<Status(uint64_t row0, uint64_t rows, uint32_t* ids, float* weights)>;
// Writes the missing chunks of cluster_id and weights, `jobs` chunks at a time; a row
// chunk missing from either array is encoded once, for both. done(rows) follows each
// chunk's writes. Returns the chunks written.
Result<uint64_t> WriteCpcaRows(io::ContainerWriter& out, const CpcaLayout& layout, int jobs,
                               const CpcaRowEncoder& encode, const std::function<void(uint64_t rows)>& done);

class CpcaModel {
 public:
  // True when the metadata is a cpca output's (has the "cpca" key).
  static bool IsCpca(const format::Metadata& meta);
  // Checks the arrays against the "cpca" block and loads the means and directions
  // (K·(S+1)·D floats; refused, naming the sizes, above mem_limit).
  static Result<CpcaModel> Load(const io::ContainerReader& in, uint64_t mem_limit);

  uint64_t clusters() const { return k_; }
  uint64_t basis() const { return s_; }
  uint64_t dims() const { return d_; }
  uint64_t rows() const { return n_; }
  double relative_rms_error() const { return error_; }
  // Chunks of the per-row arrays (cluster_id and weights share them).
  uint64_t row_chunks() const { return row_spec_.ChunkCount(); }
  format::ChunkExtent row_extent(uint64_t chunk) const { return row_spec_.Extent(chunk); }
  // The mean (i = 0) or direction i − 1 of cluster k: D floats.
  const float* vector(uint64_t k, uint64_t i) const { return vectors_.data() + (k * (s_ + 1) + i) * d_; }

  // The approximation of the rows of one row chunk (extent rows × D, row-major), each
  // value computed in double and rounded once. Checks every cluster id (kDataLoss naming
  // file, row and value when one is ≥ K).
  Status DecodeChunk(const io::ContainerReader& in, uint64_t chunk, std::vector<float>* out) const;
  // Cluster ids and weights of one row chunk (weights: rows × S; empty when S = 0),
  // ids checked as in DecodeChunk.
  Status ReadRows(const io::ContainerReader& in, uint64_t chunk, std::vector<uint32_t>* ids,
                  std::vector<float>* weights) const;
  // The image the rows are the pixels of (from basis.rows), when they are.
  std::optional<std::pair<uint64_t, uint64_t>> image() const { return image_; }

 private:
  std::string path_;
  uint64_t k_ = 0, s_ = 0, d_ = 0, n_ = 0;
  double error_ = 0;
  int id_array_ = -1, weight_array_ = -1;
  format::ArraySpec row_spec_;
  std::vector<float> vectors_;
  std::optional<std::pair<uint64_t, uint64_t>> image_;
};

// B = T L from a cpca model held in memory: per cluster the lighting is projected on the
// mean and the directions (K·(S+1) dot products of length D), then per row the S weights
// blend the cluster's projections. `lighting` is dense, 6R² × 3, in the matrix's column
// basis.
class CpcaRelighter {
 public:
  // Loads model, ids and weights; fails, naming the sizes, above mem_limit bytes.
  static Result<CpcaRelighter> Load(const std::string& path, uint64_t mem_limit);
  uint64_t rows() const { return model_.rows(); }
  const CpcaModel& model() const { return model_; }
  uint64_t bytes() const {
    return ids_.size() * 4 + weights_.size() * 4 + model_.clusters() * (model_.basis() + 1) * model_.dims() * 4;
  }
  // out: rows × 3.
  void Relight(const float* lighting, float* out_rgb) const;
  // The same from a sparse set of lighting terms (columns and RGB weights).
  void RelightTerms(const std::vector<uint32_t>& columns, const std::vector<float>& rgb, float* out_rgb) const;

 private:
  void Blend(const std::vector<double>& projections, float* out_rgb) const;
  CpcaModel model_;
  std::vector<uint32_t> ids_;
  std::vector<float> weights_;
};

}  // namespace ltb::stages
