// Advisory locks that keep two processes from writing the same thing: one writer per stage
// output (LockOutput), one `ltbake run` per work directory (the pipeline).
//
// A lock is flock(LOCK_EX) on a small lock file that holds the PID of its holder, so the
// process turned away can say who has it. The kernel drops the lock when its holder dies,
// however it dies (a SIGKILL leaves the file, not the lock). Within one process the lock of
// a file is shared: taking it again (a stage that locks its output before the container
// writer locks it too) returns another handle to the same lock, released with the last.
#pragma once

#include <functional>
#include <memory>
#include <string>

#include "format/status.h"

namespace ltb::io {

struct LockOptions {
  // Keep trying this long before giving up (0: one try).
  double wait_seconds = 0;
  // The descriptor survives exec: child processes hold the lock too, until the last of
  // them exits (the run's work-directory lock, inherited by the stages it starts).
  bool inherit = false;
  // Unlink the lock file on release (an output's lock leaves nothing behind). Not for
  // inherited locks: a child still holding the old file would not stop a new holder.
  bool remove_on_release = true;
  // The message when another process holds the lock; `holder` is "PID 1234" (or "another
  // process" when the file names none).
  std::function<std::string(const std::string& holder)> busy_message;
  // Polled while waiting: true stops the wait with kCancelled (a signal arrived).
  std::function<bool()> cancelled;
};

class FileLock {
 public:
  FileLock() = default;  // holds nothing

  // Takes the lock at `lock_path` (created if absent). kFailedPrecondition with
  // options.busy_message when another process holds it; kIo (naming the path) when the file
  // cannot be created or locked.
  static Result<FileLock> Acquire(const std::string& lock_path, const LockOptions& options);

  bool held() const { return state_ != nullptr; }
  const std::string& path() const;
  // Drops this handle now (the lock goes with the process's last handle).
  void Release() { state_.reset(); }

  struct State;

 private:
  std::shared_ptr<State> state_;
};

// The lock file of an output: "dir/out.ltm" -> "dir/out.ltm.lock".
std::string OutputLockPath(const std::string& output);

// Takes the lock of an output before anything is opened for writing. A second writer gets
// kFailedPrecondition: "OUTPUT is in use by PID N (another ltbake writing it); wait for it or
// choose another output", and has touched nothing but the lock file's descriptor. An output
// path that holds a directory, FIFO, device or socket is refused first (io::ReplaceableOutput).
Result<FileLock> LockOutput(const std::string& output);

// The PID recorded in a lock file, or 0 (no file, no PID yet).
long LockHolderPid(const std::string& lock_path);

}  // namespace ltb::io
