// Runs one stage as a child process (`ltbake <stage> ...`): its stdout and stderr are
// passed on and appended to a log, a pending SIGINT/SIGTERM is forwarded to it, and its
// wall time, CPU time, block I/O, peak RSS and exit status are measured (wait4). The child dies with its parent
// (PR_SET_PDEATHSIG), so a bake killed with SIGKILL leaves no stage running on its own.
#pragma once

#include <cstdint>
#include <functional>
#include <string>
#include <string_view>
#include <vector>

#include "format/status.h"

namespace ltb::pipeline {

struct ChildResult {
  int exit_code = -1;   // when the child exited normally
  int term_signal = 0;  // when a signal killed it
  double wall_seconds = 0;
  uint64_t peak_rss_bytes = 0;
  double user_seconds = 0, system_seconds = 0;  // CPU time of the child (and its waited-for children)
  uint64_t disk_read_bytes = 0,
           disk_write_bytes = 0;    // block I/O (ru_inblock/ru_oublock × 512): page-cache hits are not counted
  std::string stdout_text;          // everything it printed on stdout
  std::vector<std::string> errors;  // its "ltbake: error: ..." lines (stderr)
};

struct ChildIo {
  std::string log_path;                             // appended to; progress redraws left out
  std::function<void(std::string_view)> on_stdout;  // may be empty
  std::function<void(std::string_view)> on_stderr;  // may be empty
  std::function<int()> pending_signal;              // a signal to forward (0: none), polled
  // A child that has not exited this long after the forwarded signal is killed (SIGKILL):
  // a Slurm client whose controller is gone retries for minutes and ignores SIGTERM.
  double kill_after_seconds = 30;
  // > 0: the child is killed (SIGKILL) after this long whatever it is doing (scancel after
  // an interrupt, which must not keep the run from stopping).
  double deadline_seconds = 0;
};

Result<ChildResult> RunChild(const std::vector<std::string>& argv, const ChildIo& io);

// The command line as a shell would need it typed.
std::string ShellQuote(const std::vector<std::string>& argv);

}  // namespace ltb::pipeline
