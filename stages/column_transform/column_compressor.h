// The per-column core of `column-transform` (Cheslack-Postava et al. 2007, §4.2): each
// column of the transposed matrix is a W×H image; it is transformed step by step, and at
// every depth in the allowed range the error of its best N-term approximation is measured
// in the image domain. The column keeps the depth with the least error (on a tie of two
// exact approximations, the one with fewer nonzeros, then the shallower one).
//
// Selection ranks coefficients by their contribution to the image-domain error,
// c² · ‖ψ̃‖², where ψ̃ is the synthesis function of the coefficient's band: 1 for the
// orthonormal filters (Parseval), the numerically measured band norm for the biorthogonal
// ones (whose bands do not preserve energy). Errors are exact: for orthonormal filters the
// energy of the dropped coefficients, for biorthogonal ones the energy of the
// reconstructed dropped part. Energies and errors are accumulated in double.
//
// No full sort: the N-th largest is found by selection (linear time), and every extra
// depth is one more analysis step on the low band. For `terms` selections the kept set of
// a depth is a cut (a key threshold and a count of ties); the error is measured in one
// pass over the eight lanes together, and the kept list is built once, for the chosen
// depth, from a copy of that depth's low band. Every sum runs in the same order as a
// per-column loop would, so results do not depend on the path. docs/COLUMN-TRANSFORM.md
// has the numerical guarantees.
#pragma once

#include <algorithm>
#include <cstdint>
#include <vector>

#include "format/status.h"
#include "stages/wavelet/wavelet.h"

namespace ltb::stages {

// Relative energy below which an approximation counts as exact: (64 ε_f32)², about
// 1.5e-11 (relative RMS error 4e-6), a bound on the rounding of up to ~12 f32 analysis
// and synthesis steps.
inline constexpr double kExactRelativeEnergy = (64.0 * 0x1p-24) * (64.0 * 0x1p-24);

// Energy bins for the rate–distortion budget: bin(e) = floor(8 · log2 e) for e > 0,
// computed exactly from the binary exponent and fixed thresholds 2^(k/8).
inline constexpr int kBinsPerOctave = 8;
int EnergyBin(double e);
double BinLowerEdge(int bin);  // 2^(bin/8): EnergyBin(e) >= bin  <=>  e >= BinLowerEdge(bin)

struct ColumnChoice {
  int depth = 0;
  double energy = 0;            // Σ x² of the column image
  double error = 0;             // Σ (x − x̂)² of the kept approximation at `depth`
  std::vector<uint32_t> index;  // kept coefficient positions (y·W + x in the Mallat layout), ascending
  std::vector<float> value;     // their coefficients
};

// How the coefficients to keep are chosen at a given depth.
struct Selection {
  enum class Kind { kTerms, kThreshold } kind = Kind::kTerms;
  uint64_t terms = 0;     // kTerms: keep the `terms` largest (by weighted energy);
                          // kThreshold: also keep the first `terms` (in position order) of bin threshold_bin − 1
  int threshold_bin = 0;  // kThreshold: keep those with EnergyBin(weighted energy) >= threshold_bin
};

// Per (column, depth) histogram of weighted coefficient energies, for the budget search.
struct EnergyHistogram {
  std::vector<int32_t> bin;     // ascending
  std::vector<uint64_t> count;  // coefficients in the bin
  std::vector<double> energy;   // Σ weighted energy in the bin
};

class ColumnCompressor {
 public:
  // Columns are width × height images (pixel (y, x) at y·width + x); depths
  // [min_depth, max_depth] are examined. Fails on sizes the filter cannot take.
  static Result<ColumnCompressor> Create(wavelet::Filter filter, uint64_t width, uint64_t height, int min_depth,
                                         int max_depth);

  static constexpr size_t kLanes = 8;  // columns transformed together (one vector lane each)

  // Chooses the depth and the kept coefficients of `n` ≤ kLanes columns (n pointers to
  // width·height floats). `selection[k]` applies to column k; `depth_override[k]` ≥ 0
  // fixes column k's depth (used by the budget's second pass), −1 examines the range.
  // All-zero columns get depth min_depth, energy 0 and nothing kept. Fails on a NaN or
  // an infinity, naming the column (by its position in the call) and the pixel.
  Status Choose(const float* const* columns, size_t n, const Selection* selection, const int* depth_override,
                ColumnChoice* out);

  // For the budget's first pass: the energy histograms of column k at every depth of the
  // range (out[k * depths() + (d − min_depth)]), and each column's energy.
  Status Histograms(const float* const* columns, size_t n, EnergyHistogram* out, double* energy);

  // Weighted energy factor ‖ψ̃‖² of every coefficient position at depth d.
  const std::vector<double>& Weights(int depth) const { return weights_[depth]; }

  wavelet::Filter filter() const { return filter_; }
  int min_depth() const { return min_depth_; }
  int max_depth() const { return max_depth_; }
  int depths() const { return max_depth_ - min_depth_ + 1; }
  uint64_t width() const { return width_; }
  uint64_t height() const { return height_; }
  // Tests and benchmarks: examine every depth the pre-issue-23 way (a full selection and,
  // for biorthogonal filters, a reconstruction per column and depth). Same results.
  void SetReferencePath(bool on) { reference_path_ = on; }

