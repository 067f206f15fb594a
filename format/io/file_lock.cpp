#include "format/io/file_lock.h"

#include <fcntl.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <cstdlib>
#include <map>
#include <mutex>
#include <thread>
#include <utility>

#include "format/io/atomic_file.h"
#include "format/io/file.h"

namespace ltb::io {

struct FileLock::State {
  int fd = -1;
  std::string path;
  dev_t dev = 0;
  ino_t ino = 0;
  bool remove_on_release = true;
  ~State();
};

namespace {

// The locks this process holds, by lock file: flock conflicts between two descriptors of one
// process too, so a second Acquire of a held lock shares the first one's state.
std::mutex g_mu;
std::map<std::pair<dev_t, ino_t>, std::weak_ptr<FileLock::State>>& Registry() {
  static auto* m = new std::map<std::pair<dev_t, ino_t>, std::weak_ptr<FileLock::State>>;  // never destroyed
  return *m;
}

long ReadPid(int fd) {
  char buf[32] = {};
  ssize_t n = ::pread(fd, buf, sizeof buf - 1, 0);
  if (n <= 0) return 0;
  char* end = nullptr;
  long pid = std::strtol(buf, &end, 10);
  return (end != buf && pid > 0) ? pid : 0;
}

}  // namespace

FileLock::State::~State() {
  std::lock_guard<std::mutex> lock(g_mu);
  Registry().erase({dev, ino});
  if (remove_on_release) {
    // Unlinked while still locked: a process that opened this file meanwhile finds, once it
    // has the lock, that the path no longer names it, and starts over with a new file.
    struct stat st;
    if (::stat(path.c_str(), &st) == 0 && st.st_dev == dev && st.st_ino == ino) ::unlink(path.c_str());
  }
  ::close(fd);
}

const std::string& FileLock::path() const {
  static const std::string kNone;
  return state_ ? state_->path : kNone;
}

Result<FileLock> FileLock::Acquire(const std::string& lock_path, const LockOptions& options) {
  using Clock = std::chrono::steady_clock;
  const auto deadline = Clock::now() + std::chrono::duration_cast<Clock::duration>(
                                           std::chrono::duration<double>(std::max(0.0, options.wait_seconds)));
  for (;;) {
    // Open refuses a lock path that is not a regular file, without blocking on a FIFO.
    auto opened = File::Open(lock_path, File::Mode::kCreate, options.inherit);
    if (!opened.ok()) {
      if (opened.status().code() == StatusCode::kInvalidArgument) {
        return InvalidArgument(opened.status().message() + " (it is where a lock file goes: remove it)");
      }
      return opened.status().WithContext("cannot create the lock file");
    }
    const int fd = opened->Release();
    struct stat st;
    if (::fstat(fd, &st) != 0) {
      int err = errno;
      ::close(fd);
      return IoError(lock_path + ": fstat", err);
    }
    {
      std::unique_lock<std::mutex> lock(g_mu);
      for (;;) {
        auto it = Registry().find({st.st_dev, st.st_ino});
        if (it == Registry().end()) break;
        if (auto held = it->second.lock()) {
          ::close(fd);
          FileLock f;
          f.state_ = std::move(held);
          return f;
        }
        // Being released by another thread of this process: wait for it to finish.
        lock.unlock();
        std::this_thread::yield();
        lock.lock();
      }
    }
    // Tries on this descriptor until the lock is ours or the wait is over (the descriptor
    // stays open meanwhile: a waiting process can be seen waiting, in /proc/PID/fd).
    bool reopen = false;
    while (!reopen) {
      if (::flock(fd, LOCK_EX | LOCK_NB) == 0) {
        struct stat now;
        if (::stat(lock_path.c_str(), &now) != 0 || now.st_dev != st.st_dev || now.st_ino != st.st_ino) {
          // Its holder released (and unlinked) it since we opened it: start over with the
          // file now at the path.
          ::close(fd);
          reopen = true;
          continue;
        }
        // Best effort: on a full disk the lock still holds, the others just cannot name us.
        const std::string pid = std::to_string(::getpid()) + "\n";
        if (::ftruncate(fd, 0) == 0) (void)!::pwrite(fd, pid.data(), pid.size(), 0);
        auto state = std::make_shared<State>();
        state->fd = fd;
        state->path = lock_path;
        state->dev = st.st_dev;
        state->ino = st.st_ino;
        state->remove_on_release = options.remove_on_release;
        std::lock_guard<std::mutex> lock(g_mu);
        Registry()[{st.st_dev, st.st_ino}] = state;
        FileLock f;
        f.state_ = std::move(state);
        return f;
      }
      const int err = errno;
      if (err == EINTR) continue;
      if (err != EWOULDBLOCK) {
        ::close(fd);
        return IoError(lock_path + ": flock", err);
      }
      if (Clock::now() < deadline) {
        if (options.cancelled && options.cancelled()) {
          ::close(fd);
          return Cancelled("interrupted while waiting for the lock " + lock_path);
        }
        std::this_thread::sleep_for(std::chrono::milliseconds(100));
        continue;
      }
      // Held by another process. It records its PID right after taking the lock: give it
      // a moment to do so before saying it is unknown.
      long pid = ReadPid(fd);
      for (int i = 0; pid == 0 && i < 20; ++i) {
        std::this_thread::sleep_for(std::chrono::milliseconds(5));
        pid = ReadPid(fd);
      }
      ::close(fd);
      const std::string holder = pid > 0 ? "PID " + std::to_string(pid) : std::string("another process");
      if (options.busy_message) return FailedPrecondition(options.busy_message(holder));
      return FailedPrecondition(lock_path + " is locked by " + holder);
    }
  }
}

std::string OutputLockPath(const std::string& output) { return output + ".lock"; }

Result<FileLock> LockOutput(const std::string& output) {
  // An output that could not be replaced gets no lock file beside it either (`-o /dev/full`
  // must not create /dev/full.lock).
  LTB_RETURN_IF_ERROR(ReplaceableOutput(output).status());
  LockOptions o;
  o.busy_message = [&output](const std::string& holder) {
    return output + " is in use by " + holder + " (another ltbake writing it); wait for it or choose another output";
  };
  auto lock = FileLock::Acquire(OutputLockPath(output), o);
  if (!lock.ok() && lock.status().code() == StatusCode::kIo) return lock.status().WithContext(output);
  return lock;
}

long LockHolderPid(const std::string& lock_path) {
  int fd = ::open(lock_path.c_str(), O_RDONLY | O_NONBLOCK | O_CLOEXEC);
  if (fd < 0) return 0;
  long pid = ReadPid(fd);
  ::close(fd);
  return pid;
}

}  // namespace ltb::io
