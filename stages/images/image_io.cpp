#include "stages/images/image_io.h"

#include <OpenEXR/ImfChannelList.h>
#include <OpenEXR/ImfFrameBuffer.h>
#include <OpenEXR/ImfHeader.h>
#include <OpenEXR/ImfIO.h>
#include <OpenEXR/ImfOutputFile.h>
#include <stb/stb_image_write.h>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdio>
#include <vector>

#include "format/io/atomic_file.h"
#include "format/io/file.h"
#include "format/io/file_lock.h"
#include "format/npy.h"
#include "stages/common/quantity.h"

namespace ltb::stages {

namespace {

// The relit image's EXR: 32-bit float RGB, ZIP compression; into a file or a stream.
Imf::Header ExrHeader(uint64_t w, uint64_t h) {
  Imf::Header header(static_cast<int>(w), static_cast<int>(h));
  header.compression() = Imf::ZIP_COMPRESSION;
  for (const char* c : {"R", "G", "B"}) header.channels().insert(c, Imf::Channel(Imf::FLOAT));
  return header;
}

void WriteExrPixels(Imf::OutputFile& file, const float* rgb, uint64_t w, uint64_t h) {
  Imf::FrameBuffer fb;
  const size_t xs = 3 * sizeof(float), ys = w * xs;
  char* base = reinterpret_cast<char*>(const_cast<float*>(rgb));
  fb.insert("R", Imf::Slice(Imf::FLOAT, base, xs, ys));
  fb.insert("G", Imf::Slice(Imf::FLOAT, base + 4, xs, ys));
  fb.insert("B", Imf::Slice(Imf::FLOAT, base + 8, xs, ys));
  file.setFrameBuffer(fb);
  file.writePixels(static_cast<int>(h));
}

Status WriteExr(const std::string& tmp, const float* rgb, uint64_t w, uint64_t h) {
  try {
    Imf::OutputFile file(tmp.c_str(), ExrHeader(w, h));
    WriteExrPixels(file, rgb, w, h);
  } catch (const std::exception& e) {
    return InvalidArgument(tmp + ": OpenEXR: " + e.what());
  }
  return Status::Ok();
}

// An OpenEXR output stream into a string (the writer seeks back to fill in its offset table).
class StringOStream : public Imf::OStream {
 public:
  explicit StringOStream(std::string* out) : Imf::OStream("memory"), out_(out) {}
  void write(const char c[], int n) override {
    const size_t end = pos_ + static_cast<size_t>(n);
    if (end > out_->size()) out_->resize(end);
    std::copy(c, c + n, out_->begin() + static_cast<std::ptrdiff_t>(pos_));
    pos_ = end;
  }
  uint64_t tellp() override { return pos_; }
  void seekp(uint64_t pos) override { pos_ = pos; }

