// OpenEXR for the envmap library: the header walk that foresees OpenEXR's allocations
// (CheckExrHeaderSizes), then the pixels through the library (ReadExr).
#include <OpenEXR/ImfChannelList.h>
#include <OpenEXR/ImfFrameBuffer.h>
#include <OpenEXR/ImfHeader.h>
#include <OpenEXR/ImfInputFile.h>
#include <OpenEXR/ImfRgbaFile.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <exception>
#include <memory>

#include "format/bytes.h"
#include "stages/images/image_readers.h"

namespace ltb::stages::envmap_internal {
namespace {

// A count held in a double, in full while exact (below 2^53), else in %.4g.
std::string Count(double v) {
  if (v < 9007199254740992.0) return std::to_string(uint64_t(v));
  char buf[48];
  std::snprintf(buf, sizeof buf, "%.4g", v);
  return buf;
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

// The little-endian int32 at b[at].
int32_t LeI32(const std::vector<uint8_t>& b, uint64_t at) {
  return int32_t(uint32_t(b[at]) | uint32_t(b[at + 1]) << 8 | uint32_t(b[at + 2]) << 16 | uint32_t(b[at + 3]) << 24);
}

// OpenEXR reads the types it knows by their own layout, not by the size field: a size
// that disagrees would make its reading and this walk part ways (exr_fuzzer). `at`: the
// byte of the size field.
Status CheckFixedSize(const std::string& path, const std::string& name, const std::string& type, int32_t n,
                      uint64_t at) {
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
                      std::to_string(at) + " declares " + std::to_string(n) + " bytes; that type has " +
                      std::to_string(want) + " (damaged file)");
    }
  }
  return Status::Ok();
}

// What an attribute whose `n` bytes at b[pos] lie within the bytes read tells of the part's
// layout: its channel list (whose end is checked), data window, compression and tiles.
Status ReadAttribute(const std::string& path, const std::vector<uint8_t>& b, uint64_t pos, int32_t n,
                     const std::string& name, const std::string& type, ExrLayout* layout) {
  if (type == "chlist") {
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
        const int32_t pixel_type = LeI32(b, c + 1);
        bytes_per_pixel += pixel_type == 1 ? 2 : 4;  // HALF; UINT, FLOAT (others: refused by OpenEXR)
      }
      c += 1 + 16;
    }
    if (name == "channels") {  // a repeated attribute replaces the earlier one, as in OpenEXR
      layout->has_channels = true;
      layout->bytes_per_pixel = bytes_per_pixel;
      layout->chroma = chroma;
    }
    if (!ok) {
      return DataLoss(path + ": OpenEXR channel list \"" + name + "\" at byte " + std::to_string(pos) +
                      " does not end where its size (" + std::to_string(n) + " bytes) says (damaged file)");
    }
  }
  if (name == "dataWindow" && type == "box2i") {
    layout->has_window = true;
    for (int k = 0; k < 4; ++k) layout->window[k] = LeI32(b, pos + 4 * k);
  } else if (name == "compression" && type == "compression") {
    layout->compression = b[pos];
  } else if (name == "tiles" && type == "tiledesc") {
    layout->tiled = true;
    layout->tile_x = uint32_t(LeI32(b, pos));
    layout->tile_y = uint32_t(LeI32(b, pos + 4));
  }
  return Status::Ok();
}

// "data window (x0, y0) - (x1, y1)", for messages.
std::string WindowText(const Imath::Box2i& dw) {
  return "data window (" + std::to_string(dw.min.x) + ", " + std::to_string(dw.min.y) + ") - (" +
         std::to_string(dw.max.x) + ", " + std::to_string(dw.max.y) + ")";
}

// The name of a lossy compression (DWAA, DWAB, B44, B44A); empty for a lossless one.
std::string LossyCompressionName(Imf::Compression compression) {
  switch (compression) {
    case Imf::DWAA_COMPRESSION:
      return "DWAA";
    case Imf::DWAB_COMPRESSION:
      return "DWAB";
    case Imf::B44_COMPRESSION:
      return "B44";
    case Imf::B44A_COMPRESSION:
      return "B44A";
    default:
      break;
  }
  return "";
}

// Which channels the map is read from: R, G and B; luminance-chroma (Y with RY or BY); or
// luminance Y alone.
struct ExrChannels {
  bool rgb = false, chroma = false, lum = false;
};

Result<ExrChannels> CheckExrChannels(const std::string& path, const Imf::ChannelList& channels) {
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
  ExrChannels ch;
  ch.rgb = channels.findChannel("R") && channels.findChannel("G") && channels.findChannel("B");
  ch.chroma = channels.findChannel("Y") && (channels.findChannel("RY") || channels.findChannel("BY"));
  ch.lum = channels.findChannel("Y") != nullptr;
  if (!ch.rgb && !ch.lum) {
    return InvalidArgument(path + ": OpenEXR file has channels " + (names.empty() ? "(none)" : names) +
                           "; an environment map needs R, G and B (A is ignored) or luminance Y");
  }
  return ch;
}

