// Relighting: B = T L for a new environment, from a compressed or uncompressed transport
// matrix (DESIGN.md "The math in one paragraph"; docs/RELIGHT.md).
//
// Lighting approximation (Ng et al. 2003, §4): the cubemap radiance is transformed per face
// in the rows' wavelet filter (the basis T's rows are in), and only the N largest terms
// are kept, ranked by magnitude × the support area of their basis function (`area`),
// × the norm of T's matching column (`transport`), or by magnitude alone (`none`).
//
// Relighting from a column-transformed matrix (final.ltm, cols4d.ltm) evaluates Eq. 8 of
// Cheslack-Postava et al. 2007: the chosen lights are grouped by their column's depth,
// each group is sparse-accumulated into an image buffer at that depth's Mallat layout,
// and one single-step inverse column transform runs per level from the deepest down. It is
// exact: the same as inverse-transforming every column first.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "format/array_spec.h"
#include "format/chunk_codec.h"
#include "format/progress.h"
#include "format/status.h"
#include "stages/wavelet/wavelet.h"

namespace ltb::io {
class ContainerReader;
}  // namespace ltb::io

namespace ltb::stages {

class ColumnCodec;  // stages/column_transform/column_codec.h

enum class Weighting { kArea, kTransport, kNone };
Result<Weighting> ParseWeighting(const std::string& name);
const char* WeightingName(Weighting w);  // the --weighting spelling

// The kept lighting terms: column index (in the matrix's column basis) and RGB weight.
struct LightTerms {
  std::vector<uint32_t> column;
  std::vector<float> rgb;  // 3 per term
};

// The column basis of a matrix (pixel or per-face wavelet cubemap) and what the
// lighting approximation needs to know about it.
class LightingBasis {
 public:
  static Result<LightingBasis> FromMetadata(const format::Metadata& meta, const std::string& path);
  uint64_t cube_res() const { return cube_res_; }
  bool wavelet() const { return wavelet_; }
  wavelet::Filter filter() const { return filter_; }
  // Cubemap radiance (6R² × 3, texel-major) into this basis, and back, in place.
  void ToBasis(float* cubemap) const;
  void ToPixels(float* cubemap) const;
  // The N-term approximation of lighting already in this basis. `column_norms` (‖T_j‖)
  // is needed for Weighting::kTransport only.
  Status SelectTerms(const float* lighting, uint64_t terms, Weighting weighting,
                     const std::vector<double>& column_norms, LightTerms* out) const;

 private:
  uint64_t cube_res_ = 0;
  bool wavelet_ = false;
  wavelet::Filter filter_ = wavelet::Filter::kHaar;
  std::vector<float> area_;  // support area (texels) of each column's basis function
};

// A column-transformed (or plain column-block) matrix held in memory, sparse, for frames.
class Relighter {
 public:
  // final.ltm / cols4d.ltm (any depth mode), or an uncompressed column-block container
  // (cols.ltm: every column at depth 0). Needs cubemap columns (basis.cols).
  // Fails (naming the sizes) when the sparse matrix would take more than `mem_limit` bytes.
  // Decodes `jobs` chunks at a time in parallel; the result does not depend on `jobs`.
  static Result<Relighter> Load(const std::string& path, uint64_t mem_limit, const Progress& progress, int jobs = 1);

  uint64_t rows() const { return rows_; }
  const LightingBasis& basis() const { return basis_; }
  uint64_t image_width() const { return width_; }  // the column image (rows × 1 when not an image)
  uint64_t image_height() const { return height_; }
  uint64_t nonzeros() const { return values_.size(); }
  uint64_t bytes() const { return values_.size() * 8 + col_ptr_.size() * 8; }
  const std::vector<double>& column_norms() const { return column_norm_; }

  // B (rows × 3, row order) for the given terms.
  void Relight(const LightTerms& terms, float* out_rgb);
  // Bytes of the kept coefficients Relight(terms) reads: 8 per nonzero of the terms'
  // columns (a 4-byte position and a 4-byte value).
  uint64_t CoefficientBytes(const LightTerms& terms) const;

