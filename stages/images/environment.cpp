#include "stages/images/environment.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <utility>

#include "format/bytes.h"
#include "format/io/file.h"
#include "format/npy.h"
#include "stages/common/quantity.h"
#include "stages/images/exact_cubemap.h"

namespace ltb::stages {

namespace {

// A cubemap .npy opened and its header parsed (only a regular file is opened).
struct NpyFile {
  io::File f;
  uint64_t size = 0;
  format::NpyHeader h;
};
Result<NpyFile> OpenNpy(const std::string& path) {
  LTB_RETURN_IF_ERROR(io::RequireRegularFile(path, "name a 6R² × 3 cubemap .npy file"));
  LTB_ASSIGN_OR_RETURN(io::File f, io::File::Open(path, io::File::Mode::kRead));
  LTB_ASSIGN_OR_RETURN(uint64_t size, f.Size());
  std::vector<std::byte> head(std::min<uint64_t>(size, format::kMaxNpyHeaderBytes + 12));
  LTB_RETURN_IF_ERROR(f.ReadAt(0, head));
  auto h = format::ParseNpyHeader(head);
  if (!h.ok()) return h.status().WithContext(path);
  return NpyFile{std::move(f), size, std::move(*h)};
}

}  // namespace

Result<uint64_t> CubemapNpyResolution(const std::string& path) {
  LTB_ASSIGN_OR_RETURN(NpyFile npy, OpenNpy(path));
  const format::NpyHeader& h = npy.h;
  const uint64_t n = h.shape.empty() ? 0 : h.shape[0];
  const uint64_t r = n % 6 == 0 ? static_cast<uint64_t>(std::llround(std::sqrt(static_cast<double>(n / 6)))) : 0;
  if (h.fortran_order || h.shape.size() != 2 || h.shape[1] != 3 || r == 0 || 6 * r * r != n || (r & (r - 1)) != 0 ||
      (h.descr != "<f4" && h.descr != "<f8")) {
    return InvalidArgument(path +
                           " is not a cubemap .npy (a C-order float32/float64 array of shape (6R², 3), R a power of "
                           "two; `ltbake convert env.exr env.npy --cube-res R` writes one)");
  }
  return r;
}

Result<std::vector<float>> ReadCubemapNpy(const std::string& path, uint64_t r, bool clamp, uint64_t* clamped) {
  LTB_ASSIGN_OR_RETURN(NpyFile npy, OpenNpy(path));
  io::File& f = npy.f;
  const uint64_t size = npy.size;
  const format::NpyHeader* h = &npy.h;
  uint64_t n = 0;
  if (r == 0 || format::MulOverflows(r, r, &n) || format::MulOverflows(n, 6, &n) || n > (uint64_t(1) << 40)) {
    return InvalidArgument(path + ": cube resolution " + std::to_string(r) + " of the matrix is out of range");
  }
  std::string shape;
  for (uint64_t d : h->shape) shape += (shape.empty() ? "" : ", ") + std::to_string(d);
  if (h->shape.size() == 1) shape += ",";
  if (h->fortran_order || h->shape.size() != 2 || h->shape[0] != n || h->shape[1] != 3 ||
      (h->descr != "<f4" && h->descr != "<f8")) {
    return InvalidArgument(path + ": holds a " + (h->fortran_order ? "Fortran-order" : "C-order") + " '" + h->descr +
                           "' array of shape (" + shape + "); expected a C-order float32/float64 array of shape (" +
                           std::to_string(n) + ", 3), a cubemap for R = " + std::to_string(r) +
                           " (`ltbake convert env.exr env.npy --cube-res " + std::to_string(r) + "` writes one)");
  }
  LTB_ASSIGN_OR_RETURN(uint64_t data_bytes, format::NpyDataBytes(*h));
  if (h->data_offset > size || data_bytes > size - h->data_offset) {
    return InvalidArgument(path + ": truncated: shape (" + shape + ") of '" + h->descr + "' needs " +
                           std::to_string(data_bytes) + " bytes after the " + std::to_string(h->data_offset) +
                           "-byte header, the file has " + std::to_string(size - std::min(size, h->data_offset)));
  }
  // The output is no larger than the file; the values are read in strips of 1 MiB.
  std::vector<float> out(n * 3);
  constexpr double kFloatMax = std::numeric_limits<float>::max();
  uint64_t bad = 0, first = 0;
  double first_value = 0, most_negative = 0;
  const uint64_t per_strip = (uint64_t(1) << 20) / h->itemsize;
  std::vector<std::byte> raw(std::min(n * 3, per_strip) * h->itemsize);
  for (uint64_t strip = 0; strip < n * 3; strip += per_strip) {
    const uint64_t count = std::min(per_strip, n * 3 - strip);
    LTB_RETURN_IF_ERROR(
        f.ReadAt(h->data_offset + strip * h->itemsize, format::MutableByteSpan(raw.data(), count * h->itemsize)));
    for (uint64_t k = 0; k < count; ++k) {
      double v;
      if (h->itemsize == 4) {
        float x;
        std::memcpy(&x, raw.data() + k * 4, 4);
        v = x;
      } else {
        std::memcpy(&v, raw.data() + k * 8, 8);
      }
      const uint64_t i = strip + k;
      if (v >= 0 && v <= kFloatMax) {
        out[i] = static_cast<float>(v);
        continue;
      }
      if (clamp) {
        out[i] = std::isnan(v) || v < 0 ? 0.0f : static_cast<float>(kFloatMax);
        if (clamped != nullptr) ++*clamped;
        continue;
      }
      if (bad++ == 0) first = i, first_value = v;
      if (v < most_negative) most_negative = v;
    }
  }
  if (bad == 0) return out;
  const char* kind = std::isnan(first_value)   ? "NaN"
                     : std::isinf(first_value) ? (first_value > 0 ? "infinite" : "negative and infinite")
                     : first_value < 0         ? "negative"
                                               : "beyond float32's largest value, 3.40282347e+38";
  std::string msg = path + ": texel " + std::to_string(first / 3) + " channel " + std::to_string(first % 3) + " is " +
                    MessageNumber(first_value) + " (" + kind + ")";
  if (bad > 1) msg += "; " + std::to_string(bad) + " values in all";
  if (most_negative < 0) msg += ", the most negative " + MessageNumber(most_negative);
  return InvalidArgument(msg +
                         "; radiance must be finite and non-negative — fix the cubemap, or pass --clamp to set NaN "
                         "and negative values to 0 and larger ones to the largest finite float");
}

Result<Environment> Environment::Open(const std::string& path, uint64_t cube_res, const EnvLoadOptions& o,
                                      EnvResampling resampling) {
  Environment e;
  e.cube_res_ = cube_res;
  e.progress_ = o.progress;
  e.jobs_ = o.jobs;
  if (path.ends_with(".npy")) {
    LTB_ASSIGN_OR_RETURN(std::vector<float> m, ReadCubemapNpy(path, cube_res, o.clamp, &e.clamped_));
    e.fixed_ = std::move(m);
    for (float v : e.fixed_) e.peak_ = std::max(e.peak_, std::fabs(v));
    return e;
  }
  LTB_ASSIGN_OR_RETURN(EnvMap map, LoadEnvMap(path, o));
  e.clamped_ = map.clamped;
  for (float v : map.rgb) e.peak_ = std::max(e.peak_, std::fabs(v));  // NaN (outside an angular disk) is skipped
  if (resampling == EnvResampling::kExact && map.layout != EnvLayout::kLatLong) {
    e.exact_ = std::make_shared<const EnvMap>(std::move(map));
    return e;
  }
  LTB_ASSIGN_OR_RETURN(CubemapResampler r, CubemapResampler::Create(map, cube_res, o.progress));
  e.resampler_ = std::make_unique<CubemapResampler>(std::move(r));
  return e;
}

Result<Environment> Environment::FromCubemap(std::vector<float> values, uint64_t cube_res, bool clamp,
                                             const std::string& what) {
  if (cube_res == 0 || values.size() != 18 * cube_res * cube_res) {
    return InvalidArgument(what + ": holds " + std::to_string(values.size()) +
                           " values; expected a cubemap of shape (" + std::to_string(6 * cube_res * cube_res) +
                           ", 3) for the matrix's R = " + std::to_string(cube_res));
  }
  Environment e;
  e.cube_res_ = cube_res;
  uint64_t bad = 0, first = 0;
  for (uint64_t i = 0; i < values.size(); ++i) {
    float& v = values[i];
    if (v >= 0 && std::isfinite(v)) continue;
    if (clamp) {
      v = std::isnan(v) || v < 0 ? 0.0f : std::numeric_limits<float>::max();
      ++e.clamped_;
    } else if (bad++ == 0) {
      first = i;
    }
  }
  if (bad > 0) {
    return InvalidArgument(what + ": texel " + std::to_string(first / 3) + " channel " + std::to_string(first % 3) +
                           " is " + MessageNumber(values[first]) + "; " + std::to_string(bad) +
                           " values in all are not finite and non-negative radiance (clamp_env=True sets NaN and "
                           "negative values to 0 and +Inf to the largest finite float)");
  }
  e.fixed_ = std::move(values);
  for (float v : e.fixed_) e.peak_ = std::max(e.peak_, v);
  return e;
}

Status Environment::Cubemap(double rotation, std::vector<float>* out) const {
  if (exact_) {
    std::lock_guard<std::mutex> lock(last_->mutex);
    if (last_->cube.empty() || last_->rotation != rotation) {
      LTB_ASSIGN_OR_RETURN(last_->cube, ExactCubemap(*exact_, cube_res_, rotation, progress_));
      last_->rotation = rotation;
    }
    *out = last_->cube;
    return Status::Ok();
  }
  out->resize(6 * cube_res_ * cube_res_ * 3);
  if (resampler_) {
    resampler_->Resample(rotation, out->data(), jobs_);
  } else {
    std::copy(fixed_.begin(), fixed_.end(), out->begin());
  }
  return Status::Ok();
}

}  // namespace ltb::stages