// The pixels of the data window `dw` into img->rgb (allocated), `strip` rows at a time
// (scratch buffers of `strip_px` pixels). A damaged chunk fails at its strip; the cancel
// hook is polled between strips.
Status ReadExrStrips(const std::string& path, Imf::InputFile& file, const Imath::Box2i& dw, const ExrChannels& ch,
                     uint64_t strip, uint64_t strip_px, const EnvLoadOptions& o, Image* img) {
  const int64_t w = int64_t(dw.max.x) - dw.min.x + 1, h = int64_t(dw.max.y) - dw.min.y + 1;
  const bool rgb = ch.rgb, chroma = ch.chroma;
  const std::string window = WindowText(dw);
  std::vector<Imf::Rgba> rgba;
  std::vector<float> lum_strip;
  std::unique_ptr<Imf::RgbaInputFile> rf;
  if (rgb) {
    Imf::FrameBuffer fb;
    const char* name[3] = {"R", "G", "B"};
    for (int c = 0; c < 3; ++c) {
      fb.insert(name[c],
                Imf::Slice::Make(Imf::FLOAT, img->rgb.data() + c, dw, 3 * sizeof(float), 3 * sizeof(float) * w));
    }
    file.setFrameBuffer(fb);
  } else if (chroma) {
    rf = std::make_unique<Imf::RgbaInputFile>(path.c_str());
    rgba.resize(strip_px);
  } else {
    lum_strip.resize(strip_px);
    img->channel[0] = img->channel[1] = img->channel[2] = "Y";
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
          img->rgb[(first + i) * 3] = rgba[i].r;
          img->rgb[(first + i) * 3 + 1] = rgba[i].g;
          img->rgb[(first + i) * 3 + 2] = rgba[i].b;
        }
      } else {
        Imf::FrameBuffer fb;
        fb.insert("Y", Imf::Slice(Imf::FLOAT, reinterpret_cast<char*>(FrameOrigin(lum_strip.data(), dw.min.x, y0, w)),
                                  sizeof(float), sizeof(float) * size_t(w)));
        file.setFrameBuffer(fb);
        file.readPixels(int(y0), int(y1));
        for (uint64_t i = 0; i < count; ++i) {
          img->rgb[(first + i) * 3] = img->rgb[(first + i) * 3 + 1] = img->rgb[(first + i) * 3 + 2] = lum_strip[i];
        }
      }
    } catch (const std::exception& e) {
      return DataLoss(path + ": OpenEXR could not read rows " + std::to_string(y0 - dw.min.y) + ".." +
                      std::to_string(y1 - dw.min.y) + " of " + std::to_string(h) + " (" + window + "): " + e.what());
    }
  }
  return Status::Ok();
}

// The data window's size, refused when empty or beyond kMaxPixels.
Result<ImageSize> CheckExrWindow(const std::string& path, const Imath::Box2i& dw) {
  const int64_t w = int64_t(dw.max.x) - dw.min.x + 1, h = int64_t(dw.max.y) - dw.min.y + 1;
  uint64_t pixels = 0;
  if (w <= 0 || h <= 0 || format::MulOverflows(uint64_t(w), uint64_t(h), &pixels) || pixels > kMaxPixels) {
    return InvalidArgument(path + ": OpenEXR " + WindowText(dw) + " is " + std::to_string(w) + "x" + std::to_string(h) +
                           ", empty or beyond " + std::to_string(kMaxPixels) + " pixels (16384 x 16384)");
  }
  return ImageSize{uint64_t(w), uint64_t(h)};
}

}  // namespace

Result<ImageSize> ReadExrSize(const std::string& path) {
  try {
    Imf::InputFile file(path.c_str());
    return CheckExrWindow(path, file.header().dataWindow());
  } catch (const std::exception& e) {
    return DataLoss(path + ": OpenEXR could not read its header: " + e.what());
  }
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
    LTB_ASSIGN_OR_RETURN(const ImageSize size, CheckExrWindow(path, dw));
    const int64_t w = int64_t(size.width), h = int64_t(size.height);
    const uint64_t pixels = size.width * size.height;
    const std::string window = WindowText(dw);
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
    img.compression = LossyCompressionName(header.compression());
    img.lossy = !img.compression.empty();
    LTB_ASSIGN_OR_RETURN(const ExrChannels ch, CheckExrChannels(path, header.channels()));
    const bool rgb = ch.rgb, chroma = ch.chroma;
    // Strips: whole chunks (every compression's lines per chunk divides 256), ~4 MiB of floats.
    const uint64_t strip = std::max<uint64_t>(256, ((uint64_t(4) << 20) / (uint64_t(w) * 12)) / 256 * 256);
    const uint64_t strip_px = std::min<uint64_t>(strip, uint64_t(h)) * uint64_t(w);  // buffers: rows of one strip
    const uint64_t scratch = rgb ? 0 : chroma ? strip_px * sizeof(Imf::Rgba) : strip_px * sizeof(float);
    LTB_RETURN_IF_ERROR(CheckMemory(pixels, scratch, o.max_bytes, path, "the OpenEXR image " + Size(w, h)));
    LTB_RETURN_IF_ERROR(AllocatePixels(&img.rgb, pixels * 3, path, Size(w, h) + " image"));
    LTB_RETURN_IF_ERROR(ReadExrStrips(path, file, dw, ch, strip, strip_px, o, &img));
    return img;
  } catch (const std::exception& e) {
    return DataLoss(path + ": OpenEXR could not read it: " + e.what());
  }
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
      const int32_t n = LeI32(b, pos);
      pos += 4;
      if (n < 0 || uint64_t(n) > size - pos) {
        return DataLoss(path + ": OpenEXR header attribute \"" + name + "\" (type \"" + type + "\") at byte " +
                        std::to_string(pos - 4) + " declares " + std::to_string(n) + " bytes, but " +
                        std::to_string(size - pos) + " follow in the file (damaged or not an OpenEXR file)");
      }
      LTB_RETURN_IF_ERROR(CheckFixedSize(path, name, type, n, pos - 4));
      if (pos + uint64_t(n) <= cap) LTB_RETURN_IF_ERROR(ReadAttribute(path, b, pos, n, name, type, &layout));
      pos += uint64_t(n);
      if (pos > cap) return Status::Ok();  // a header this large: left to OpenEXR, sizes so far are sane
    }
    if (!multipart || !any) return Status::Ok();
  }
}

}  // namespace ltb::stages::envmap_internal
