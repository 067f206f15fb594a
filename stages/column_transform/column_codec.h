// Reading column-transformed matrices (cols4d.ltm from `column-transform`, final.ltm from
// `quantize`): what their metadata says, the level of every coefficient, dequantization
// and the inverse column transform back to the image (the row-transformed basis).
//
// Levels (for quantize's scaling, §4.3 of Cheslack-Postava et al.): in a column at depth d,
// the low band and the detail bands of the coarsest step d are level 0; the detail bands
// of analysis step s are level d − s (step 1, the finest, is level d − 1).
//
// Quantization factor of a coefficient (`--scaling level`): ‖ψ̃‖ · 2^level, where ‖ψ̃‖ is the
// synthesis norm of its band (1 for the orthonormal filters and at depth 0). The first
// factor expresses the coefficient in the L2-normalised basis — the paper's 2^−l decay
// holds there; the biorthogonal lifting filters keep DC gain 1 instead, so their coarse
// coefficients are smaller by up to 2^d and their quantization error is amplified by ‖ψ̃‖
// in the image. `--scaling none`: factor 1.
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "format/array_spec.h"
#include "format/io/container_reader.h"
#include "format/status.h"
#include "stages/wavelet/wavelet.h"

namespace ltb::stages {

// Metadata "quantization.scaling": "norm-level" (‖ψ̃‖ · 2^level, what `--scaling level`
// writes), "none" (1), "level" (2^level alone: files from the first quantize build,
// 2026-11-22, still decode) and "norm" (‖ψ̃‖ alone: one quantization step in these units
// is the same image-domain error at every position, what `quantize --error-ratio` writes).
enum class Scaling { kNone, kLevel, kNormLevel, kNorm };
Result<Scaling> ParseScaling(const std::string& name);
const char* ScalingName(Scaling s);

struct Quantization {
  int bits = 0;  // 0: not quantized (column-transform output)
  Scaling scaling = Scaling::kNormLevel;
  bool dither = true;
  uint64_t seed = 0;
  double Levels() const { return static_cast<double>((int64_t{1} << (bits - 1)) - 1); }  // Q = 2^(bits−1) − 1
};

class ColumnCodec {
 public:
  // From the metadata of a column-transform or quantize output; fails for other files.
  static Result<ColumnCodec> FromMetadata(const format::Metadata& meta, const std::string& path);
  static bool IsColumnTransformed(const format::Metadata& meta);

  wavelet::Filter filter() const { return filter_; }
  uint64_t width() const { return width_; }
  uint64_t height() const { return height_; }
  int max_depth() const { return max_depth_; }
  const Quantization& quantization() const { return quant_; }
  int depth_array() const { return depth_array_; }
  int scale_array() const { return scale_array_; }  // −1 when not quantized or one step for the matrix
  // One step for the matrix (`quantize --error-ratio`, written since 2026-12-02 without a
  // "scale" table): M = Δ · Q for every column; 0 when the scales are per column.
  double uniform_scale() const { return uniform_scale_; }

  static std::vector<uint8_t> ComputeLevels(uint64_t width, uint64_t height, int depth);
  // The quantization factor of every position at depth d (see above).
  const std::vector<double>& Factors(int depth) const { return tables_->factors.at(depth); }

  // Coefficients of one column (dense W·H, Mallat layout at `depth`) from its stored
  // sparse values: f32 as is, or quantized integers q → q / Q · scale / factor.
  void DenseCoefficients(int depth, double scale, const uint32_t* index, const void* values, size_t n,
                         float* out) const;
  // Inverse column transform of one dense column in place: coefficients → image.
  void ToImage(int depth, float* column, std::vector<float>* scratch) const;

  // Decodes column chunk `chunk` of an open reader into dense image columns
  // (column-major: e.cols × W·H floats). Thread-safe.
  Status DecodeChunk(const io::ContainerReader& reader, uint64_t chunk, std::vector<float>* out,
                     const io::ReadOptions& options = {}) const;

 private:
  struct Tables {
    std::vector<std::vector<double>> factors;  // per depth, per position
  };
  wavelet::Filter filter_ = wavelet::Filter::kLeGall53;
  uint64_t width_ = 0, height_ = 0;
  int max_depth_ = 0;
  Quantization quant_;
  int depth_array_ = -1, scale_array_ = -1;
  double uniform_scale_ = 0;
  std::shared_ptr<const Tables> tables_;
};

// ‖ψ̃‖² of every coefficient position of a width × height column at depths 0..max_depth:
// a unit coefficient at the centre of each band synthesized back to pixels (in double).
// All 1 for the orthonormal filters and at depth 0.
std::vector<std::vector<double>> SynthesisEnergies(wavelet::Filter filter, uint64_t width, uint64_t height,
                                                   int max_depth);
// Factors for quantization (see above) per position and depth.
std::vector<std::vector<double>> QuantizationFactors(wavelet::Filter filter, uint64_t width, uint64_t height,
                                                     int max_depth, Scaling scaling);

}  // namespace ltb::stages
