// Reading a `cpca` output (cpca.ltm, docs/CPCA.md): the cluster means and principal
// directions, and per row a cluster id and S weights. Used by convert (decode), relight
// and inspect.
//
// Arrays: 0 "cluster_vectors" (K·(S+1) × D f32, row k·(S+1) the mean of cluster k, rows
// k·(S+1)+1+i its direction i), "cluster_id" (N × 1 u32) and, for S > 0, "weights"
// (N × S f32); cluster_id and weights share one row block, so their chunk c covers the
// same rows. Metadata "cpca" holds K, S, N, D and the error; "basis" describes the decoded
// N × D matrix (rows: the input's rows, cols: the input's column basis).
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "format/array_spec.h"
#include "format/io/container_reader.h"
#include "format/status.h"

namespace ltb::stages {

inline constexpr const char* kCpcaVectorsArray = "cluster_vectors";
inline constexpr const char* kCpcaIdArray = "cluster_id";
inline constexpr const char* kCpcaWeightsArray = "weights";

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
