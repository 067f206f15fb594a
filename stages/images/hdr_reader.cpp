// Radiance RGBE (.hdr) for the envmap library: the header and resolution line, then the
// scanlines, run-length encoded or flat.
#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstring>
#include <exception>

#include "format/bytes.h"
#include "stages/images/image_readers.h"

namespace ltb::stages::envmap_internal {
namespace {

// The densest Radiance .hdr accepted: pixels per byte of pixel data (ReadHdr).
constexpr uint64_t kMaxHdrPixelsPerByte = 256;

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

// What the header and the resolution line of a .hdr declare.
struct HdrHeader {
  uint64_t w = 0, h = 0, pixels = 0;
  bool flip_y = false, flip_x = false;
};

// The header lines up to the blank line and the resolution line, with every size checked
// against the cap, the file and the memory limit; `*pos` is left at the first scanline. buf
// holds the file's first bytes (all of them to decode it); file_size is its whole length.
Result<HdrHeader> ReadHdrHeader(const std::string& path, const std::vector<uint8_t>& buf, uint64_t file_size,
                                const EnvLoadOptions& o, uint64_t* pos_out) {
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
  const uint64_t data_bytes = file_size - pos;
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
  LTB_RETURN_IF_ERROR(
      CheckMemory(pixels, file_size + w * 4, o.max_bytes, path, "the Radiance .hdr image " + Size(w, h)));
  *pos_out = pos;
  return HdrHeader{w, h, pixels, ys == "+Y", xs == "-X"};
}

// The scanlines' bytes being decoded: `pos` is the next byte; messages name the scanline.
struct HdrScanlines {
  const std::string& path;
  const std::vector<uint8_t>& buf;
  uint64_t size, h, pos;

  Status Truncated(uint64_t y) const {
    return DataLoss(path + ": Radiance .hdr truncated: the pixel data ends in scanline " + std::to_string(y) + " of " +
                    std::to_string(h) + " (the file has " + std::to_string(size) + " bytes)");
  }
  Status Bad(uint64_t y, const std::string& what) const {
    return DataLoss(path + ": Radiance .hdr scanline " + std::to_string(y) + " at byte " + std::to_string(pos) + ": " +
                    what + " (damaged file)");
  }
};

// A run-length encoded scanline (the "new" format: header 2 2 hi lo, then each of the
// four components in runs and literals) into `scan` (width × RGBE).
Status DecodeRleScanline(HdrScanlines& in, uint64_t y, uint64_t width, std::vector<uint8_t>& scan) {
  const std::vector<uint8_t>& buf = in.buf;
  const uint64_t size = in.size;
  uint64_t& pos = in.pos;
  const uint8_t* b = &buf[pos];
  uint64_t n = (uint64_t(b[2]) << 8) | b[3];
  if (n != width) {
    return in.Bad(
        y, "run-length header says " + std::to_string(n) + " pixels, the image is " + std::to_string(width) + " wide");
  }
  pos += 4;
  for (int ch = 0; ch < 4; ++ch) {
    uint64_t x = 0;
    while (x < width) {
      if (pos >= size) return in.Truncated(y);
      uint64_t count = buf[pos++];
      if (count > 128) {
        count -= 128;
        if (x + count > width) return in.Bad(y, "a run of " + std::to_string(count) + " overflows the width");
        if (pos >= size) return in.Truncated(y);
        uint8_t v = buf[pos++];
        for (uint64_t k = 0; k < count; ++k) scan[(x + k) * 4 + ch] = v;
      } else {
        if (count == 0 || x + count > width) {
          return in.Bad(y, "a literal of " + std::to_string(count) + " bytes overflows the width");
        }
        if (pos + count > size) return in.Truncated(y);
        for (uint64_t k = 0; k < count; ++k) scan[(x + k) * 4 + ch] = buf[pos + k];
        pos += count;
      }
      x += count;
    }
  }
  return Status::Ok();
}

// A flat scanline: RGBE pixels, with the original (1,1,1,n) records repeating the previous
// pixel (consecutive records shift n by 8 more bits).
Status DecodeFlatScanline(HdrScanlines& in, uint64_t y, uint64_t width, std::vector<uint8_t>& scan) {
  uint64_t& pos = in.pos;
  uint64_t x = 0;
  int shift = 0;
  while (x < width) {
    if (pos + 4 > in.size) return in.Truncated(y);
    const uint8_t* p = &in.buf[pos];
    pos += 4;
    if (p[0] == 1 && p[1] == 1 && p[2] == 1) {  // repeat the previous pixel
      if (x == 0 || shift > 24) return in.Bad(y, "a repeat record without a pixel to repeat");
      uint64_t rep = uint64_t(p[3]) << shift;
      if (x + rep > width) return in.Bad(y, "a repeat of " + std::to_string(rep) + " overflows the width");
      for (uint64_t k = 0; k < rep; ++k) std::memcpy(&scan[(x + k) * 4], &scan[(x - 1) * 4], 4);
      x += rep;
      shift += 8;
    } else {
      std::memcpy(&scan[x * 4], p, 4);
      ++x;
      shift = 0;
    }
  }
  return Status::Ok();
}

}  // namespace

// Radiance RGBE (.hdr): header lines up to a blank line, a resolution line, then scanlines
// either run-length encoded per component (the "new" format, widths 8..32767) or flat RGBE
// with the original (1,1,1,n) repeat records. RGBE -> float as in Greg Ward's rgbe.c and
// stb_image: mantissa · 2^(e − 136), 0 when e = 0.
Result<ImageSize> ReadHdrSize(const std::string& path, const std::vector<uint8_t>& head, uint64_t file_size,
                              const EnvLoadOptions& o) {
  uint64_t pos = 0;
  LTB_ASSIGN_OR_RETURN(HdrHeader hh, ReadHdrHeader(path, head, file_size, o, &pos));
  return ImageSize{hh.w, hh.h};
}

Result<Image> ReadHdr(const std::string& path, const std::vector<uint8_t>& buf, const EnvLoadOptions& o) {
  uint64_t pos = 0;
  LTB_ASSIGN_OR_RETURN(HdrHeader hh, ReadHdrHeader(path, buf, buf.size(), o, &pos));
  const uint64_t w = hh.w, h = hh.h;
  const bool flip_y = hh.flip_y, flip_x = hh.flip_x;
  Image img;
  img.width = w;
  img.height = h;
  LTB_RETURN_IF_ERROR(AllocatePixels(&img.rgb, hh.pixels * 3, path, Size(w, h) + " image"));
  std::vector<uint8_t> scan;
  try {
    scan.resize(img.width * 4);
  } catch (const std::exception&) {
    return InvalidArgument(path + ": no memory for a scanline of " + std::to_string(w) + " pixels");
  }
  HdrScanlines in{path, buf, buf.size(), h, pos};
  for (uint64_t y = 0; y < img.height; ++y) {
    if (y % kRowsPerPoll == 0 && o.progress.Cancelled()) {
      return Cancelled(path + ": interrupted while decoding scanline " + std::to_string(y) + " of " +
                       std::to_string(h));
    }
    if (in.pos + 4 > in.size) return in.Truncated(y);
    const uint8_t* b = &buf[in.pos];
    if (img.width >= 8 && img.width < 32768 && b[0] == 2 && b[1] == 2 && (b[2] & 0x80) == 0) {
      LTB_RETURN_IF_ERROR(DecodeRleScanline(in, y, img.width, scan));
    } else {
      LTB_RETURN_IF_ERROR(DecodeFlatScanline(in, y, img.width, scan));
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

}  // namespace ltb::stages::envmap_internal
