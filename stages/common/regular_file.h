// Refusing inputs that are not regular files before opening them: opening a FIFO for
// reading blocks until a writer appears (a hang that no signal check reaches), and a
// directory or a device is never an input file.
#pragma once

#include <sys/stat.h>

#include <cerrno>
#include <string>

#include "format/io/file.h"
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
  // The same words as io::File::Open uses for what the path is.
  return InvalidArgument(path + ": is " + io::FileKind(st.st_mode) + ", not a regular file; " + wanted);
}

}  // namespace ltb::stages