 private:
  // One chunk of the matrix as read, with its columns' side tables.
  struct LoadedChunk {
    format::SparseChunk sc;
    std::vector<uint8_t> depths;
    std::vector<double> scales, energy;  // energy < 0: not recorded
  };
  // Appends a chunk's columns (dequantized) to the in-memory matrix.
  Status AppendChunk(const std::string& path, const ColumnCodec* codec, uint64_t mem_limit, const LoadedChunk& d);
  // ‖ψ̃‖² of every position per depth, when a column's norm is estimated from its coefficients
  // (no recorded energy and a biorthogonal column filter); empty otherwise.
  std::vector<std::vector<double>> synthesis_energy_;

  uint64_t rows_ = 0, cols_ = 0;
  uint64_t width_ = 0, height_ = 0;
  LightingBasis basis_;
  wavelet::Filter col_filter_ = wavelet::Filter::kLeGall53;
  int max_depth_ = 0;
  std::vector<wavelet::BandSize> bands_;
  std::vector<uint8_t> depth_;
  std::vector<uint64_t> col_ptr_;  // cols + 1
  std::vector<uint32_t> pos_;
  std::vector<float> values_;
  std::vector<double> column_norm_;  // ‖T_j‖ (image domain), for the transport weighting
  std::vector<float> scratch_;
  std::vector<std::vector<uint32_t>> by_depth_;
};

// B = T L streamed from a row- or column-block container with dense lighting (6R² × 3 in
// the container's column basis), in double: the exact relighting used as the reference.
Result<std::vector<float>> RelightStreaming(const std::string& path, const float* lighting, int jobs,
                                            const Progress& progress);

// Error metrics of an RGB image (rows × 3) against a reference.
struct ImageErrors {
  double rel_l2 = 0;   // ‖B − R‖ / ‖R‖
  double rel_h1 = -1;  // ‖∇(B − R)‖ / ‖∇R‖ (gradient part of the H1 norm; −1 without an image)
  double psnr = 0;     // 20 log10(max R / RMSE)
};
ImageErrors CompareImages(const float* image, const float* reference, uint64_t rows, uint64_t width, uint64_t height);

// The matrix's "mask" side table (a u8 per row, 0: the pixel sees no geometry), read whole;
// empty when the container has none (a converted .npy matrix, cpca.ltm). The file, the
// table and the chunk are named on errors.
Result<std::vector<uint8_t>> ReadRowMask(const io::ContainerReader& in);

// The matrix's "reflectance" side table (rows × 3 f32: a coloured monochrome bake's per-row
// tint × vertex colour, docs/COLOUR.md), read whole; empty when the container has none.
// `rows`: the matrix's rows (a cpca.ltm's are not its first array's).
Result<std::vector<float>> ReadRowReflectance(const io::ContainerReader& in, uint64_t rows);
// image (rows × 3) *= reflectance per row and channel; nothing when reflectance is empty.
void ApplyReflectance(const std::vector<float>& reflectance, std::vector<float>* image);

// What relight does to every image it outputs (docs/RELIGHT.md "Output"): a row whose mask
// is 0 is black — the uncompressed transport there is exactly 0, and what a compressed
// matrix holds there is ringing of its column transform — and, unless keep_negative,
// negative radiance (the same ringing, or an approximated lighting's negative lobes) is
// clamped to 0. `mask` is empty or one entry per row.
struct OutputFixes {
  uint64_t masked_rows = 0;     // rows set to 0 by the mask (whatever they held)
  uint64_t clamped_values = 0;  // negative values set to 0
};
OutputFixes FinishRelitImage(const std::vector<uint8_t>& mask, bool keep_negative, std::vector<float>* image);

// Relighting holds the lighting's wavelet coefficients (up to R × a texel) and the sums of
// Eq. 8 in float32: a map near float32's largest value (3.4e38) would overflow them. The
// power of two k ≥ 0 to relight a cubemap at (× 2^-k, exact) so that its largest value is at
// most 2^64; the image is scaled back by 2^k after (and checked: CheckRelitImageFinite).
int LightingExponent(const std::vector<float>& cubemap);
// The same for lighting whose values are at most `peak` (a source map's largest value bounds
// every texel of every rotation of it): one exponent for a whole sequence or view.
int LightingExponent(float peak);
// v · 2^k for every value (exact unless it leaves float32's range).
void ScaleByPowerOfTwo(std::vector<float>* values, int k);

}  // namespace ltb::stages