  // Bytes of working memory one compressor uses (for --mem-limit).
  static uint64_t WorkingBytes(uint64_t width, uint64_t height, int max_depth, bool orthonormal);

 private:
  Status Load(const float* const* columns, size_t n, double* energy, bool* live);
  // Selects at the current depth for lane k; fills kept positions (ascending) and, for
  // the orthonormal filters and depth 0, the exact dropped energy (else −1).
  void Select(size_t lane, int depth, const Selection& sel, double energy, std::vector<uint32_t>* kept,
              double* dropped);
  // kTerms selection: ranks by the float key |c|·‖ψ̃‖ (monotone in c²‖ψ̃‖²) with a radix
  // histogram of the key bits, kept up to date across depths: going from depth d−1 to d
  // changes only the coefficients of the old low band.
  void SelectTerms(size_t lane, int depth, uint64_t terms, std::vector<uint32_t>* kept);
  void UpdateKeys(size_t lane, int depth);
  void UpdateKeysGroup(int depth, const bool* lanes);  // UpdateKeys for lanes[k], in one pass
  // Its two passes over lanes lane[0..m) (column_keys.cpp): rebuilt from scratch, or updated
  // over the previous low band rw_w × rw_h; sub_w × sub_h is this depth's low band.
  void RebuildKeyLanes(int depth, const size_t* lane, size_t m, const float* rw, uint64_t sub_w, uint64_t sub_h);
  void UpdateKeyLanes(int depth, const size_t* lane, size_t m, const float* rw, uint64_t rw_w, uint64_t rw_h,
                      uint64_t sub_w, uint64_t sub_h);
  // The kept set of a kTerms selection as a cut: keys > t, and the first `ties` keys
  // equal to t in position order (n kept in all). False when that set needs the
  // explicit path (other selections, or kept terms the rounding-residue trim may drop).
  struct Cut {
    uint32_t t = 0;
    uint64_t ties = 0, n = 0;
  };
  bool CutTerms(size_t lane, int depth, const Selection& sel, double energy, Cut* cut);
  // One pass over the eight lanes at `depth`: lane k keeps what cut[k] keeps (t =
  // INT32_MAX keeps nothing). Unweighted: the dropped energy per lane into error[k];
  // weighted: the dropped part into work_.
  void CutPass(int depth, const Cut* cut, bool weighted, double* error);
  // Σ v² per lane of work_, in position order.
  void WorkEnergies(double* error);
  // The kept list of a cut at `depth`, from the saved low band of that depth (depth 0:
  // the column itself) and the finer bands, which later steps leave alone.
  void MaterializeCut(size_t lane, int depth, const Cut& cut, const float* column, ColumnChoice* out);
  // The positive keys of histogram bin `bin` into cand_.
  void Candidates(const uint32_t* keys, uint32_t bin);

  wavelet::Filter filter_ = wavelet::Filter::kLeGall53;
  bool orthonormal_ = false;
  uint64_t width_ = 0, height_ = 0, pixels_ = 0;
  int min_depth_ = 0, max_depth_ = 0;
  std::vector<wavelet::BandSize> bands_;
  std::vector<std::vector<double>> weights_;  // per depth (biorthogonal only; empty = all 1)
  std::vector<float> coeffs_;                 // [pixel][lane]
  std::vector<float> work_;                   // reconstruction buffer [pixel][lane]
  std::vector<float> scratch_;
  std::vector<double> mag_;  // weighted energies of one lane (budget paths)
  std::vector<int32_t> bins_;
  static constexpr int kKeyShift = 20;  // histogram of the key's top 11 bits (sign is 0)
  static constexpr size_t kKeyBins = size_t{1} << (31 - kKeyShift);
  std::vector<float> root_weights_;        // per depth ‖ψ̃‖, flattened (biorthogonal only)
  std::vector<uint32_t> keys_;             // [lane][pixel] float bits of |c|·‖ψ̃‖
  std::vector<uint32_t> key_hist_;         // [lane][bin]
  std::vector<uint32_t> sub_hist_;         // four partial histograms of one lane
  const float* const* columns_ = nullptr;  // during Choose: the columns (depth-0 keys)
  int key_depth_[kLanes] = {};             // depth the lane's keys describe (−1: none)
  uint64_t key_zeros_[kLanes] = {};        // keys equal to 0 per lane
  // The region an incremental UpdateKeys changes (the previous low band): its exact-zero
  // coefficients and the smallest key of the others, before and after the update.
  struct RegionStats {
    uint64_t zeros = 0;
    uint32_t min_key = UINT32_MAX;
    void Add(uint32_t abs_bits, uint32_t key) {
      if (abs_bits == 0)
        zeros++;
      else
        min_key = std::min(min_key, key);
    }
  };
  struct RegionTrack {
    RegionStats before, now;  // of the last update (before: min_key 0 when unknown)
    RegionStats next, saved;  // the next region (this depth's low band), as this update left it
  };
  RegionTrack region_[kLanes];
  std::vector<uint32_t> cand_;  // keys in the threshold bin
  std::vector<float> saved_;    // [lane][low band of the best depth so far]
  bool reference_path_ = false;
  std::vector<uint64_t> hist_count_;
  std::vector<double> hist_energy_;
};

}  // namespace ltb::stages
