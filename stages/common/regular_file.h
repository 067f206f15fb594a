// Refusing inputs that are not regular files before opening them: opening a FIFO for
// reading blocks until a writer appears (a hang that no signal check reaches), and a
// directory or a device is never an input file.
#pragma once

#include <sys/stat.h>

#include <cerrno>
#include <string>

#include "format/status.h"

namespace ltb::stages {

// Ok for a regular file (or a symlink to one); NotFound when nothing is there; otherwise
// InvalidArgument "PATH: is a FIFO (named pipe), not a regular file; WANTED".
inline Status CheckRegularFile(const std::string& path, const std::string& wanted) {
  struct stat st {};
  if (::stat(path.c_str(), &st) != 0) {
    if (errno == ENOENT) return NotFound(path + ": no such file");
    return IoError(path + ": stat", errno);
  }
  if (S_ISREG(st.st_mode)) return Status::Ok();
  const char* what = S_ISDIR(st.st_mode)    ? "a directory"
                     : S_ISFIFO(st.st_mode) ? "a FIFO (named pipe)"
                     : S_ISCHR(st.st_mode)  ? "a character device"
                     : S_ISBLK(st.st_mode)  ? "a block device"
                     : S_ISSOCK(st.st_mode) ? "a socket"
                                            : "a special file";
  return InvalidArgument(path + ": is " + what + ", not a regular file; " + wanted);
}

}  // namespace ltb::stages
