#include "stages/images/video.h"

#include <fcntl.h>
#include <signal.h>
#include <spawn.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <sstream>
#include <vector>

extern char** environ;

namespace ltb::stages {

Result<Mp4Writer> Mp4Writer::Open(const std::string& path, uint64_t width, uint64_t height, double fps) {
  if (width == 0 || height == 0) {
    return InvalidArgument(path + ": the matrix rows are not an image; write frames as .npy through a %04d pattern");
  }
  if (!(fps > 0 && fps <= 1000)) return InvalidArgument("--fps " + std::to_string(fps) + ": expected 0 < fps <= 1000");
  Mp4Writer w;
  w.path_ = path;
  w.width_ = width;
  w.height_ = height;
  LTB_ASSIGN_OR_RETURN(io::AtomicFile f, io::AtomicFile::Create(path));
  w.file_ = std::make_unique<io::AtomicFile>(std::move(f));
  w.log_ = w.file_->temp_path() + ".log";
  int sv[2];
  if (socketpair(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0, sv) != 0) return IoError("socketpair for ffmpeg", errno);
  const std::string size = std::to_string(width) + "x" + std::to_string(height);
  std::ostringstream rate;
  rate << fps;
  std::vector<std::string> args = {"ffmpeg",
                                   "-hide_banner",
                                   "-loglevel",
                                   "error",
                                   "-y",
                                   "-f",
                                   "rawvideo",
                                   "-pix_fmt",
                                   "rgb24",
                                   "-s",
                                   size,
                                   "-r",
                                   rate.str(),
                                   "-i",
                                   "-",
                                   "-vf",
                                   "pad=ceil(iw/2)*2:ceil(ih/2)*2",
                                   "-pix_fmt",
                                   "yuv420p",
                                   "-f",
                                   "mp4",
                                   w.file_->temp_path()};
  std::vector<char*> argv;
  for (auto& a : args) argv.push_back(a.data());
  argv.push_back(nullptr);
  posix_spawn_file_actions_t fa;
  posix_spawn_file_actions_init(&fa);
  posix_spawn_file_actions_adddup2(&fa, sv[1], 0);
  posix_spawn_file_actions_addopen(&fa, 1, "/dev/null", O_WRONLY, 0);
  posix_spawn_file_actions_addopen(&fa, 2, w.log_.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
  pid_t pid = -1;
  const int rc = posix_spawnp(&pid, "ffmpeg", &fa, nullptr, argv.data(), environ);
  posix_spawn_file_actions_destroy(&fa);
  close(sv[1]);
  if (rc != 0) {
    close(sv[0]);
    unlink(w.log_.c_str());
    return FailedPrecondition(path + ": cannot run ffmpeg (" + std::string(strerror(rc)) +
                              "); install Debian's ffmpeg (scripts/setup.sh) or write frames through a pattern such "
                              "as frames/relit_%04d.png");
  }
  w.fd_ = sv[0];
  w.pid_ = pid;
  return w;
}

Mp4Writer::Mp4Writer(Mp4Writer&& o) noexcept
    : path_(std::move(o.path_)),
      log_(std::move(o.log_)),
      width_(o.width_),
      height_(o.height_),
      file_(std::move(o.file_)),
      fd_(o.fd_),
      pid_(o.pid_) {
  o.fd_ = -1;
  o.pid_ = -1;
}

Mp4Writer::~Mp4Writer() {
  if (pid_ > 0) kill(pid_, SIGTERM);
  bool clean = false;
  (void)Stop(&clean);
  if (!log_.empty()) unlink(log_.c_str());
}

Status Mp4Writer::Add(const uint8_t* srgb) {
  const uint8_t* p = srgb;
  size_t left = width_ * height_ * 3;
  while (left > 0) {
    ssize_t n = send(fd_, p, left, MSG_NOSIGNAL);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) {
      bool clean = false;
      (void)Stop(&clean);
      std::ifstream log(log_);
      std::string why((std::istreambuf_iterator<char>(log)), std::istreambuf_iterator<char>());
      return IoError(path_ + ": ffmpeg stopped taking frames" + (why.empty() ? "" : ": " + why), errno);
    }
    p += n;
    left -= static_cast<size_t>(n);
  }
  return Status::Ok();
}

Status Mp4Writer::Stop(bool* clean) {
  if (fd_ >= 0) close(fd_);
  fd_ = -1;
  *clean = false;
  if (pid_ <= 0) return Status::Ok();
  int status = 0;
  while (waitpid(pid_, &status, 0) < 0 && errno == EINTR) {
  }
  pid_ = -1;
  *clean = WIFEXITED(status) && WEXITSTATUS(status) == 0;
  return Status::Ok();
}

Status Mp4Writer::Finish() {
  bool clean = false;
  LTB_RETURN_IF_ERROR(Stop(&clean));
  if (!clean) {
    std::ifstream log(log_);
    std::string why((std::istreambuf_iterator<char>(log)), std::istreambuf_iterator<char>());
    return IoError(path_ + ": ffmpeg failed" + (why.empty() ? "" : ": " + why), 0);
  }
  unlink(log_.c_str());
  log_.clear();
  return file_->Commit();
}

}  // namespace ltb::stages
