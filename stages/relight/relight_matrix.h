// The matrix a relight multiplies, in whichever form its layout calls for: held in memory
// (Relighter, Eq. 8, for final.ltm / cols4d.ltm / cols.ltm), clustered PCA (CpcaRelighter,
// per cluster, for cpca.ltm) or streamed from disk (RelightStreaming, for the row-block
// rows.ltm / raw.ltm). Shared by `relight` (run_relight.cpp), lighting sequences
// (run_sequence.cpp) and `view` (stages/view).
#pragma once

#include <cstdint>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <vector>

#include "format/progress.h"
#include "format/status.h"
#include "stages/common/channels.h"
#include "stages/cpca/cpca_model.h"
#include "stages/relight/relight.h"

namespace ltb::stages {

class RelightMatrix {
 public:
  // Opens and (unless streamed) loads `path`; `report` (may be null) gains the in-memory
  // size: nonzeros / cpca clusters and matrix_bytes_in_memory. `path` may name a colour
  // channel set (stages/common/channels.h): channel c of the image is then channel c of
  // the lighting through the matrix of channel c. A "reflectance" side table (a coloured
  // monochrome bake, docs/COLOUR.md) multiplies each row's RGB.
  static Result<RelightMatrix> Open(const std::string& path, uint64_t mem_limit, int jobs, const Progress& progress,
                                    nlohmann::json* report);

  const std::string& path() const { return path_; }
  uint64_t rows() const { return rows_; }
  uint64_t width() const { return width_; }  // 0 × 0 when the rows are not an image
  uint64_t height() const { return height_; }
  bool streamed() const { return channels_.empty() ? !relighter_ && !cpca_ : channels_[0].streamed(); }
  // 3 for a colour channel set, else 1.
  int channel_count() const { return channels_.empty() ? 1 : static_cast<int>(channels_.size()); }
  const LightingBasis& basis() const { return basis_; }
  // Rows that see no geometry (empty: no such table); FinishRelitImage blackens them.
  const std::vector<uint8_t>& mask() const { return mask_; }
  // ‖T_j‖ per column for the transport weighting (empty unless held in memory by columns).
  const std::vector<double>& column_norms() const;

  // image (rows × 3) = T × the terms' lighting; the weights may be negative.
  Status Relight(const LightTerms& terms, std::vector<float>* image);
  // Relighter::CoefficientBytes for a matrix held as sparse columns (one file, not a
  // channel set, CPCA or streamed); nothing otherwise.
  std::optional<uint64_t> CoefficientBytes(const LightTerms& terms) const {
    if (!channels_.empty() || !relighter_) return std::nullopt;
    return relighter_->CoefficientBytes(terms);
  }
  // image = T × dense lighting (6R² × 3, in basis()).
  Status RelightDense(const std::vector<float>& lighting, std::vector<float>* image);

 private:
  static Result<RelightMatrix> OpenSet(const std::string& path, const std::vector<SetMember>& members,
                                       uint64_t mem_limit, int jobs, const Progress& progress, nlohmann::json* report);
  // The image of each channel's matrix, channel c kept from the c-th; then the reflectance.
  template <typename F>
  Status PerChannel(std::vector<float>* image, F relight_one);
  std::string path_;
  int jobs_ = 1;
  uint64_t rows_ = 0, width_ = 0, height_ = 0;
  LightingBasis basis_;
  std::optional<Relighter> relighter_;
  std::optional<CpcaRelighter> cpca_;
  std::vector<uint8_t> mask_;
  std::vector<float> reflectance_;       // rows × 3, or empty
  std::vector<RelightMatrix> channels_;  // a channel set: one matrix per channel
  Progress progress_;
};

// A --reference against the matrix it judges: the same rows and R, and a channel set
// against a channel set; the error names both files.
Status CheckSameBake(const RelightMatrix& reference, const RelightMatrix& matrix);

}  // namespace ltb::stages
