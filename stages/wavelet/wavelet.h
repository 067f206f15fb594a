// Wavelet transforms shared by the stages and by relighting.
//
// Filters: orthonormal `haar` (= db1), `db2`, `db3`, `db4` with periodic extension on
// power-of-two lengths, matching PyWavelets' mode='periodization'; biorthogonal
// `legall53` and `cdf97` as the JPEG 2000 Part 1 lifting steps with whole-sample
// symmetric extension, for any length (a length-1 signal is its own low band).
//
// Data layout: a signal is `n` samples `stride` values apart, and every sample is a
// vector of `lanes` contiguous values — so one call transforms `lanes` independent
// signals at once (e.g. 16 matrix rows), and the inner loops run over contiguous lanes.
// A 2D image is width × height pixels, pixel (y, x) at data[(y * width + x) * lanes].
// One 2D analysis step transforms the top-left band (one row step, then one column
// step) into the Mallat layout: low band top-left, then the high bands (as
// pywt.coeffs_to_array lays them out). Low bands have ceil(n/2) samples.
//
// No call allocates: each takes a scratch buffer of at least ScratchSize() values.
#pragma once

#include <cstddef>
#include <span>
#include <string>
#include <vector>

#include "format/status.h"

namespace ltb::wavelet {

enum class Filter { kHaar, kDb2, kDb3, kDb4, kLeGall53, kCdf97 };

// "haar", "db1" (= haar), "db2", "db3", "db4", "legall53", "cdf97".
Result<Filter> ParseFilter(const std::string& name);
const char* FilterName(Filter f);
bool IsOrthonormal(Filter f);
// Analysis low-pass taps of an orthonormal filter as PyWavelets defines them (dec_lo;
// dec_hi[j] = (-1)^(j+1) dec_lo[F-1-j]); empty for the biorthogonal ones.
std::span<const double> OrthoLowPass(Filter f);

inline size_t LowCount(size_t n) { return (n + 1) / 2; }

// Number of 2D steps that bring a width × height image to a 1 × 1 low band.
int MaxDepth(size_t width, size_t height);
// Sizes of the low band after 0..depth steps (element 0 is width × height).
struct BandSize {
  size_t width, height;
};
std::vector<BandSize> BandSizes(size_t width, size_t height, int depth);

// Orthonormal filters need power-of-two sides; biorthogonal ones take any size.
Status CheckSize(Filter f, size_t width, size_t height);

// Scratch values needed by the 2D calls on a width × height image with `lanes`.
inline size_t ScratchSize(size_t width, size_t height, size_t lanes) { return width * height * lanes; }

// 1D single steps on n samples (n >= 1; a power of two for orthonormal filters).
// Scratch: n * lanes values.
template <typename T>
void AnalysisStep1D(Filter f, T* data, size_t n, size_t stride, size_t lanes, T* scratch);
template <typename T>
void SynthesisStep1D(Filter f, T* data, size_t n, size_t stride, size_t lanes, T* scratch);

// 1D transform to `depth` levels (each step on the low band) and its inverse.
template <typename T>
void Forward1D(Filter f, T* data, size_t n, size_t stride, size_t lanes, int depth, T* scratch);
template <typename T>
void Inverse1D(Filter f, T* data, size_t n, size_t stride, size_t lanes, int depth, T* scratch);

// One 2D analysis step on the band_w × band_h top-left band of the image (depth l to
// l+1), and the single synthesis step back (depth l+1 to l) given the same band size.
template <typename T>
void AnalysisStep2D(Filter f, T* data, size_t width, size_t lanes, size_t band_w, size_t band_h, T* scratch);
template <typename T>
void SynthesisStep2D(Filter f, T* data, size_t width, size_t lanes, size_t band_w, size_t band_h, T* scratch);

// Full 2D transform to `depth` steps (depth <= MaxDepth) and its inverse.
template <typename T>
void Forward2D(Filter f, T* data, size_t width, size_t height, size_t lanes, int depth, T* scratch);
template <typename T>
void Inverse2D(Filter f, T* data, size_t width, size_t height, size_t lanes, int depth, T* scratch);

}  // namespace ltb::wavelet
