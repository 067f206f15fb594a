// Internal to the envmap library (stages/images/envmap.h is the public header): the .exr
// and .hdr readers (image_readers.cpp, hdr_reader.cpp, exr_reader.cpp) and the size and
// memory helpers the loader and the resampler share. Hostile files: every size is checked
// with overflow-safe arithmetic against the cap, the file and the memory limit before
// anything of that size is allocated.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "format/io/file.h"
#include "format/status.h"
#include "stages/images/envmap.h"

namespace ltb::stages::envmap_internal {

// Largest image ltbake loads (pixels): 2^28 ≈ 16384 × 16384, 3 GiB of floats.
inline constexpr uint64_t kMaxPixels = 1ull << 28;

// Rows decoded between two polls of the cancel hook.
inline constexpr uint64_t kRowsPerPoll = 64;

struct Image {
  uint64_t width = 0, height = 0;
  PixelBuffer rgb;
  const char* channel[3] = {"R", "G", "B"};  // for messages ("Y" for luminance files)
  bool lossy = false;                        // lossy EXR compression (DWAA, DWAB, B44, B44A)
  std::string compression;
};

// "WxH", for messages.
std::string Size(uint64_t w, uint64_t h);

std::string MiB(uint64_t bytes);
// The same for sizes computed in double from a hostile header, which may pass 2^64 (a
// conversion to uint64_t would be undefined: exr_fuzzer run 7).
std::string MiB(double bytes);

// `count` floats of pixels (rgb.resize), or a status naming the image. Call only after the
// sizes were checked against the cap, the file and the memory limit; never throws.
Status AllocatePixels(PixelBuffer* rgb, uint64_t count, const std::string& path, const std::string& what);

// Refuses an image whose pixels (and other buffers, `extra` bytes) would pass the memory
// limit, before anything of that size is allocated.
Status CheckMemory(uint64_t pixels, uint64_t extra, uint64_t max_bytes, const std::string& path,
                   const std::string& what);

// One .exr or .hdr file, recognised by its magic bytes (only a regular file is opened).
Result<Image> ReadImage(const std::string& path, const EnvLoadOptions& o);

// The width and height the .exr or .hdr file declares, after the checks ReadImage makes
// before it allocates pixels, without decoding any: an .exr's header alone; an .hdr's
// header (its declared size is checked against the file's length, not its pixels).
struct ImageSize {
  uint64_t width = 0, height = 0;
};
Result<ImageSize> ReadImageSize(const std::string& path, const EnvLoadOptions& o);

// The readers ReadImage dispatches to.
// Radiance RGBE (.hdr), from the whole file's bytes (hdr_reader.cpp).
Result<Image> ReadHdr(const std::string& path, const std::vector<uint8_t>& buf, const EnvLoadOptions& o);
// From the file's first bytes (its header) and its whole length.
Result<ImageSize> ReadHdrSize(const std::string& path, const std::vector<uint8_t>& head, uint64_t file_size,
                              const EnvLoadOptions& o);
// OpenEXR through the library (exr_reader.cpp), after CheckExrHeaderSizes passed.
Result<Image> ReadExr(const std::string& path, const EnvLoadOptions& o);
Result<ImageSize> ReadExrSize(const std::string& path);
// Walks the OpenEXR header(s) of `f` (`size` bytes) before OpenEXR reads them (exr_reader.cpp).
Status CheckExrHeaderSizes(const std::string& path, io::File& f, uint64_t size, uint64_t max_bytes);

}  // namespace ltb::stages::envmap_internal
