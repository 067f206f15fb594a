// Writing relit images: linear OpenEXR (32-bit float RGB), tone-mapped sRGB PNG, or .npy
// (rows × 3 float32, rows in matrix order). Each is written beside the target and renamed
// into place, so the path never holds a half-written image.
#pragma once

#include <cstdint>
#include <string>

#include "format/status.h"

namespace ltb::stages {

struct ImageWriteOptions {
  // PNG only: radiance is multiplied by `exposure` before the sRGB curve; 0 picks the
  // exposure that maps the 99th percentile of luminance to 0.9.
  double exposure = 0;
};

// `rgb` holds rows × 3 floats; width × height must equal rows for .exr and .png.
Status WriteImage(const std::string& path, const float* rgb, uint64_t rows, uint64_t width, uint64_t height,
                  const ImageWriteOptions& options = {});

}  // namespace ltb::stages
