// Writing relit images: linear OpenEXR (32-bit float RGB), tone-mapped sRGB PNG, or .npy
// (rows × 3 float32, rows in matrix order). Each is written beside the target and renamed
// into place, so the path never holds a half-written image.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "format/status.h"

namespace ltb::stages {

// The largest PNG exposure a flag or a query takes.
inline constexpr double kMaxExposure = 1e12;

struct ImageWriteOptions {
  // PNG only: radiance is multiplied by `exposure` (0..kMaxExposure) before the sRGB curve;
  // 0 picks the exposure that maps the 99th percentile of luminance to 0.9.
  double exposure = 0;
};

// The PNG exposure: the 99th percentile of luminance maps to 0.9 (1 for a black image).
double AutoExposure(const float* rgb, uint64_t rows);
// rows × 3 bytes: radiance × exposure through the sRGB curve.
std::vector<uint8_t> ToSrgb8(const float* rgb, uint64_t rows, double exposure);
// A PNG file's bytes, in memory, from width × height × 3 sRGB bytes.
std::string EncodePng(const uint8_t* srgb, uint64_t width, uint64_t height);
// An EXR file's bytes, in memory, from width × height × 3 linear floats: the file WriteImage
// writes for an .exr path, byte for byte.
Result<std::string> EncodeExr(const float* rgb, uint64_t width, uint64_t height);

// `rgb` holds rows × 3 floats; width × height must equal rows for .exr and .png.
Status WriteImage(const std::string& path, const float* rgb, uint64_t rows, uint64_t width, uint64_t height,
                  const ImageWriteOptions& options = {});

// The path of frame `frame` from an -o pattern with one integer conversion (%d, %04d, %0Nd
// for N < 100; %% for a literal %), or an error naming the pattern: a lighting sequence's
// (which may be an .mp4 instead) or an orbit's (triple-product and glossy views).
enum class FramePattern { kSequence, kOrbit };
Result<std::string> FramePath(const std::string& pattern, uint64_t frame, FramePattern kind = FramePattern::kSequence);

// Ok when every value of a relit image (rows × 3) is finite; else an InvalidArgument naming
// the first pixel (x, y of an image `width` wide; a row of a vertex bake, width 0), its
// channel and value, and the lighting `env` whose radiance is too large to relight in float32.
Status CheckRelitImageFinite(const std::vector<float>& image, uint64_t width, const std::string& env);

}  // namespace ltb::stages
