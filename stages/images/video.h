// An .mp4 of relit frames through Debian's `ffmpeg` (H.264 when the build has it, else
// MPEG-4 part 2; yuv420p, sides padded to even). Frames go to ffmpeg's standard input as raw
// RGB over a socket (a dead ffmpeg is an error, not a SIGPIPE); the video is written beside
// the target and renamed into place by Finish, so the path never holds a half-written file.
#pragma once

#include <sys/types.h>

#include <cstdint>
#include <memory>
#include <string>

#include "format/io/atomic_file.h"
#include "format/status.h"

namespace ltb::stages {

class Mp4Writer {
 public:
  static Result<Mp4Writer> Open(const std::string& path, uint64_t width, uint64_t height, double fps);
  Mp4Writer(Mp4Writer&&) noexcept;
  Mp4Writer& operator=(Mp4Writer&&) = delete;
  ~Mp4Writer();  // an unfinished video is abandoned: ffmpeg stopped, the partial file removed

  // width × height × 3 sRGB bytes.
  Status Add(const uint8_t* srgb);
  Status Finish();

 private:
  Mp4Writer() = default;
  Status Stop(bool* clean);
  std::string path_, log_;
  uint64_t width_ = 0, height_ = 0;
  std::unique_ptr<io::AtomicFile> file_;
  int fd_ = -1;
  pid_t pid_ = -1;
};

}  // namespace ltb::stages
