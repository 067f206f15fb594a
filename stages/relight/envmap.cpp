#include "stages/relight/envmap.h"

#include <OpenEXR/ImfChannelList.h>
#include <OpenEXR/ImfFrameBuffer.h>
#include <OpenEXR/ImfHeader.h>
#include <OpenEXR/ImfInputFile.h>
#include <OpenEXR/ImfRgbaFile.h>
#include <sys/mman.h>

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <exception>
#include <glm/geometric.hpp>
#include <limits>
#include <memory>
#include <numbers>

#include "format/io/atomic_file.h"
#include "format/io/file.h"
#include "format/npy.h"
#include "stages/common/cubemap.h"

namespace ltb::stages {

namespace {

constexpr double kPi = std::numbers::pi;
// Largest image ltbake loads (pixels): 2^28 ≈ 16384 × 16384, 3 GiB of floats.
constexpr uint64_t kMaxPixels = 1ull << 28;
// Largest cubemap the resampler builds (its tables grow as R²: ~50 M intervals at 512).
constexpr uint64_t kMaxCubeRes = 512;
constexpr const char* kFaceNames[6] = {"px", "nx", "py", "ny", "pz", "nz"};
constexpr const char* kPlaceholder = "{face}";

std::string Num(double v) {
  char buf[48];
  std::snprintf(buf, sizeof buf, "%.9g", v);
  return buf;
}
std::string Size(uint64_t w, uint64_t h) { return std::to_string(w) + "x" + std::to_string(h); }

bool EndsWithNoCase(const std::string& s, const std::string& suffix) {
  if (s.size() < suffix.size()) return false;
  for (size_t i = 0; i < suffix.size(); ++i) {
    if (std::tolower(static_cast<unsigned char>(s[s.size() - suffix.size() + i])) != suffix[i]) return false;
  }
  return true;
}

// cos a − cos b without cancellation for nearby angles.
double CosDiff(double a, double b) { return 2.0 * std::sin(0.5 * (a + b)) * std::sin(0.5 * (b - a)); }

// ---- image files --------------------------------------------------------------------

struct Image {
  uint64_t width = 0, height = 0;
  PixelBuffer rgb;
  const char* channel[3] = {"R", "G", "B"};  // for messages ("Y" for luminance files)
  bool lossy = false;                        // lossy EXR compression (DWAA, DWAB, B44, B44A)
  std::string compression;
};

// The densest Radiance .hdr accepted: pixels per byte of pixel data (ReadHdr).
constexpr uint64_t kMaxHdrPixelsPerByte = 256;

// Rows decoded between two polls of the cancel hook.
constexpr uint64_t kRowsPerPoll = 64;

std::string MiB(uint64_t bytes) {
  char buf[48];
  std::snprintf(buf, sizeof buf, "%.1f MiB", double(bytes) / (1 << 20));
  return buf;
}

// The same for sizes computed in double from a hostile header, which may pass 2^64 (a
// conversion to uint64_t would be undefined: exr_fuzzer run 7).
std::string MiB(double bytes) {
  char buf[48];
  std::snprintf(buf, sizeof buf, "%.1f MiB", bytes / (1 << 20));
  return buf;
}

// A count held in a double, in full while exact (below 2^53), else in %.4g.
std::string Count(double v) {
  if (v < 9007199254740992.0) return std::to_string(uint64_t(v));
  char buf[48];
  std::snprintf(buf, sizeof buf, "%.4g", v);
  return buf;
}

// `count` floats of pixels (rgb.resize), or a status naming the image. Call only after the
// sizes were checked against the cap, the file and the memory limit; never throws.
Status AllocatePixels(PixelBuffer* rgb, uint64_t count, const std::string& path, const std::string& what) {
  try {
    rgb->resize(count);
  } catch (const std::exception&) {  // bad_alloc, length_error
    return InvalidArgument(path + ": no memory for the " + what + " (" + MiB(count * sizeof(float)) +
                           "); free memory or use a smaller map");
  }
  return Status::Ok();
}

// Refuses an image whose pixels (and other buffers, `extra` bytes) would pass the memory
// limit, before anything of that size is allocated.
Status CheckMemory(uint64_t pixels, uint64_t extra, uint64_t max_bytes, const std::string& path,
                   const std::string& what) {
  if (max_bytes == 0) return Status::Ok();
  uint64_t need = 0;
  if (format::MulOverflows(pixels, 3 * sizeof(float), &need) || format::AddOverflows(need, extra, &need) ||
      need > max_bytes) {
    return InvalidArgument(path + ": " + what + " needs " + MiB(need) + " of memory, beyond the memory limit of " +
                           MiB(max_bytes) + " (--mem-limit); raise --mem-limit or use a smaller map");
  }
  return Status::Ok();
}

Result<std::vector<uint8_t>> ReadWholeFile(const std::string& path, uint64_t max_bytes) {
  LTB_ASSIGN_OR_RETURN(io::File f, io::File::Open(path, io::File::Mode::kRead));
  LTB_ASSIGN_OR_RETURN(uint64_t size, f.Size());
  if (size > (uint64_t(4) << 30)) {
    return InvalidArgument(path + ": " + std::to_string(size) +
                           " bytes; environment maps over 4 GiB are not supported");
  }
  if (max_bytes != 0 && size > max_bytes) {
    return InvalidArgument(path + ": the file is " + MiB(size) + ", beyond the memory limit of " + MiB(max_bytes) +
                           " (--mem-limit); raise --mem-limit");
  }
  std::vector<uint8_t> bytes;
  try {
    bytes.resize(size);
  } catch (const std::exception&) {
    return InvalidArgument(path + ": no memory to read its " + std::to_string(size) + " bytes");
  }
  LTB_RETURN_IF_ERROR(f.ReadAt(0, format::MutableByteSpan(reinterpret_cast<std::byte*>(bytes.data()), size)));
  return bytes;
}

// A decimal dimension of a Radiance resolution line: digits only, 1..2^63.
bool ParseDimension(const std::string& token, uint64_t* out) {
  if (token.empty() || token.size() > 19) return false;
  uint64_t v = 0;
  for (char c : token) {
    if (c < '0' || c > '9') return false;
    v = v * 10 + uint64_t(c - '0');  // 19 digits cannot overflow 64 bits
  }
  *out = v;
  return v > 0;
}

// Radiance RGBE (.hdr): header lines up to a blank line, a resolution line, then scanlines
// either run-length encoded per component (the "new" format, widths 8..32767) or flat RGBE
// with the original (1,1,1,n) repeat records. RGBE -> float as in Greg Ward's rgbe.c and
// stb_image: mantissa · 2^(e − 136), 0 when e = 0.
Result<Image> ReadHdr(const std::string& path, const std::vector<uint8_t>& buf, const EnvLoadOptions& o) {
  const uint64_t size = buf.size();
  uint64_t pos = 0;
  auto next_line = [&](std::string* line) {
    if (pos >= size) return false;
    uint64_t end = pos;
    while (end < size && buf[end] != '\n') ++end;
    if (end >= size) return false;  // a header line always ends with '\n'
    line->assign(reinterpret_cast<const char*>(buf.data()) + pos, end - pos);
    if (!line->empty() && line->back() == '\r') line->pop_back();
    pos = end + 1;
    return true;
  };
  std::string line;
  if (size < 2 || buf[0] != '#' || buf[1] != '?' || !next_line(&line)) {
    return InvalidArgument(path + ": not a Radiance .hdr file (no \"#?\" signature line)");
  }
  bool blank = false;
  while (pos < (1u << 16) && next_line(&line)) {
    if (line.empty()) {
      blank = true;
      break;
    }
    if (line.rfind("FORMAT=", 0) == 0) {
      std::string fmt = line.substr(7);
      while (!fmt.empty() && std::isspace(static_cast<unsigned char>(fmt.back()))) fmt.pop_back();
      if (fmt != "32-bit_rle_rgbe") {
        return Unimplemented(path + ": Radiance pixel format \"" + fmt +
                             "\" is not supported; ltbake reads 32-bit_rle_rgbe (convert XYZE maps to RGB first)");
      }
    }
  }
  if (!blank) {
    return DataLoss(path + ": Radiance .hdr header does not end with a blank line within " +
                    std::to_string(std::min<uint64_t>(pos, 1u << 16)) + " bytes (truncated or not an .hdr file)");
  }
  if (!next_line(&line)) return DataLoss(path + ": Radiance .hdr: truncated before the resolution line");
  std::string shown = line.substr(0, 80);
  for (char& c : shown) {
    if (static_cast<unsigned char>(c) < 0x20 || static_cast<unsigned char>(c) >= 0x7f) c = '?';
  }
  std::vector<std::string> tok;
  for (size_t i = 0; i < line.size();) {
    while (i < line.size() && (line[i] == ' ' || line[i] == '\t')) ++i;
    size_t j = i;
    while (j < line.size() && line[j] != ' ' && line[j] != '\t') ++j;
    if (j > i) tok.push_back(line.substr(i, j - i));
    i = j;
  }
  if (tok.size() != 4 || tok[0].size() != 2 || tok[2].size() != 2) {
    return DataLoss(path + ": Radiance .hdr: bad resolution line \"" + shown + "\" (expected e.g. \"-Y 512 +X 1024\")");
  }
  const std::string& ys = tok[0];
  const std::string& xs = tok[2];
  if ((ys != "-Y" && ys != "+Y") || (xs != "+X" && xs != "-X")) {
    return Unimplemented(path + ": Radiance .hdr orientation \"" + shown +
                         "\" is not supported; ltbake reads -Y H +X W and its flips (+Y, -X), not transposed images");
  }
  uint64_t w = 0, h = 0, pixels = 0;
  if (!ParseDimension(tok[1], &h) || !ParseDimension(tok[3], &w)) {
    return DataLoss(path + ": Radiance .hdr resolution line \"" + shown + "\": the " +
                    (ParseDimension(tok[1], &h) ? "width \"" + tok[3] : "height \"" + tok[1]) +
                    "\" is not a positive integer below 10^19");
  }
  if (format::MulOverflows(w, h, &pixels) || pixels > kMaxPixels) {
    return InvalidArgument(path + ": Radiance .hdr size " + Size(w, h) + " (resolution line \"" + shown +
                           "\") is beyond " + std::to_string(kMaxPixels) + " pixels (16384 x 16384)");
  }
  // Every scanline takes at least 4 bytes of the file (one flat pixel or a run-length header).
  const uint64_t data_bytes = size - pos;
  if (h > data_bytes / 4) {
    return DataLoss(path + ": Radiance .hdr declares " + std::to_string(h) + " scanlines (resolution line \"" + shown +
                    "\") but holds " + std::to_string(data_bytes) +
                    " bytes of pixel data, less than 4 per scanline (truncated, or the size is damaged)");
  }
  // Radiance's run-length encoding packs at most 127 values of one channel into 2 bytes, so
  // even a constant map holds about 16 pixels per byte of pixel data. The old-style repeat
  // records can in principle go further (a 4-byte record repeating 2^24 pixels), which lets
  // a few hundred bytes declare gigabytes of pixels: a size beyond kMaxHdrPixelsPerByte is
  // refused before anything of that size is allocated (fuzzer finding, hdr_fuzzer run 5).
  if (pixels / kMaxHdrPixelsPerByte > data_bytes) {
    return DataLoss(path + ": Radiance .hdr declares " + Size(w, h) + " = " + std::to_string(pixels) +
                    " pixels (resolution line \"" + shown + "\") in " + std::to_string(data_bytes) +
                    " bytes of pixel data, more than " + std::to_string(kMaxHdrPixelsPerByte) +
                    " pixels per byte: the size is damaged (if the map is real, save it again, or as .exr)");
  }
  LTB_RETURN_IF_ERROR(CheckMemory(pixels, size + w * 4, o.max_bytes, path, "the Radiance .hdr image " + Size(w, h)));
  const bool flip_y = ys == "+Y", flip_x = xs == "-X";
  Image img;
  img.width = w;
  img.height = h;
  LTB_RETURN_IF_ERROR(AllocatePixels(&img.rgb, pixels * 3, path, Size(w, h) + " image"));
  std::vector<uint8_t> scan;
  try {
    scan.resize(img.width * 4);
  } catch (const std::exception&) {
    return InvalidArgument(path + ": no memory for a scanline of " + std::to_string(w) + " pixels");
  }
  auto truncated = [&](uint64_t y) {
    return DataLoss(path + ": Radiance .hdr truncated: the pixel data ends in scanline " + std::to_string(y) + " of " +
                    std::to_string(h) + " (the file has " + std::to_string(size) + " bytes)");
  };
  auto bad = [&](uint64_t y, const std::string& what) {
    return DataLoss(path + ": Radiance .hdr scanline " + std::to_string(y) + " at byte " + std::to_string(pos) + ": " +
                    what + " (damaged file)");
  };
  for (uint64_t y = 0; y < img.height; ++y) {
    if (y % kRowsPerPoll == 0 && o.progress.Cancelled()) {
      return Cancelled(path + ": interrupted while decoding scanline " + std::to_string(y) + " of " +
                       std::to_string(h));
    }
    if (pos + 4 > size) return truncated(y);
    const uint8_t* b = &buf[pos];
    if (img.width >= 8 && img.width < 32768 && b[0] == 2 && b[1] == 2 && (b[2] & 0x80) == 0) {
      uint64_t n = (uint64_t(b[2]) << 8) | b[3];
      if (n != img.width) {
        return bad(y, "run-length header says " + std::to_string(n) + " pixels, the image is " +
                          std::to_string(img.width) + " wide");
      }
      pos += 4;
      for (int ch = 0; ch < 4; ++ch) {
        uint64_t x = 0;
        while (x < img.width) {
          if (pos >= size) return truncated(y);
          uint64_t count = buf[pos++];
          if (count > 128) {
            count -= 128;
            if (x + count > img.width) return bad(y, "a run of " + std::to_string(count) + " overflows the width");
            if (pos >= size) return truncated(y);
            uint8_t v = buf[pos++];
            for (uint64_t k = 0; k < count; ++k) scan[(x + k) * 4 + ch] = v;
          } else {
            if (count == 0 || x + count > img.width) {
              return bad(y, "a literal of " + std::to_string(count) + " bytes overflows the width");
            }
            if (pos + count > size) return truncated(y);
            for (uint64_t k = 0; k < count; ++k) scan[(x + k) * 4 + ch] = buf[pos + k];
            pos += count;
          }
          x += count;
        }
      }
    } else {
      uint64_t x = 0;
      int shift = 0;
      while (x < img.width) {
        if (pos + 4 > size) return truncated(y);
        const uint8_t* p = &buf[pos];
        pos += 4;
        if (p[0] == 1 && p[1] == 1 && p[2] == 1) {  // repeat the previous pixel
          if (x == 0 || shift > 24) return bad(y, "a repeat record without a pixel to repeat");
          uint64_t rep = uint64_t(p[3]) << shift;
          if (x + rep > img.width) return bad(y, "a repeat of " + std::to_string(rep) + " overflows the width");
          for (uint64_t k = 0; k < rep; ++k) std::memcpy(&scan[(x + k) * 4], &scan[(x - 1) * 4], 4);
          x += rep;
          shift += 8;
        } else {
          std::memcpy(&scan[x * 4], p, 4);
          ++x;
          shift = 0;
        }
      }
    }
    const uint64_t row = flip_y ? img.height - 1 - y : y;
    for (uint64_t x = 0; x < img.width; ++x) {
      const uint8_t* p = &scan[x * 4];
      float* o = &img.rgb[(row * img.width + (flip_x ? img.width - 1 - x : x)) * 3];
      if (p[3] == 0) {
        o[0] = o[1] = o[2] = 0.0f;
      } else {
        float f = std::ldexp(1.0f, int(p[3]) - 136);
        o[0] = p[0] * f;
        o[1] = p[1] * f;
        o[2] = p[2] * f;
      }
    }
  }
  return img;
}

// Where pixel (0, 0) lies for a frame buffer whose first element holds pixel (x0, y0), rows
// w pixels apart (OpenEXR addresses frame buffers by absolute pixel coordinates). Computed on
// integers, modulo 2^64: the address may lie far outside the buffer and is only ever used
// with the offsets of the pixels inside it.
template <typename T>
T* FrameOrigin(T* first, int64_t x0, int64_t y0, int64_t w) {
  const uint64_t offset = (uint64_t(y0) * uint64_t(w) + uint64_t(x0)) * sizeof(T);
  return reinterpret_cast<T*>(reinterpret_cast<uintptr_t>(first) - offset);
}

// OpenEXR through the library (every compression it knows, scanline or tiled, part 0):
// R, G, B (A ignored) as float; luminance-chroma (Y, RY, BY) through RgbaInputFile;
// luminance Y alone replicated to grey. Read in strips of rows: a damaged chunk fails at
// its strip, and the cancel hook is polled between strips.
Result<Image> ReadExr(const std::string& path, const EnvLoadOptions& o) {
  try {
    Imf::InputFile file(path.c_str());
    const Imf::Header& header = file.header();
    const Imath::Box2i dw = header.dataWindow();
    const int64_t w = int64_t(dw.max.x) - dw.min.x + 1, h = int64_t(dw.max.y) - dw.min.y + 1;
    uint64_t pixels = 0;
    const std::string window = "data window (" + std::to_string(dw.min.x) + ", " + std::to_string(dw.min.y) + ") - (" +
                               std::to_string(dw.max.x) + ", " + std::to_string(dw.max.y) + ")";
    if (w <= 0 || h <= 0 || format::MulOverflows(uint64_t(w), uint64_t(h), &pixels) || pixels > kMaxPixels) {
      return InvalidArgument(path + ": OpenEXR " + window + " is " + std::to_string(w) + "x" + std::to_string(h) +
                             ", empty or beyond " + std::to_string(kMaxPixels) + " pixels (16384 x 16384)");
    }
    // The chunk table (read and, when damaged, rebuilt from the chunks by OpenEXR) must cover
    // the whole window: a window patched larger than the data fails here, before the pixels
    // are allocated.
    if (!file.isComplete()) {
      return DataLoss(path + ": OpenEXR file is incomplete: its chunks do not cover the " + window + " (" + Size(w, h) +
                      "); the file is truncated or its data window is damaged");
    }
    Image img;
    img.width = w;
    img.height = h;
    switch (header.compression()) {
      case Imf::DWAA_COMPRESSION:
        img.compression = "DWAA";
        break;
      case Imf::DWAB_COMPRESSION:
        img.compression = "DWAB";
        break;
      case Imf::B44_COMPRESSION:
        img.compression = "B44";
        break;
      case Imf::B44A_COMPRESSION:
        img.compression = "B44A";
        break;
      default:
        break;
    }
    img.lossy = !img.compression.empty();
    const Imf::ChannelList& channels = header.channels();
    std::string names;
    for (auto it = channels.begin(); it != channels.end(); ++it) {
      names += (names.empty() ? "" : ", ") + std::string(it.name());
      if (it.channel().xSampling != 1 || it.channel().ySampling != 1) {
        const std::string n = it.name();
        if (n == "R" || n == "G" || n == "B" || n == "Y") {
          // Sub-sampled chroma (RY, BY) is fine: RgbaInputFile reconstructs it.
          return Unimplemented(path + ": OpenEXR channel " + n +
                               " is sub-sampled; ltbake reads full-resolution R, G, B or Y");
        }
      }
    }
    const bool rgb = channels.findChannel("R") && channels.findChannel("G") && channels.findChannel("B");
    const bool chroma = channels.findChannel("Y") && (channels.findChannel("RY") || channels.findChannel("BY"));
    const bool lum = channels.findChannel("Y") != nullptr;
    if (!rgb && !lum) {
      return InvalidArgument(path + ": OpenEXR file has channels " + (names.empty() ? "(none)" : names) +
                             "; an environment map needs R, G and B (A is ignored) or luminance Y");
    }
    // Strips: whole chunks (every compression's lines per chunk divides 256), ~4 MiB of floats.
    const uint64_t strip = std::max<uint64_t>(256, ((uint64_t(4) << 20) / (uint64_t(w) * 12)) / 256 * 256);
    const uint64_t strip_px = std::min<uint64_t>(strip, uint64_t(h)) * uint64_t(w);  // buffers: rows of one strip
    const uint64_t scratch = rgb ? 0 : chroma ? strip_px * sizeof(Imf::Rgba) : strip_px * sizeof(float);
    LTB_RETURN_IF_ERROR(CheckMemory(pixels, scratch, o.max_bytes, path, "the OpenEXR image " + Size(w, h)));
    LTB_RETURN_IF_ERROR(AllocatePixels(&img.rgb, pixels * 3, path, Size(w, h) + " image"));
    std::vector<Imf::Rgba> rgba;
    std::vector<float> lum_strip;
    std::unique_ptr<Imf::RgbaInputFile> rf;
    if (rgb) {
      Imf::FrameBuffer fb;
      const char* name[3] = {"R", "G", "B"};
      for (int c = 0; c < 3; ++c) {
        fb.insert(name[c],
                  Imf::Slice::Make(Imf::FLOAT, img.rgb.data() + c, dw, 3 * sizeof(float), 3 * sizeof(float) * w));
      }
      file.setFrameBuffer(fb);
    } else if (chroma) {
      rf = std::make_unique<Imf::RgbaInputFile>(path.c_str());
      rgba.resize(strip_px);
    } else {
      lum_strip.resize(strip_px);
      img.channel[0] = img.channel[1] = img.channel[2] = "Y";
    }
    for (int64_t y0 = dw.min.y; y0 <= dw.max.y; y0 += int64_t(strip)) {
      if (o.progress.Cancelled()) {
        return Cancelled(path + ": interrupted while reading row " + std::to_string(y0 - dw.min.y) + " of " +
                         std::to_string(h));
      }
      const int64_t y1 = std::min<int64_t>(dw.max.y, y0 + int64_t(strip) - 1);
      const uint64_t first = uint64_t(y0 - dw.min.y) * uint64_t(w), count = uint64_t(y1 - y0 + 1) * uint64_t(w);
      try {
        if (rgb) {
          file.readPixels(int(y0), int(y1));
        } else if (chroma) {
          // (0, 0) of the frame buffer is where pixel (min.x, y0) of the strip lands.
          rf->setFrameBuffer(FrameOrigin(rgba.data(), dw.min.x, y0, w), 1, size_t(w));
          rf->readPixels(int(y0), int(y1));
          for (uint64_t i = 0; i < count; ++i) {
            img.rgb[(first + i) * 3] = rgba[i].r;
            img.rgb[(first + i) * 3 + 1] = rgba[i].g;
            img.rgb[(first + i) * 3 + 2] = rgba[i].b;
          }
        } else {
          Imf::FrameBuffer fb;
          fb.insert("Y", Imf::Slice(Imf::FLOAT, reinterpret_cast<char*>(FrameOrigin(lum_strip.data(), dw.min.x, y0, w)),
                                    sizeof(float), sizeof(float) * size_t(w)));
          file.setFrameBuffer(fb);
          file.readPixels(int(y0), int(y1));
          for (uint64_t i = 0; i < count; ++i) {
            img.rgb[(first + i) * 3] = img.rgb[(first + i) * 3 + 1] = img.rgb[(first + i) * 3 + 2] = lum_strip[i];
          }
        }
      } catch (const std::exception& e) {
        return DataLoss(path + ": OpenEXR could not read rows " + std::to_string(y0 - dw.min.y) + ".." +
                        std::to_string(y1 - dw.min.y) + " of " + std::to_string(h) + " (" + window + "): " + e.what());
      }
    }
    return img;
  } catch (const std::exception& e) {
    return DataLoss(path + ": OpenEXR could not read it: " + e.what());
  }
}

// What CheckExrHeaderSizes reads of one part's header to foresee OpenEXR's allocations.
struct ExrLayout {
  bool has_window = false, has_channels = false, tiled = false;
  int32_t window[4] = {0, 0, 0, 0};  // xMin, yMin, xMax, yMax
  uint64_t bytes_per_pixel = 0;      // all channels
  bool chroma = false;               // luminance-chroma (RY or BY): read through RgbaInputFile
  int compression = 3;               // OpenEXR's default when the header names none: ZIP
  uint32_t tile_x = 0, tile_y = 0;
};

// Lines per chunk of each OpenEXR compression (NO, RLE, ZIPS, ZIP, PIZ, PXR24, B44, B44A,
// DWAA, DWAB); others are refused by OpenEXR itself.
uint64_t ExrLinesPerChunk(int compression) {
  static constexpr uint64_t kLines[] = {1, 1, 1, 16, 32, 16, 32, 32, 32, 256};
  return compression >= 0 && compression < 10 ? kLines[compression] : 1;
}

// The most one block of lines (or one tile) may take in OpenEXR, with its compressor's
// buffers, whatever the memory limit: a 16384-wide map of four float channels in DWAB
// chunks of 256 lines needs 64 MiB per block.
constexpr uint64_t kMaxExrBlockBytes = uint64_t(512) << 20;

Status CheckExrLayout(const std::string& path, int part, const ExrLayout& l, uint64_t size, uint64_t max_bytes) {
  if (!l.has_window || !l.has_channels) return Status::Ok();  // OpenEXR refuses the header itself
  const int64_t w = int64_t(l.window[2]) - l.window[0] + 1, h = int64_t(l.window[3]) - l.window[1] + 1;
  if (w <= 0 || h <= 0) return Status::Ok();  // refused with the window's values by ReadExr
  const std::string where = path + ": OpenEXR part " + std::to_string(part) + " (data window " + std::to_string(w) +
                            "x" + std::to_string(h) + ", ";
  // Chunks, each with an 8-byte entry in the offset table that follows the header(s).
  double chunks = 0, block = 0;
  if (l.tiled) {
    if (l.tile_x == 0 || l.tile_y == 0) return Status::Ok();  // refused by OpenEXR
    chunks = std::ceil(double(w) / l.tile_x) * std::ceil(double(h) / l.tile_y);
    block = double(l.tile_x) * l.tile_y * double(l.bytes_per_pixel);
  } else {
    const uint64_t lines = ExrLinesPerChunk(l.compression);
    chunks = std::ceil(double(h) / double(lines));
    block = double(w) * double(l.bytes_per_pixel) * double(lines);  // allocated whole, even for fewer rows
  }
  if (chunks * 8 > double(size)) {
    return DataLoss(where + Count(chunks) + " chunks): its chunk offset table alone needs " + Count(chunks * 8) +
                    " bytes, more than the file's " + std::to_string(size) +
                    " (the data window is damaged or the file is truncated)");
  }
  // A block of lines or a tile, and the compressor's input and output buffers of that size.
  // RgbaInputFile, which reads luminance-chroma files, also keeps about 32 lines of Rgba
  // (8 bytes a pixel) of the window's width to filter the chroma (exr_fuzzer run 6: 539
  // bytes declaring a 5.8M-wide window made it allocate 1.49 GB, 256 bytes per column).
  const double need = std::max(3 * block, l.chroma ? 256.0 * double(w) : 0.0);
  const uint64_t cap = max_bytes ? std::min(max_bytes, kMaxExrBlockBytes) : kMaxExrBlockBytes;
  if (need > double(cap)) {
    const std::string unit = need > 3 * block ? "row of luminance-chroma pixels (about 32 lines of RGBA)"
                             : l.tiled        ? "tile of " + std::to_string(l.tile_x) + "x" + std::to_string(l.tile_y)
                                       : "block of " + std::to_string(ExrLinesPerChunk(l.compression)) + " lines";
    return InvalidArgument(where + std::to_string(l.bytes_per_pixel) + " bytes per pixel): OpenEXR would need " +
                           MiB(need) + " to decode one " + unit + ", beyond " +
                           (cap == max_bytes ? "the memory limit of " + MiB(cap) + " (--mem-limit)"
                                             : "the " + MiB(cap) + " ltbake allows for one block") +
                           " (the data window is damaged, or save the map with fewer lines per chunk)");
  }
  return Status::Ok();
}

// OpenEXR allocates each header attribute's declared size before reading it (a 15-byte
// file declaring a 2 GB attribute: found by exr_fuzzer). Walks the header(s) first, as
// the OpenEXR file layout describes them: after the magic and the version field, each
// attribute is a name and a type name (NUL-terminated), an int32 size and that many bytes;
// an empty name ends a header (a multi-part file has several, then one more empty name).
// Every size must fit in the bytes left in the file.
//
// OpenEXR also allocates, as it opens a part, its chunk offset table (8 bytes per chunk)
// and a block of lines (or one tile) with its compressor's buffers, sized from the data
// window, channels and compression alone: a 200-byte file declaring a window 1.5 million
// pixels wide made it allocate 1.5 GB (exr_fuzzer run 5). So each header's dataWindow,
// channels, compression and tiles are read here too, and a part is refused when its offset
// table cannot fit in the file or one block of it would pass max_bytes (or kMaxExrBlockBytes).
Status CheckExrHeaderSizes(const std::string& path, io::File& f, uint64_t size, uint64_t max_bytes) {
  const uint64_t cap = std::min<uint64_t>(size, uint64_t(64) << 20);  // headers are small
  std::vector<uint8_t> b(cap);
  LTB_RETURN_IF_ERROR(f.ReadAt(0, format::MutableByteSpan(reinterpret_cast<std::byte*>(b.data()), cap)));
  if (cap < 8)
    return DataLoss(path + ": OpenEXR file ends inside its version field (" + std::to_string(size) + " bytes)");
  const uint32_t version = uint32_t(b[4]) | uint32_t(b[5]) << 8 | uint32_t(b[6]) << 16 | uint32_t(b[7]) << 24;
  const bool multipart = (version & 0x1000u) != 0;
  const size_t max_name = (version & 0x400u) ? 255 : 31;
  uint64_t pos = 8;
  auto read_name = [&](std::string* name) -> Status {
    uint64_t end = pos;
    while (end < cap && b[end] != 0) ++end;
    if (end >= cap) return DataLoss(path + ": OpenEXR header ends inside a name at byte " + std::to_string(pos));
    if (end - pos > max_name) {
      return DataLoss(path + ": OpenEXR header name at byte " + std::to_string(pos) + " is " +
                      std::to_string(end - pos) + " bytes long (at most " + std::to_string(max_name) + ")");
    }
    name->assign(reinterpret_cast<const char*>(b.data()) + pos, end - pos);
    pos = end + 1;
    return Status::Ok();
  };
  auto i32 = [&](uint64_t at) {
    return int32_t(uint32_t(b[at]) | uint32_t(b[at + 1]) << 8 | uint32_t(b[at + 2]) << 16 | uint32_t(b[at + 3]) << 24);
  };
  for (int part = 0;; ++part) {
    std::string name, type;
    bool any = false;
    ExrLayout layout;
    for (;;) {
      LTB_RETURN_IF_ERROR(read_name(&name));
      if (name.empty()) {
        if (any) LTB_RETURN_IF_ERROR(CheckExrLayout(path, part, layout, size, max_bytes));
        break;
      }
      any = true;
      LTB_RETURN_IF_ERROR(read_name(&type));
      if (pos + 4 > cap) return DataLoss(path + ": OpenEXR header ends inside the size of attribute \"" + name + "\"");
      const int32_t n = int32_t(uint32_t(b[pos]) | uint32_t(b[pos + 1]) << 8 | uint32_t(b[pos + 2]) << 16 |
                                uint32_t(b[pos + 3]) << 24);
      pos += 4;
      if (n < 0 || uint64_t(n) > size - pos) {
        return DataLoss(path + ": OpenEXR header attribute \"" + name + "\" (type \"" + type + "\") at byte " +
                        std::to_string(pos - 4) + " declares " + std::to_string(n) + " bytes, but " +
                        std::to_string(size - pos) + " follow in the file (damaged or not an OpenEXR file)");
      }
      // OpenEXR reads the types it knows by their own layout, not by the size field: a size
      // that disagrees would make its reading and this walk part ways (exr_fuzzer).
      static const std::pair<const char*, int32_t> kFixed[] = {{"box2i", 16},
                                                               {"box2f", 16},
                                                               {"int", 4},
                                                               {"float", 4},
                                                               {"double", 8},
                                                               {"v2i", 8},
                                                               {"v2f", 8},
                                                               {"v3i", 12},
                                                               {"v3f", 12},
                                                               {"compression", 1},
                                                               {"lineOrder", 1},
                                                               {"envmap", 1},
                                                               {"rational", 8},
                                                               {"timecode", 8},
                                                               {"keycode", 28},
                                                               {"tiledesc", 9},
                                                               {"m33f", 36},
                                                               {"m44f", 64},
                                                               {"chromaticities", 32},
                                                               {"deepImageState", 1}};
      for (const auto& [t, want] : kFixed) {
        if (type == t && n != want) {
          return DataLoss(path + ": OpenEXR header attribute \"" + name + "\" of type " + type + " at byte " +
                          std::to_string(pos - 4) + " declares " + std::to_string(n) + " bytes; that type has " +
                          std::to_string(want) + " (damaged file)");
        }
      }
      if (type == "chlist" && pos + uint64_t(n) <= cap) {
        // Channels: name NUL, int32 type, uint8 pLinear, 3 reserved, int32 x/y sampling; a NUL ends the list.
        uint64_t c = pos, end = pos + uint64_t(n), bytes_per_pixel = 0;
        bool ok = false, chroma = false;
        while (c < end) {
          if (b[c] == 0) {
            ok = c + 1 == end;
            break;
          }
          const uint64_t first = c;
          while (c < end && b[c] != 0) ++c;
          const std::string channel(reinterpret_cast<const char*>(b.data() + first), c - first);
          chroma = chroma || channel == "RY" || channel == "BY";
          if (c + 1 + 16 <= end) {
            const int32_t pixel_type = i32(c + 1);
            bytes_per_pixel += pixel_type == 1 ? 2 : 4;  // HALF; UINT, FLOAT (others: refused by OpenEXR)
          }
          c += 1 + 16;
        }
        if (name == "channels") {  // a repeated attribute replaces the earlier one, as in OpenEXR
          layout.has_channels = true;
          layout.bytes_per_pixel = bytes_per_pixel;
          layout.chroma = chroma;
        }
        if (!ok) {
          return DataLoss(path + ": OpenEXR channel list \"" + name + "\" at byte " + std::to_string(pos) +
                          " does not end where its size (" + std::to_string(n) + " bytes) says (damaged file)");
        }
      }
      if (pos + uint64_t(n) <= cap) {
        if (name == "dataWindow" && type == "box2i") {
          layout.has_window = true;
          for (int k = 0; k < 4; ++k) layout.window[k] = i32(pos + 4 * k);
        } else if (name == "compression" && type == "compression") {
          layout.compression = b[pos];
        } else if (name == "tiles" && type == "tiledesc") {
          layout.tiled = true;
          layout.tile_x = uint32_t(i32(pos));
          layout.tile_y = uint32_t(i32(pos + 4));
        }
      }
      pos += uint64_t(n);
      if (pos > cap) return Status::Ok();  // a header this large: left to OpenEXR, sizes so far are sane
    }
    if (!multipart || !any) return Status::Ok();
  }
}

Result<Image> ReadImage(const std::string& path, const EnvLoadOptions& o) {
  LTB_RETURN_IF_ERROR(io::RequireRegularFile(path, "name a .exr or .hdr image file"));
  {
    LTB_ASSIGN_OR_RETURN(io::File f, io::File::Open(path, io::File::Mode::kRead));
    LTB_ASSIGN_OR_RETURN(uint64_t size, f.Size());
    std::byte magic[4] = {};
    LTB_RETURN_IF_ERROR(f.ReadAt(0, format::MutableByteSpan(magic, std::min<uint64_t>(size, 4))));
    if (size >= 4 && magic[0] == std::byte{0x76} && magic[1] == std::byte{0x2f} && magic[2] == std::byte{0x31} &&
        magic[3] == std::byte{0x01}) {
      LTB_RETURN_IF_ERROR(CheckExrHeaderSizes(path, f, size, o.max_bytes));
      return ReadExr(path, o);
    }
    if (size < 2 || magic[0] != std::byte{'#'} || magic[1] != std::byte{'?'}) {
      std::string what = size == 0 ? "the file is empty" : "it has neither the OpenEXR magic (76 2f 31 01) nor \"#?\"";
      return InvalidArgument(path + ": not an OpenEXR (.exr) or Radiance (.hdr) image: " + what);
    }
  }
  LTB_ASSIGN_OR_RETURN(std::vector<uint8_t> bytes, ReadWholeFile(path, o.max_bytes));
  return ReadHdr(path, bytes, o);
}

// ---- layouts ------------------------------------------------------------------------

// Face (0..5) shown in cell (col, row) of a cross, -1 for an unused cell.
int CrossFace(EnvLayout layout, uint64_t col, uint64_t row) {
  if (layout == EnvLayout::kHCross) {  // 4 × 3: +Y / −X +Z +X −Z / −Y
    static const int kRow1[4] = {1, 4, 0, 5};
    if (row == 1) return kRow1[col];
    if (col == 1) return row == 0 ? 2 : 3;
    return -1;
  }
  if (layout == EnvLayout::kVCross) {  // 3 × 4: +Y / −X +Z +X / −Y / −Z
    static const int kRow1[3] = {1, 4, 0};
    if (row == 1) return kRow1[col];
    if (col == 1) return row == 0 ? 2 : row == 2 ? 3 : 5;
    return -1;
  }
  return 0;
}

// Angular (light-probe) maps, as Debevec distributes his probes: a square image whose
// inscribed disk holds every direction. With (u, v) in [-1, 1]² (u right, v up) and
// r = |(u, v)|, the direction at (u, v) lies at the angle π·r from the map's centre
// direction, towards the image direction (u, v); the disk's rim is the direction behind.
// The centre is the direction of a lat-long map's centre column (+X), up is +Z and right
// is the direction of increasing lat-long u at that centre (−Y), so a probe and its
// lat-long panorama converted centre to centre give the same cubemap (docs/ENVMAPS.md).
glm::dvec3 AngularDirection(double u, double v) {
  const double r = std::sqrt(u * u + v * v);
  const double s = r > 0 ? std::sin(kPi * r) / r : kPi;  // sin(πr)/r → π at the centre
  return {std::cos(kPi * r), -u * s, v * s};             // forward +X, right −Y, up +Z
}

// The pixel (x, y) of a W×W angular map holding direction d.
void DirectionToAngular(const glm::dvec3& d, uint64_t w, uint64_t* x, uint64_t* y) {
  const glm::dvec3 n = glm::normalize(d);
  const double pu = -n.y, pv = n.z, len = std::sqrt(pu * pu + pv * pv);
  const double r = std::acos(std::clamp(n.x, -1.0, 1.0)) / kPi;
  const double u = len > 0 ? pu / len * r : 0.0, v = len > 0 ? pv / len * r : 0.0;
  *x = std::min<uint64_t>(w - 1, uint64_t(std::max(0.0, (u + 1.0) * 0.5 * double(w))));
  *y = std::min<uint64_t>(w - 1, uint64_t(std::max(0.0, (1.0 - v) * 0.5 * double(w))));
}

// Whether pixel (x, y) of a W×W angular map touches the disk (the pixels the resampler
// reads; the values of the others are never used, so they are not checked).
bool InAngularDisk(uint64_t x, uint64_t y, uint64_t w) {
  auto nearest = [](double a, double b) { return a > 0 ? a : b < 0 ? b : 0.0; };  // of [a, b] to 0
  const double u = nearest(2.0 * double(x) / double(w) - 1.0, 2.0 * double(x + 1) / double(w) - 1.0);
  const double v = nearest(1.0 - 2.0 * double(y + 1) / double(w), 1.0 - 2.0 * double(y) / double(w));
  return u * u + v * v <= 1.0;
}

// Face size and the pixel origin of each face in a face layout.
struct FaceGeometry {
  uint64_t size = 0;
  uint64_t x0[6] = {}, y0[6] = {};
};

FaceGeometry FacesOf(const EnvMap& env) {
  FaceGeometry g;
  if (env.layout == EnvLayout::kFaces) {
    g.size = env.width;
    for (int f = 0; f < 6; ++f) g.y0[f] = f * g.size;
    return g;
  }
  const uint64_t cols = env.layout == EnvLayout::kHCross ? 4 : 3, rows = env.layout == EnvLayout::kHCross ? 3 : 4;
  g.size = env.width / cols;
  for (uint64_t r = 0; r < rows; ++r)
    for (uint64_t c = 0; c < cols; ++c) {
      int f = CrossFace(env.layout, c, r);
      if (f >= 0) {
        g.x0[f] = c * g.size;
        g.y0[f] = r * g.size;
      }
    }
  return g;
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
  EnvLayout layout = o.layout;
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

// ---- resampling ---------------------------------------------------------------------

namespace {

// Exact 1-D overlaps between a source grid of n_src equal cells and a target grid of n_dst
// equal cells over [0, 1]: for each target cell, (source cell, overlap [a, b]) with a and b
// as fractions. Integer arithmetic in units of 1/(n_src·n_dst), so aligned grids are exact.
struct Overlap {
  uint64_t src;
  double a, b;
};
std::vector<std::vector<Overlap>> Overlaps(uint64_t n_src, uint64_t n_dst) {
  std::vector<std::vector<Overlap>> out(n_dst);
  const double unit = 1.0 / (double(n_src) * double(n_dst));
  uint64_t i = 0;
  for (uint64_t j = 0; j < n_dst; ++j) {
    const uint64_t lo = j * n_src, hi = (j + 1) * n_src;
    while (i < n_src && (i + 1) * n_dst <= lo) ++i;
    for (uint64_t k = i; k < n_src && k * n_dst < hi; ++k) {
      const uint64_t a = std::max(lo, k * n_dst), b = std::min(hi, (k + 1) * n_dst);
      if (b > a) out[j].push_back({k, a * unit, b * unit});
    }
  }
  return out;
}

// A zeroed table of `count` doubles. Resample reads ~50·R² scattered places of it per frame:
// on 2 MB pages (transparent huge pages, where the kernel grants them) the TLB covers the
// whole table, about 20% faster per frame than 4 KB pages. Shared: copies of a resampler
// share the (immutable) table.
std::shared_ptr<double[]> AllocateTable(uint64_t count) {
  constexpr size_t kHuge = size_t(2) << 20;
  const size_t bytes = count * sizeof(double);
  const size_t align = bytes >= 2 * kHuge ? kHuge : 64;
  const size_t rounded = (bytes + align - 1) / align * align;
  void* p = std::aligned_alloc(align, rounded);
  if (p == nullptr) return nullptr;
#ifdef MADV_HUGEPAGE
  if (align == kHuge) madvise(p, rounded, MADV_HUGEPAGE);  // advice only: failure is harmless
#endif
  std::memset(p, 0, rounded);
  return std::shared_ptr<double[]>(static_cast<double*>(p), [](double* q) { std::free(q); });
}

// Largest divisor g of n with n / g >= target (1 when n < target).
uint64_t GroupFor(uint64_t n, uint64_t target) {
  for (uint64_t g = std::max<uint64_t>(1, n / std::max<uint64_t>(1, target)); g > 1; --g) {
    if (n % g == 0 && n / g >= target) return g;
  }
  return 1;
}

}  // namespace

namespace {

// Sub-samples of a source (cube-face texels, angular-map pixels) splatted into the working
// lat-long grid: each adds its radiance × solid angle to the working pixel holding its
// centre direction; Finish divides by the solid angle gathered, and gives a pixel no
// sub-sample reached (thin ones near the poles) the source at its centre direction.
struct WorkingSplat {
  uint64_t hw, ww;
  std::vector<double> ldw, dw;
  WorkingSplat(uint64_t rows, uint64_t cols) : hw(rows), ww(cols), ldw(rows * cols * 3, 0.0), dw(rows * cols, 0.0) {}
  void Add(const glm::dvec3& d, const float* L, double domega) {
    double lu, lv;
    DirectionToLatLong(d, &lu, &lv);
    const uint64_t I = std::min<uint64_t>(uint64_t(lu * ww), ww - 1);
    const uint64_t J = std::min<uint64_t>(uint64_t(lv * hw), hw - 1);
    dw[J * ww + I] += domega;
    for (int c = 0; c < 3; ++c) ldw[(J * ww + I) * 3 + c] += L[c] * domega;
  }
  // at(direction) -> const float*: the source pixel holding a direction.
  template <typename At>
  void Finish(std::vector<double>* work, At at) const {
    work->assign(hw * ww * 3, 0.0);
    for (uint64_t J = 0; J < hw; ++J)
      for (uint64_t I = 0; I < ww; ++I) {
        const uint64_t px = J * ww + I;
        if (dw[px] > 0) {
          for (int c = 0; c < 3; ++c) (*work)[px * 3 + c] = ldw[px * 3 + c] / dw[px];
        } else {
          const float* L = at(LatLongDirection((I + 0.5) / ww, (J + 0.5) / hw));
          for (int c = 0; c < 3; ++c) (*work)[px * 3 + c] = L[c];
        }
      }
  }
};

}  // namespace

Result<CubemapResampler> CubemapResampler::Create(const EnvMap& env, uint64_t cube_res, const Progress& progress) {
  // The tables are bounded by R (and the working grid by 2^22 pixels), but a row of the
  // source is held in double: a lat-long map of extreme width may not fit. No exception
  // leaves the library.
  try {
    return CreateUnchecked(env, cube_res, progress);
  } catch (const std::bad_alloc&) {
    return InvalidArgument(env.path + ": no memory to resample the " + Size(env.width, env.height) +
                           " map to an R = " + std::to_string(cube_res) + " cubemap");
  }
}

Result<CubemapResampler> CubemapResampler::CreateUnchecked(const EnvMap& env, uint64_t cube_res,
                                                           const Progress& progress) {
  if (cube_res < 1 || cube_res > kMaxCubeRes) {
    return InvalidArgument("cubemap resolution " + std::to_string(cube_res) + " is outside 1.." +
                           std::to_string(kMaxCubeRes));
  }
  if (env.width == 0 || env.height == 0 || env.rgb.size() != env.width * env.height * 3) {
    return InvalidArgument(env.path + ": environment map holds " + std::to_string(env.rgb.size()) +
                           " values, its size " + Size(env.width, env.height) + " needs 3 per pixel");
  }
  const uint64_t R = cube_res, n = 6 * R * R;
  // Polled every few rows of each pass (a huge source or R = 512 takes seconds).
  auto cancelled = [&](uint64_t i, const char* pass) -> Status {
    if (i % kRowsPerPoll != 0 || !progress.Cancelled()) return Status::Ok();
    return Cancelled(env.path + ": interrupted while resampling to the R = " + std::to_string(R) + " cubemap (" + pass +
                     ")");
  };
  CubemapResampler rs;
  rs.r_ = R;
  rs.omega_.resize(n);
  for (uint64_t t = 0; t < n; ++t) rs.omega_[t] = cubemap::TexelSolidAngle(cubemap::ColumnToTexel(t, R), uint32_t(R));

  // Working grid targets: 16R rows of 180°/16R (about a fifth of the smallest texel's side,
  // 0.94/R rad at the cube corners), 32R columns (as wide as rows are high at the equator);
  // both halved (with more bands per row) while the prefix tables would pass 2^22 pixels.
  uint64_t target_rows = 16 * R, target_cols = 32 * R, sub = 1;
  while (target_rows * target_cols > (1ull << 22) && target_rows > 1) {
    target_rows /= 2;
    target_cols /= 2;
    sub *= 2;
  }
  std::vector<double> work;  // hw × ww × 3 working values
  if (env.layout == EnvLayout::kLatLong) {
    const uint64_t W = env.width, H = env.height;
    // Rows: whole groups of source rows when that lands at or above the target (bands then
    // never split a source row), sub-bands of each source row when the source is coarser.
    if (H >= target_rows) {
      rs.hw_ = H / GroupFor(H, target_rows);
      if (rs.hw_ > 4 * target_rows) rs.hw_ = target_rows;  // no usable divisor: fractional rows
    } else {
      rs.hw_ = H;
      sub *= (target_rows + H - 1) / H;
    }
    if (W >= target_cols) {
      rs.ww_ = W / GroupFor(W, target_cols);
      if (rs.ww_ > 4 * target_cols) rs.ww_ = target_cols;
    } else {
      rs.ww_ = W;
    }
    for (uint64_t j = 0; j < H; ++j) {
      LTB_RETURN_IF_ERROR(cancelled(j, "source power"));
      double omega = CosDiff(kPi * j / H, kPi * (j + 1) / H) * 2.0 * kPi / W;
      double s[3] = {0, 0, 0};
      for (uint64_t i = 0; i < W; ++i)
        for (int c = 0; c < 3; ++c) s[c] += env.rgb[(j * W + i) * 3 + c];
      for (int c = 0; c < 3; ++c) rs.power_[c] += s[c] * omega;
    }
    // Separable exact area average: θ overlaps weigh by Δcos θ, φ overlaps by length.
    auto rows = Overlaps(H, rs.hw_), cols = Overlaps(W, rs.ww_);
    work.assign(rs.hw_ * rs.ww_ * 3, 0.0);
    std::vector<double> row(W * 3);
    for (uint64_t J = 0; J < rs.hw_; ++J) {
      LTB_RETURN_IF_ERROR(cancelled(J, "working grid"));
      std::fill(row.begin(), row.end(), 0.0);
      double wsum = 0;
      for (const Overlap& o : rows[J]) {
        const double wt = CosDiff(kPi * o.a, kPi * o.b);
        wsum += wt;
        const float* src = &env.rgb[o.src * W * 3];
        for (uint64_t k = 0; k < W * 3; ++k) row[k] += wt * src[k];
      }
      for (uint64_t I = 0; I < rs.ww_; ++I) {
        double s[3] = {0, 0, 0}, lsum = 0;
        for (const Overlap& o : cols[I]) {
          const double wt = o.b - o.a;
          lsum += wt;
          for (int c = 0; c < 3; ++c) s[c] += wt * row[o.src * 3 + c];
        }
        for (int c = 0; c < 3; ++c) work[(J * rs.ww_ + I) * 3 + c] = s[c] / (wsum * lsum);
      }
    }
  } else if (env.layout == EnvLayout::kHCross || env.layout == EnvLayout::kVCross || env.layout == EnvLayout::kFaces) {
    const FaceGeometry g = FacesOf(env);
    const uint64_t F = g.size;
    if (F == 0) return InvalidArgument(env.path + ": " + Size(env.width, env.height) + " holds no cube faces");
    rs.hw_ = target_rows;
    rs.ww_ = target_cols;
    auto source = [&](int f, uint64_t s, uint64_t t) {
      return &env.rgb[((g.y0[f] + t) * env.width + g.x0[f] + s) * 3];
    };
    for (int f = 0; f < 6; ++f)
      for (uint64_t t = 0; t < F; ++t) {
        LTB_RETURN_IF_ERROR(cancelled(t, "source power"));
        for (uint64_t s = 0; s < F; ++s) {
          const double omega = cubemap::TexelSolidAngle({f, uint32_t(s), uint32_t(t)}, uint32_t(F));
          for (int c = 0; c < 3; ++c) rs.power_[c] += source(f, s, t)[c] * omega;
        }
      }
    // Splat k×k sub-texels of each source texel (exact solid angles) into the working pixel
    // holding their centre; sub-texels about half a working row across at the face centre.
    uint64_t k = std::max<uint64_t>(1, uint64_t(std::ceil(4.0 * rs.hw_ / (kPi * F))));
    while (k > 1 && 6 * F * F * k * k > (1ull << 25)) --k;
    const uint64_t m = k * F;
    std::vector<double> corner((m + 1) * (m + 1));
    for (uint64_t q = 0; q <= m; ++q)
      for (uint64_t p = 0; p <= m; ++p) {
        const double x = -1.0 + 2.0 * p / m, y = -1.0 + 2.0 * q / m;
        corner[q * (m + 1) + p] = std::atan2(x * y, std::sqrt(x * x + y * y + 1.0));
      }
    WorkingSplat splat(rs.hw_, rs.ww_);
    for (int f = 0; f < 6; ++f)
      for (uint64_t q = 0; q < m; ++q) {
        LTB_RETURN_IF_ERROR(cancelled(q, "working grid"));
        const double v = -1.0 + 2.0 * (q + 0.5) / m;
        for (uint64_t p = 0; p < m; ++p) {
          const double u = -1.0 + 2.0 * (p + 0.5) / m;
          const double domega = corner[(q + 1) * (m + 1) + p + 1] - corner[(q + 1) * (m + 1) + p] -
                                corner[q * (m + 1) + p + 1] + corner[q * (m + 1) + p];
          splat.Add(cubemap::FaceDirection(f, u, v), source(f, p / k, q / k), domega);
        }
      }
    splat.Finish(&work, [&](const glm::dvec3& d) {
      const cubemap::Texel x = cubemap::DirectionToTexel(d, uint32_t(F));
      return source(x.face, x.s, x.t);
    });
  } else if (env.layout == EnvLayout::kAngular) {
    // As for cube faces: k×k sub-pixels of each source pixel splatted into the working pixel
    // holding their centre direction, each weighing its solid angle π·sin(πr)/r·du·dv (the
    // map is equi-angular in r: dω = sin θ dθ dφ with θ = πr). Sub-pixels about half a
    // working row across (a pixel spans 2π/W in θ).
    const uint64_t W = env.width;
    rs.hw_ = target_rows;
    rs.ww_ = target_cols;
    uint64_t k = std::max<uint64_t>(1, uint64_t(std::ceil(4.0 * double(rs.hw_) / double(W))));
    while (k > 1 && W * W * k * k > (1ull << 25)) --k;
    const double du = 2.0 / double(W * k);
    WorkingSplat splat(rs.hw_, rs.ww_);
    for (uint64_t y = 0; y < W * k; ++y) {
      LTB_RETURN_IF_ERROR(cancelled(y, "working grid"));
      const double v = 1.0 - (double(y) + 0.5) * du;
      for (uint64_t x = 0; x < W * k; ++x) {
        const double u = -1.0 + (double(x) + 0.5) * du;
        const double r = std::sqrt(u * u + v * v);
        if (r > 1.0) continue;
        const double domega = (r > 0 ? kPi * std::sin(kPi * r) / r : kPi * kPi) * du * du;
        const float* L = &env.rgb[((y / k) * W + x / k) * 3];
        splat.Add(AngularDirection(u, v), L, domega);
        for (int c = 0; c < 3; ++c) rs.power_[c] += L[c] * domega;
      }
    }
    splat.Finish(&work, [&](const glm::dvec3& d) {
      uint64_t x, y;
      DirectionToAngular(d, W, &x, &y);
      return &env.rgb[(y * W + x) * 3];
    });
  } else {
    return InvalidArgument(env.path + ": environment map layout is unresolved (auto)");
  }

  // Prefix sums per working row (radiance × working columns).
  const uint64_t ww = rs.ww_, hw = rs.hw_;
  std::shared_ptr<double[]> table = AllocateTable(hw * (ww + 1) * 3 + 1);  // + 1: the last 4-lane load
  if (table == nullptr) {
    return InvalidArgument(env.path + ": no memory for the " + std::to_string(hw) + " x " + std::to_string(ww) +
                           " working grid");
  }
  for (uint64_t J = 0; J < hw; ++J) {
    double* P = table.get() + J * (ww + 1) * 3;
    for (uint64_t I = 0; I < ww; ++I)
      for (int c = 0; c < 3; ++c) P[(I + 1) * 3 + c] = P[I * 3 + c] + work[(J * ww + I) * 3 + c];
  }
  rs.prefix_ = std::move(table);
  work = {};

  // Bands: `sub` per working row. In each, the column intervals where the circle of the
  // band's mean z (its area centroid) crosses each texel: sampled every 1/64 of a face
  // width, each change of texel located by bisection to 1e-11 of the circle.
  const uint64_t samples = 64 * R;
  const double eps = 1e-11 * ww;
  std::vector<double> dsum(n, 0.0);
  std::vector<std::pair<double, uint32_t>> marks;
  for (uint64_t J = 0; J < hw; ++J) {
    LTB_RETURN_IF_ERROR(cancelled(J, "latitude bands"));
    for (uint64_t q = 0; q < sub; ++q) {
      const double ta = kPi * double(J * sub + q) / double(hw * sub),
                   tb = kPi * double(J * sub + q + 1) / double(hw * sub);
      Band band;
      band.row = uint32_t(J);
      band.weight = CosDiff(ta, tb) * 2.0 * kPi / ww;
      const double z = 0.5 * (std::cos(ta) + std::cos(tb)), rho = std::sqrt(std::max(0.0, 1.0 - z * z));
      auto texel_at = [&](double col) {
        const double phi = kPi - 2.0 * kPi * col / ww;
        return uint32_t(cubemap::Column(
            cubemap::DirectionToTexel({rho * std::cos(phi), rho * std::sin(phi), z}, uint32_t(R)), uint32_t(R)));
      };
      marks.clear();
      // Bisects (lo, hi) where the texel changes from tlo to thi; a third texel in between
      // splits the search.
      auto bisect = [&](auto&& self, double lo, uint32_t tlo, double hi, uint32_t thi) -> void {
        while (hi - lo > eps) {
          const double mid = 0.5 * (lo + hi);
          const uint32_t tm = texel_at(mid);
          if (tm == tlo) {
            lo = mid;
          } else if (tm == thi) {
            hi = mid;
          } else {
            self(self, lo, tlo, mid, tm);
            lo = mid;
            tlo = tm;
          }
        }
        marks.push_back({0.5 * (lo + hi), thi});
      };
      const uint32_t t0 = texel_at(0.0);
      uint32_t prev = t0;
      for (uint64_t s = 1; s <= samples; ++s) {
        const double c = s == samples ? double(ww) : double(ww) * s / samples;
        const uint32_t t = s == samples ? t0 : texel_at(c);
        if (t != prev) bisect(bisect, double(ww) * (s - 1) / samples, prev, c, t);
        prev = t;
      }
      band.first_run = rs.run_start_.size();
      if (marks.empty()) marks.push_back({0.0, t0});
      band.run_count = marks.size();
      for (size_t i = 0; i < marks.size(); ++i) {
        rs.run_start_.push_back(marks[i].first);
        rs.run_texel_.push_back(marks[i].second);
        const double end = i + 1 < marks.size() ? marks[i + 1].first : marks[0].first + ww;
        dsum[marks[i].second] += band.weight * (end - marks[i].first);
      }
      rs.bands_.push_back(band);
    }
  }
  rs.texel_scale_.resize(n);
  for (uint64_t t = 0; t < n; ++t) {
    if (dsum[t] > 0) {
      rs.texel_scale_[t] = 1.0 / dsum[t];
      continue;
    }
    rs.texel_scale_[t] = 1.0;
    double u, v;
    DirectionToLatLong(cubemap::TexelCenter(cubemap::ColumnToTexel(t, R), uint32_t(R)), &u, &v);
    rs.empty_.push_back({t, uint32_t(std::min<uint64_t>(uint64_t(v * hw), hw - 1)), u * ww});
  }
  return rs;
}

namespace {
// R, G, B and an unused lane: one AVX register, or two SSE2 ones. Passed by pointer only
// (a by-value 32-byte vector changes the ABI between AVX and non-AVX builds).
using Vec4 = double __attribute__((vector_size(32)));
inline void Load(const double* p, Vec4* v) { std::memcpy(v, p, sizeof *v); }
}  // namespace

void CubemapResampler::Resample(double rotation, float* out) const {
  const uint64_t n = 6 * r_ * r_, ww = ww_;
  const double wwd = double(ww);
  thread_local std::vector<Vec4> acc;
  acc.assign(n, Vec4{0, 0, 0, 0});
  // The rotated map at working column c is the source at c + shift (docs/ENVMAPS.md).
  double turns = rotation / (2.0 * kPi);
  turns -= std::floor(turns);
  double shift = turns * wwd;
  if (!(shift >= 0.0 && shift < wwd)) shift = 0.0;
  const size_t stride = (ww + 1) * 3;
  for (const Band& b : bands_) {
    const double* P = prefix_.get() + b.row * stride;
    Vec4 total;
    Load(P + ww * 3, &total);
    const double* start = &run_start_[b.first_run];
    const uint32_t* texel = &run_texel_[b.first_run];
    const uint64_t count = b.run_count;
    // ∫_0^x of the row at x = start[k] + shift, extended periodically: the starts that pass
    // ww wrap (and gain one row total). Lane 3 is the next column's R: ignored.
    auto eval = [&](double x, const Vec4& wrap, Vec4* q) {
      const int64_t i = std::min<int64_t>(int64_t(x), int64_t(ww) - 1);
      const double f = x - double(i);
      Vec4 p0, p1;
      Load(P + 3 * i, &p0);
      Load(P + 3 * i + 3, &p1);
      *q = p0 + f * (p1 - p0) + wrap;
    };
    const Vec4 zero = {0, 0, 0, 0};
    Vec4 first, prev, next;
    if (start[0] + shift >= wwd) {
      eval(start[0] + shift - wwd, total, &first);
    } else {
      eval(start[0] + shift, zero, &first);
    }
    prev = first;
    uint64_t k = 0;
    for (; k + 1 < count && start[k + 1] + shift < wwd; ++k) {
      eval(start[k + 1] + shift, zero, &next);
      acc[texel[k]] += b.weight * (next - prev);
      prev = next;
    }
    for (; k + 1 < count; ++k) {
      eval(start[k + 1] + shift - wwd, total, &next);
      acc[texel[k]] += b.weight * (next - prev);
      prev = next;
    }
    acc[texel[count - 1]] += b.weight * (first + total - prev);
  }
  for (const EmptyTexel& e : empty_) {
    double x = e.column + shift;
    if (x >= wwd) x -= wwd;
    const uint64_t i = std::min<uint64_t>(uint64_t(x), ww - 1);
    const double* p = prefix_.get() + e.row * stride + i * 3;
    Vec4 p0, p1;
    Load(p, &p0);
    Load(p + 3, &p1);
    acc[e.texel] = p1 - p0;
  }
  // Texel radiance = Σ L dΩ / Σ dΩ, then one factor per channel so that Σ texel·Ω_texel
  // equals the source's power.
  Vec4 sum = {0, 0, 0, 0};
  for (uint64_t t = 0; t < n; ++t) sum += acc[t] * (texel_scale_[t] * omega_[t]);
  double g[3];
  for (int c = 0; c < 3; ++c) g[c] = sum[c] > 0 ? power_[c] / sum[c] : 1.0;
  for (uint64_t t = 0; t < n; ++t)
    for (int c = 0; c < 3; ++c) out[t * 3 + c] = float(acc[t][c] * texel_scale_[t] * g[c]);
}

Status ConvertEnvToNpy(const std::string& in, const std::string& out, uint64_t cube_res, const EnvLoadOptions& options,
                       uint64_t* clamped) {
  if (cube_res == 0) {
    return InvalidArgument("convert " + in + ": an environment map needs --cube-res R (the cubemap's face size)");
  }
  if ((cube_res & (cube_res - 1)) != 0 || cube_res > kMaxCubeRes) {
    return InvalidArgument("--cube-res " + std::to_string(cube_res) + " is not a power of two up to " +
                           std::to_string(kMaxCubeRes));
  }
  if (!EndsWithNoCase(out, ".npy")) {
    return InvalidArgument("convert " + in + " " + out + ": an environment map converts to a .npy cubemap");
  }
  LTB_ASSIGN_OR_RETURN(EnvMap env, LoadEnvMap(in, options));
  if (clamped != nullptr) *clamped = env.clamped;
  LTB_ASSIGN_OR_RETURN(CubemapResampler rs, CubemapResampler::Create(env, cube_res, options.progress));
  const uint64_t texels = 6 * cube_res * cube_res;
  std::vector<float> cube(texels * 3);
  rs.Resample(0.0, cube.data());
  std::vector<std::byte> header = format::EncodeNpyHeader("<f4", {texels, 3});
  // Written beside the output and renamed: OUT never holds a partial cubemap.
  LTB_ASSIGN_OR_RETURN(io::AtomicFile f, io::AtomicFile::Create(out));
  LTB_RETURN_IF_ERROR(f.file().WriteAt(0, header));
  LTB_RETURN_IF_ERROR(f.file().WriteAt(
      header.size(), format::ByteSpan(reinterpret_cast<const std::byte*>(cube.data()), cube.size() * sizeof(float))));
  return f.Commit();
}

}  // namespace ltb::stages