 private:
  std::string* out_;
  size_t pos_ = 0;
};

double SrgbEncode(double v) {
  v = std::clamp(v, 0.0, 1.0);
  return v <= 0.0031308 ? 12.92 * v : 1.055 * std::pow(v, 1.0 / 2.4) - 0.055;
}

Status WritePng(const std::string& tmp, const float* rgb, uint64_t w, uint64_t h, double exposure) {
  if (exposure <= 0) exposure = AutoExposure(rgb, w * h);
  std::vector<uint8_t> px = ToSrgb8(rgb, w * h, exposure);
  if (stbi_write_png(tmp.c_str(), static_cast<int>(w), static_cast<int>(h), 3, px.data(), static_cast<int>(w * 3)) ==
      0) {
    return IoError(tmp + ": writing the PNG failed", errno);
  }
  return Status::Ok();
}

Status WriteNpy(const io::File& f, const float* rgb, uint64_t rows) {
  std::vector<std::byte> header = format::EncodeNpyHeader("<f4", {rows, 3});
  LTB_RETURN_IF_ERROR(f.WriteAt(0, header));
  return f.WriteAt(header.size(), format::ByteSpan(reinterpret_cast<const std::byte*>(rgb), rows * 12));
}

}  // namespace

double AutoExposure(const float* rgb, uint64_t n) {
  if (n == 0) return 1.0;
  std::vector<float> lum(n);
  for (uint64_t i = 0; i < n; ++i) lum[i] = 0.2126f * rgb[i * 3] + 0.7152f * rgb[i * 3 + 1] + 0.0722f * rgb[i * 3 + 2];
  auto k = lum.begin() + static_cast<std::ptrdiff_t>(std::min<uint64_t>(n - 1, n * 99 / 100));
  std::nth_element(lum.begin(), k, lum.end());
  return *k > 0 ? 0.9 / *k : 1.0;
}

std::vector<uint8_t> ToSrgb8(const float* rgb, uint64_t n, double exposure) {
  std::vector<uint8_t> px(n * 3);
  for (uint64_t i = 0; i < n * 3; ++i) px[i] = static_cast<uint8_t>(std::lround(255.0 * SrgbEncode(exposure * rgb[i])));
  return px;
}

Result<std::string> EncodeExr(const float* rgb, uint64_t w, uint64_t h) {
  std::string out;
  try {
    StringOStream stream(&out);
    Imf::OutputFile file(stream, ExrHeader(w, h));
    WriteExrPixels(file, rgb, w, h);
  } catch (const std::exception& e) {
    return InvalidArgument(std::string("encoding an EXR image: OpenEXR: ") + e.what());
  }
  return out;
}

std::string EncodePng(const uint8_t* srgb, uint64_t w, uint64_t h) {
  std::string out;
  stbi_write_png_to_func(
      [](void* ctx, void* data, int size) { static_cast<std::string*>(ctx)->append(static_cast<char*>(data), size); },
      &out, static_cast<int>(w), static_cast<int>(h), 3, srgb, static_cast<int>(w * 3));
  return out;
}

Status WriteImage(const std::string& path, const float* rgb, uint64_t rows, uint64_t width, uint64_t height,
                  const ImageWriteOptions& options) {
  const bool exr = path.ends_with(".exr"), png = path.ends_with(".png"), npy = path.ends_with(".npy");
  if (!exr && !png && !npy) return InvalidArgument(path + ": the output is chosen by extension: .exr, .png or .npy");
  if ((exr || png) && (width * height != rows || width == 0)) {
    return InvalidArgument(path + ": the matrix rows are not an image (" + std::to_string(rows) +
                           " rows); write .npy instead");
  }
  // Never a non-finite value in an image.
  for (uint64_t i = 0; i < rows * 3; ++i) {
    if (std::isfinite(rgb[i])) continue;
    const uint64_t r = i / 3;
    const std::string where = width > 0 && width * height == rows
                                  ? "pixel (" + std::to_string(r % width) + ", " + std::to_string(r / width) + ")"
                                  : "row " + std::to_string(r);
    return InvalidArgument(path + ": not written: its " + where + " channel " + "RGB"[i % 3] + " would be " +
                           (std::isnan(rgb[i]) ? "NaN"
                            : rgb[i] > 0       ? "+Inf"
                                               : "-Inf") +
                           " (the lighting is too bright to relight in float32? scale the map down)");
  }
  // One writer per output: a second relight into the same path would remove this one's
  // partial file under it.
  LTB_ASSIGN_OR_RETURN(io::FileLock lock, io::LockOutput(path));
  // The EXR and PNG writers open the temporary path themselves (the same file: Commit
  // syncs its data through the AtomicFile's descriptor).
  LTB_ASSIGN_OR_RETURN(io::AtomicFile f, io::AtomicFile::Create(path));
  const std::string& tmp = f.temp_path();
  LTB_RETURN_IF_ERROR(exr   ? WriteExr(tmp, rgb, width, height)
                      : png ? WritePng(tmp, rgb, width, height, options.exposure)
                            : WriteNpy(f.file(), rgb, rows));
  return f.Commit();
}

namespace {
const char* Whose(FramePattern kind) { return kind == FramePattern::kSequence ? "a sequence's" : "an orbit's"; }
}  // namespace

Result<std::string> FramePath(const std::string& pattern, uint64_t frame, FramePattern kind) {
  const std::string video = kind == FramePattern::kSequence ? ", or an .mp4" : "";
  std::string out;
  int conversions = 0;
  for (size_t i = 0; i < pattern.size(); ++i) {
    if (pattern[i] != '%') {
      out += pattern[i];
      continue;
    }
    if (i + 1 < pattern.size() && pattern[i + 1] == '%') {
      out += '%';
      ++i;
      continue;
    }
    size_t j = i + 1;
    bool zero = j < pattern.size() && pattern[j] == '0';
    if (zero) ++j;
    size_t width_start = j;
    while (j < pattern.size() && std::isdigit(static_cast<unsigned char>(pattern[j]))) ++j;
    if (j >= pattern.size() || pattern[j] != 'd' || j - width_start > 2) {
      return InvalidArgument("-o " + pattern + ": " + Whose(kind) +
                             " output is a pattern with one %d or %0Nd (N < 100)" + video +
                             "; write %% for a literal %");
    }
    const int width = j > width_start ? std::stoi(pattern.substr(width_start, j - width_start)) : 0;
    std::string num = std::to_string(frame);
    if (static_cast<int>(num.size()) < width) num.insert(0, width - num.size(), zero ? '0' : ' ');
    out += num;
    ++conversions;
    i = j;
  }
  if (conversions != 1) {
    return InvalidArgument(
        "-o " + pattern + ": " + Whose(kind) +
        " frames are one file each: give a pattern with one %d or %04d (e.g. frames/relit_%04d.png)" + video);
  }
  return out;
}

Status CheckRelitImageFinite(const std::vector<float>& image, uint64_t width, const std::string& env) {
  // A vectorised pass for the usual answer; the first bad value looked for only when there is one.
  bool bad = false;
  const float* px = image.data();
  const uint64_t n = image.size();
#pragma omp simd reduction(| : bad)
  for (uint64_t i = 0; i < n; ++i) bad |= !std::isfinite(px[i]);
  if (!bad) return Status::Ok();
  for (uint64_t i = 0; i < image.size(); ++i) {
    if (std::isfinite(image[i])) continue;
    const uint64_t row = i / 3;
    const std::string where = width > 0
                                  ? "pixel (" + std::to_string(row % width) + ", " + std::to_string(row / width) + ")"
                                  : "row " + std::to_string(row);
    return InvalidArgument("relight: the relit image's " + where + " channel " + "RGB"[i % 3] + " is " +
                           MessageNumber(image[i]) + ", beyond float32's largest value (3.40282347e+38): " + env +
                           " is too bright to relight in float32; scale the map down (e.g. by 2^-64) and the image "
                           "up after");
  }
  return Status::Ok();
}

}  // namespace ltb::stages
