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

// `rgb` holds rows × 3 floats; width × height must equal rows for .exr and .png.
Status WriteImage(const std::string& path, const float* rgb, uint64_t rows, uint64_t width, uint64_t height,
                  const ImageWriteOptions& options = {});

}  // namespace ltb::stages
