#include "stages/images/envmap.h"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <glm/geometric.hpp>
#include <limits>

#include "format/io/atomic_file.h"
#include "format/npy.h"
#include "stages/common/quantity.h"
#include "stages/images/env_layout.h"
#include "stages/images/exact_cubemap.h"
#include "stages/images/image_readers.h"

// The image readers are in image_readers.{h,cpp}, hdr_reader.cpp and exr_reader.cpp, the
// layouts' geometry in env_layout.{h,cpp}, the resampler in resampler.{h,cpp} (its working grid
// in working_grid.{h,cpp}).

namespace ltb::stages {

using envmap_internal::AllocatePixels;
using envmap_internal::CheckMemory;
using envmap_internal::CrossFace;
using envmap_internal::Image;
using envmap_internal::ImageSize;
using envmap_internal::InAngularDisk;
using envmap_internal::kPi;
using envmap_internal::kRowsPerPoll;
using envmap_internal::ReadImage;
using envmap_internal::ReadImageSize;
using envmap_internal::Size;

namespace {

constexpr const char* kFaceNames[6] = {"px", "nx", "py", "ny", "pz", "nz"};
constexpr const char* kPlaceholder = "{face}";

std::string Num(double v) { return MessageNumber(v); }

bool EndsWithNoCase(const std::string& s, const std::string& suffix) {
  if (s.size() < suffix.size()) return false;
  for (size_t i = 0; i < suffix.size(); ++i) {
    if (std::tolower(static_cast<unsigned char>(s[s.size() - suffix.size() + i])) != suffix[i]) return false;
  }
  return true;
}

// Refuses (or, with clamp, fixes and counts) values that are not radiance, in the pixels
// the layout uses. The message names the first offending value in row-major order and how
// many there are.
Status CheckValues(Image* img, const std::string& path, EnvLayout layout, uint64_t face_size, bool clamp,
                   uint64_t* clamped, const Progress& progress) {
  uint64_t bad = 0, first_x = 0, first_y = 0;
  int first_c = 0;
  float first_v = 0, most_negative = 0;
  for (uint64_t y = 0; y < img->height; ++y) {
    if (y % kRowsPerPoll == 0 && progress.Cancelled()) {
      return Cancelled(path + ": interrupted while checking row " + std::to_string(y) + " of " +
                       std::to_string(img->height));
    }
    for (uint64_t x = 0; x < img->width; ++x) {
      if ((layout == EnvLayout::kHCross || layout == EnvLayout::kVCross) &&
          CrossFace(layout, x / face_size, y / face_size) < 0) {
        continue;
      }
      if (layout == EnvLayout::kAngular && !InAngularDisk(x, y, img->width)) continue;
      float* p = &img->rgb[(y * img->width + x) * 3];
      for (int c = 0; c < 3; ++c) {
        const float v = p[c];
        if (v >= 0.0f && v <= std::numeric_limits<float>::max()) continue;
        if (clamp) {
          p[c] = std::isnan(v) || v < 0 ? 0.0f : std::numeric_limits<float>::max();
          ++*clamped;
          continue;
        }
        if (bad++ == 0) first_x = x, first_y = y, first_c = c, first_v = v;
        if (v < most_negative) most_negative = v;
      }
    }
  }
  if (bad == 0) return Status::Ok();
  const float v = first_v;
  std::string kind = std::isnan(v)   ? "NaN"
                     : std::isinf(v) ? (v > 0 ? "infinite" : "negative and infinite")
                                     : "negative";
  std::string msg = path + ": pixel (" + std::to_string(first_x) + ", " + std::to_string(first_y) + ") channel " +
                    img->channel[first_c] + " is " + Num(v) + " (" + kind + ")";
  if (bad > 1) msg += "; " + std::to_string(bad) + " values in all";
  if (most_negative < 0) msg += ", the most negative " + Num(most_negative);
  msg +=
      "; radiance must be finite and non-negative — fix the map, or pass --clamp to set NaN and negative values "
      "to 0 and +Inf to the largest finite float";
  if (img->lossy && most_negative < 0) {
    msg +=
        " (" + img->compression + " compression is lossy and leaves small negative values; --clamp is the usual fix)";
  }
  return InvalidArgument(msg);
}

// What auto-detection accepts, for a map of w × h it did not recognise. A square map is
// named for what it most likely is (an angular light probe, read with --env-layout angular,
// or a mirror ball, which ltbake does not read): `--env-layout latlong` would read it
// without error and wrongly.
std::string AcceptedLayouts(uint64_t w, uint64_t h) {
  std::string s =
      "accepted: lat-long width = 2·height (e.g. 2048x1024), horizontal cross 4:3 (4F x 3F), vertical cross "
      "3:4 (3F x 4F), or six square face files through a {face} path (px nx py ny pz nz)";
  if (w == h) {
    return s +
           ". A square map is usually an angular (light-probe) map: say so with --env-layout angular; a "
           "mirror-ball map ltbake does not read: resample it to lat-long first (--env-layout latlong would read "
           "either, wrongly)";
  }
  return s + "; --env-layout latlong reads a lat-long map of any other size";
}

// The layout of a single-image map of w × h: o.layout when the size fits it, else what
// auto-detection reads from the size; an error names the size and the layouts accepted.
Result<EnvLayout> ResolveLayout(const std::string& path, uint64_t w, uint64_t h, EnvLayout requested) {
  EnvLayout layout = requested;
  if (layout == EnvLayout::kAuto) {
    if (w == 2 * h) {
      layout = EnvLayout::kLatLong;
    } else if (3 * w == 4 * h) {
      layout = EnvLayout::kHCross;
    } else if (4 * w == 3 * h) {
      layout = EnvLayout::kVCross;
    } else {
      return InvalidArgument(path + ": " + Size(w, h) + " is not an environment map shape ltbake recognises; " +
                             AcceptedLayouts(w, h));
    }
  } else if (layout == EnvLayout::kHCross && 3 * w != 4 * h) {
    return InvalidArgument(path + ": " + Size(w, h) + " is not a horizontal cross (4F x 3F, width:height = 4:3)");
  } else if (layout == EnvLayout::kVCross && 4 * w != 3 * h) {
    return InvalidArgument(path + ": " + Size(w, h) + " is not a vertical cross (3F x 4F, width:height = 3:4)");
  } else if (layout == EnvLayout::kAngular && w != h) {
    return InvalidArgument(path + ": " + Size(w, h) + " is not an angular map (a square image holding the disk)");
  } else if (layout == EnvLayout::kFaces && h != 6 * w) {
    return InvalidArgument(path + ": " + Size(w, h) +
                           " is not a strip of six faces (F x 6F); for six files use a path with {face}");
  }
  return layout;
}

Result<EnvMap> LoadFaces(const std::string& path, const EnvLoadOptions& o) {
  EnvMap env;
  env.layout = EnvLayout::kFaces;
  env.path = path;
  for (int f = 0; f < 6; ++f) {
    std::string p = path;
    for (size_t at; (at = p.find(kPlaceholder)) != std::string::npos;)
      p.replace(at, std::strlen(kPlaceholder), kFaceNames[f]);
    // Faces after the first share the memory limit with the six-face map already allocated.
    EnvLoadOptions face_options = o;
    if (f > 0 && o.max_bytes != 0) {
      face_options.max_bytes =
          std::max<uint64_t>(1, o.max_bytes - std::min(o.max_bytes, env.rgb.size() * sizeof(float)));
    }
    LTB_ASSIGN_OR_RETURN(Image img, ReadImage(p, face_options));
    if (img.width != img.height) {
      return InvalidArgument(p + ": a cube face must be square, this one is " + Size(img.width, img.height));
    }
    if (f == 0) {
      env.width = img.width;
      env.height = 6 * img.width;
      const std::string what = "the six " + Size(img.width, img.width) + " faces of " + path;
      LTB_RETURN_IF_ERROR(CheckMemory(env.width * env.height, img.rgb.size() * sizeof(float), o.max_bytes, p, what));
      LTB_RETURN_IF_ERROR(AllocatePixels(&env.rgb, env.width * env.height * 3, p, what));
    } else if (img.width != env.width) {
      return InvalidArgument(p + ": face is " + Size(img.width, img.height) + ", the +X face is " +
                             Size(env.width, env.width) + "; all six faces must have the same size");
    }
    LTB_RETURN_IF_ERROR(CheckValues(&img, p, EnvLayout::kFaces, env.width, o.clamp, &env.clamped, o.progress));
    std::copy(img.rgb.begin(), img.rgb.end(), env.rgb.begin() + f * env.width * env.width * 3);
  }
  return env;
}

}  // namespace

const char* EnvLayoutName(EnvLayout layout) {
  switch (layout) {
    case EnvLayout::kAuto:
      return "auto";
    case EnvLayout::kLatLong:
      return "latlong";
    case EnvLayout::kHCross:
      return "hcross";
    case EnvLayout::kVCross:
      return "vcross";
    case EnvLayout::kFaces:
      return "faces";
    case EnvLayout::kAngular:
      return "angular";
  }
  return "?";
}

Result<EnvLayout> ParseEnvLayout(const std::string& name) {
  for (EnvLayout l : {EnvLayout::kAuto, EnvLayout::kLatLong, EnvLayout::kHCross, EnvLayout::kVCross, EnvLayout::kFaces,
                      EnvLayout::kAngular}) {
    if (name == EnvLayoutName(l)) return l;
  }
  return InvalidArgument("environment layout \"" + name +
                         "\" is not one of auto, latlong, hcross, vcross, faces, angular");
}

bool IsEnvMapPath(const std::string& path) {
  return path.find(kPlaceholder) != std::string::npos || EndsWithNoCase(path, ".exr") || EndsWithNoCase(path, ".hdr") ||
         EndsWithNoCase(path, ".pic") || EndsWithNoCase(path, ".rgbe");
}

Result<EnvMap> LoadEnvMap(const std::string& path, const EnvLoadOptions& o) {
  const bool faces = path.find(kPlaceholder) != std::string::npos;
  if (faces) {
    if (o.layout != EnvLayout::kAuto && o.layout != EnvLayout::kFaces) {
      return InvalidArgument(path + ": a {face} path names six face files; --env-layout " + EnvLayoutName(o.layout) +
                             " needs one image");
    }
    return LoadFaces(path, o);
  }
  LTB_ASSIGN_OR_RETURN(Image img, ReadImage(path, o));
  const uint64_t w = img.width, h = img.height;
  LTB_ASSIGN_OR_RETURN(const EnvLayout layout, ResolveLayout(path, w, h, o.layout));
  EnvMap env;
  env.layout = layout;
  env.width = w;
  env.height = h;
  env.path = path;
  const uint64_t face = layout == EnvLayout::kHCross ? w / 4 : layout == EnvLayout::kVCross ? w / 3 : w;
  LTB_RETURN_IF_ERROR(CheckValues(&img, path, layout, face, o.clamp, &env.clamped, o.progress));
  env.rgb = std::move(img.rgb);
  return env;
}

Result<EnvLayout> CheckEnvMapShape(const std::string& path, const EnvLoadOptions& o) {
  if (path.find(kPlaceholder) == std::string::npos) {
    LTB_ASSIGN_OR_RETURN(const ImageSize size, ReadImageSize(path, o));
    return ResolveLayout(path, size.width, size.height, o.layout);
  }
  if (o.layout != EnvLayout::kAuto && o.layout != EnvLayout::kFaces) {
    return InvalidArgument(path + ": a {face} path names six face files; --env-layout " + EnvLayoutName(o.layout) +
                           " needs one image");
  }
  uint64_t first = 0;
  for (int f = 0; f < 6; ++f) {
    std::string p = path;
    for (size_t at; (at = p.find(kPlaceholder)) != std::string::npos;)
      p.replace(at, std::strlen(kPlaceholder), kFaceNames[f]);
    LTB_ASSIGN_OR_RETURN(const ImageSize size, ReadImageSize(p, o));
    if (size.width != size.height) {
      return InvalidArgument(p + ": a cube face must be square, this one is " + Size(size.width, size.height));
    }
    if (f == 0) first = size.width;
    if (size.width != first) {
      return InvalidArgument(p + ": face is " + Size(size.width, size.height) + ", the +X face is " +
                             Size(first, first) + "; all six faces must have the same size");
    }
  }
  return EnvLayout::kFaces;
}

glm::dvec3 LatLongDirection(double u, double v) {
  const double phi = kPi - 2.0 * kPi * u, theta = kPi * v;
  const double st = std::sin(theta);
  return {st * std::cos(phi), st * std::sin(phi), std::cos(theta)};
}

void DirectionToLatLong(const glm::dvec3& d, double* u, double* v) {
  const double len = glm::length(d);
  double uu = (kPi - std::atan2(d.y, d.x)) / (2.0 * kPi);
  if (uu >= 1.0) uu -= 1.0;
  *u = uu;
  *v = std::acos(std::clamp(d.z / len, -1.0, 1.0)) / kPi;
}

Result<std::vector<float>> EnvToCubemap(const std::string& in, uint64_t cube_res, const EnvLoadOptions& options,
                                        uint64_t* clamped) {
  if (cube_res == 0) {
    return InvalidArgument("convert " + in + ": an environment map needs --cube-res R (the cubemap's face size)");
  }
  if ((cube_res & (cube_res - 1)) != 0 || cube_res > CubemapResampler::kMaxCubeRes) {
    return InvalidArgument("--cube-res " + std::to_string(cube_res) + " is not a power of two up to " +
                           std::to_string(CubemapResampler::kMaxCubeRes));
  }
  LTB_ASSIGN_OR_RETURN(EnvMap env, LoadEnvMap(in, options));
  if (clamped != nullptr) *clamped = env.clamped;
  // Exact texel averages for every layout: the resampler for a lat-long map (exact there),
  // the clipped pixels (exact_cubemap.h) for the others.
  if (env.layout != EnvLayout::kLatLong) return ExactCubemap(env, cube_res, 0.0, options.progress);
  LTB_ASSIGN_OR_RETURN(CubemapResampler rs, CubemapResampler::Create(env, cube_res, options.progress));
  std::vector<float> cube(6 * cube_res * cube_res * 3);
  rs.Resample(0.0, cube.data());
  return cube;
}

Status ConvertEnvToNpy(const std::string& in, const std::string& out, uint64_t cube_res, const EnvLoadOptions& options,
                       uint64_t* clamped) {
  if (!EndsWithNoCase(out, ".npy")) {
    return InvalidArgument("convert " + in + " " + out + ": an environment map converts to a .npy cubemap");
  }
  LTB_ASSIGN_OR_RETURN(std::vector<float> cube, EnvToCubemap(in, cube_res, options, clamped));
  const uint64_t texels = 6 * cube_res * cube_res;
  std::vector<std::byte> header = format::EncodeNpyHeader("<f4", {texels, 3});
  // Written beside the output and renamed: OUT never holds a partial cubemap.
  LTB_ASSIGN_OR_RETURN(io::AtomicFile f, io::AtomicFile::Create(out));
  LTB_RETURN_IF_ERROR(f.file().WriteAt(0, header));
  LTB_RETURN_IF_ERROR(f.file().WriteAt(
      header.size(), format::ByteSpan(reinterpret_cast<const std::byte*>(cube.data()), cube.size() * sizeof(float))));
  return f.Commit();
}

}  // namespace ltb::stages
