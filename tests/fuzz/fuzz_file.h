// Shared by the fuzz targets: the readers take paths (and some pick the format by the
// extension), so each input is written to a real file in a private directory of the
// process, in /dev/shm when there is one (tmpfs: no disk traffic).
#pragma once

#include <fcntl.h>
#include <unistd.h>

#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <filesystem>
#include <string>
#include <system_error>

namespace ltb::fuzz {

// The process's own temporary directory, made on first use and removed at a normal exit.
inline const std::string& TempDir() {
  // Never destroyed: the exit handler below runs after static destructors would have.
  static const std::string* const dir = [] {
    // LTB_FUZZ_TMP (fuzz_run.sh sets it, and removes it after each target: a process that
    // dies of a finding skips the exit handler), else /dev/shm, else the temp directory.
    const char* env = std::getenv("LTB_FUZZ_TMP");
    std::string base = env != nullptr && *env != '\0'              ? std::string(env)
                       : std::filesystem::is_directory("/dev/shm") ? "/dev/shm"
                                                                   : std::filesystem::temp_directory_path().string();
    std::string tmpl = base + "/ltb-fuzz-XXXXXX";
    if (mkdtemp(tmpl.data()) == nullptr) std::abort();
    auto* d = new std::string(tmpl);
    std::atexit([] {
      std::error_code ec;
      std::filesystem::remove_all(TempDir(), ec);
    });
    return d;
  }();
  return *dir;
}

// Writes `size` bytes to TempDir()/name (replacing it) and returns the path; "" on failure.
inline std::string WriteFile(const std::string& name, const void* data, size_t size) {
  std::string path = TempDir() + "/" + name;
  int fd = open(path.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (fd < 0) return "";
  const auto* p = static_cast<const uint8_t*>(data);
  size_t done = 0;
  while (done < size) {
    ssize_t n = write(fd, p + done, size - done);
    if (n <= 0) {
      close(fd);
      return "";
    }
    done += static_cast<size_t>(n);
  }
  close(fd);
  return path;
}

inline std::string WriteFile(const std::string& name, const std::string& text) {
  return WriteFile(name, text.data(), text.size());
}

}  // namespace ltb::fuzz
