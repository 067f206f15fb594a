#include "stages/images/image_readers.h"

#include <algorithm>
#include <cstdint>
#include <cstdio>
#include <exception>

#include "format/bytes.h"
#include "format/io/file.h"

namespace ltb::stages::envmap_internal {

std::string Size(uint64_t w, uint64_t h) { return std::to_string(w) + "x" + std::to_string(h); }

std::string MiB(uint64_t bytes) {
  char buf[48];
  std::snprintf(buf, sizeof buf, "%.1f MiB", double(bytes) / (1 << 20));
  return buf;
}

std::string MiB(double bytes) {
  char buf[48];
  std::snprintf(buf, sizeof buf, "%.1f MiB", bytes / (1 << 20));
  return buf;
}

Status AllocatePixels(PixelBuffer* rgb, uint64_t count, const std::string& path, const std::string& what) {
  try {
    rgb->resize(count);
  } catch (const std::exception&) {  // bad_alloc, length_error
    return InvalidArgument(path + ": no memory for the " + what + " (" + MiB(count * sizeof(float)) +
                           "); free memory or use a smaller map");
  }
  return Status::Ok();
}

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

namespace {

// The first `limit` bytes of a file (all of it by default), after the checks every .hdr
// read makes of its size; the file's size into *file_size.
Result<std::vector<uint8_t>> ReadFileHead(const std::string& path, uint64_t max_bytes, uint64_t* file_size,
                                          uint64_t limit = UINT64_MAX) {
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
  *file_size = size;
  const uint64_t n = std::min(size, limit);
  std::vector<uint8_t> bytes;
  try {
    bytes.resize(n);
  } catch (const std::exception&) {
    return InvalidArgument(path + ": no memory to read its " + std::to_string(n) + " bytes");
  }
  LTB_RETURN_IF_ERROR(f.ReadAt(0, format::MutableByteSpan(reinterpret_cast<std::byte*>(bytes.data()), n)));
  return bytes;
}

}  // namespace

namespace {

enum class ImageKind { kExr, kHdr };

// Which reader a file is for, from its magic bytes (only a regular file is opened); an
// .exr's header sizes are checked here, before OpenEXR allocates what they declare.
Result<ImageKind> Sniff(const std::string& path, const EnvLoadOptions& o) {
  LTB_RETURN_IF_ERROR(io::RequireRegularFile(path, "name a .exr or .hdr image file"));
  LTB_ASSIGN_OR_RETURN(io::File f, io::File::Open(path, io::File::Mode::kRead));
  LTB_ASSIGN_OR_RETURN(uint64_t size, f.Size());
  std::byte magic[4] = {};
  LTB_RETURN_IF_ERROR(f.ReadAt(0, format::MutableByteSpan(magic, std::min<uint64_t>(size, 4))));
  if (size >= 4 && magic[0] == std::byte{0x76} && magic[1] == std::byte{0x2f} && magic[2] == std::byte{0x31} &&
      magic[3] == std::byte{0x01}) {
    LTB_RETURN_IF_ERROR(CheckExrHeaderSizes(path, f, size, o.max_bytes));
    return ImageKind::kExr;
  }
  if (size < 2 || magic[0] != std::byte{'#'} || magic[1] != std::byte{'?'}) {
    std::string what = size == 0 ? "the file is empty" : "it has neither the OpenEXR magic (76 2f 31 01) nor \"#?\"";
    return InvalidArgument(path + ": not an OpenEXR (.exr) or Radiance (.hdr) image: " + what);
  }
  return ImageKind::kHdr;
}

}  // namespace

Result<Image> ReadImage(const std::string& path, const EnvLoadOptions& o) {
  LTB_ASSIGN_OR_RETURN(const ImageKind kind, Sniff(path, o));
  if (kind == ImageKind::kExr) return ReadExr(path, o);
  uint64_t size = 0;
  LTB_ASSIGN_OR_RETURN(std::vector<uint8_t> bytes, ReadFileHead(path, o.max_bytes, &size));
  return ReadHdr(path, bytes, o);
}

Result<ImageSize> ReadImageSize(const std::string& path, const EnvLoadOptions& o) {
  LTB_ASSIGN_OR_RETURN(const ImageKind kind, Sniff(path, o));
  if (kind == ImageKind::kExr) return ReadExrSize(path);
  uint64_t size = 0;  // the header: at most 64 KiB of lines, then the resolution line
  LTB_ASSIGN_OR_RETURN(std::vector<uint8_t> head, ReadFileHead(path, o.max_bytes, &size, (1u << 16) + 4096));
  return ReadHdrSize(path, head, size, o);
}

}  // namespace ltb::stages::envmap_internal
