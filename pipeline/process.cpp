#include "pipeline/process.h"

#include <fcntl.h>
#include <poll.h>
#include <sys/prctl.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <csignal>
#include <cstring>
#include <fstream>

namespace ltb::pipeline {
namespace {

// Keeps the log free of progress-bar redraws: text up to a '\r' is dropped, a line is
// written when its '\n' arrives.
class LogSink {
 public:
  explicit LogSink(const std::string& path) : out_(path, std::ios::app) {}
  bool ok() const { return static_cast<bool>(out_); }
  void Add(std::string_view text) {
    for (char c : text) {
      if (c == '\r') {
        line_.clear();
      } else if (c == '\n') {
        out_ << line_ << '\n';
        line_.clear();
      } else {
        line_ += c;
      }
    }
    out_.flush();
  }
  void Close() {
    if (!line_.empty()) out_ << line_ << '\n';
    out_.flush();
  }

 private:
  std::ofstream out_;
  std::string line_;
};

}  // namespace

std::string ShellQuote(const std::vector<std::string>& argv) {
  std::string out;
  for (const auto& a : argv) {
    if (!out.empty()) out += ' ';
    bool plain = !a.empty();
    for (char c : a) {
      plain = plain && (std::isalnum(static_cast<unsigned char>(c)) || std::strchr("-_./=:,+%@", c) != nullptr);
    }
    if (plain) {
      out += a;
      continue;
    }
    out += '\'';
    for (char c : a) out += c == '\'' ? std::string("'\\''") : std::string(1, c);
    out += '\'';
  }
  return out;
}

namespace {

// In the forked child: dies with the parent, default SIGINT/SIGTERM, stdout and stderr into
// the pipes, then exec. Only async-signal-safe calls until exec.
[[noreturn]] void ExecChild(pid_t parent, int out_fd, int err_fd, char* const* args) {
  ::prctl(PR_SET_PDEATHSIG, SIGKILL);
  if (::getppid() != parent) ::_exit(127);  // the parent died before prctl took effect
  struct sigaction sa {};
  sa.sa_handler = SIG_DFL;
  ::sigaction(SIGINT, &sa, nullptr);
  ::sigaction(SIGTERM, &sa, nullptr);
  ::dup2(out_fd, 1);
  ::dup2(err_fd, 2);
  ::execv(args[0], args);
  const char msg[] = "ltbake: error: cannot execute the stage program\n";
  (void)!::write(2, msg, sizeof msg - 1);
  ::_exit(127);
}

// The child's stderr, split into lines (a \r starts a progress line over): each complete
// "ltbake: error: " line's message into errors; `line` carries the unfinished one.
void CollectErrorLines(std::string_view text, std::string* line, std::vector<std::string>* errors) {
  for (char c : text) {
    if (c == '\r') {
      line->clear();
    } else if (c == '\n') {
      if (line->rfind("ltbake: error: ", 0) == 0) errors->push_back(line->substr(15));
      line->clear();
    } else {
      *line += c;
    }
  }
}

// The reaped child's resource use and how it ended.
void SetUsageAndStatus(const struct rusage& ru, int status, ChildResult* result) {
  result->peak_rss_bytes = static_cast<uint64_t>(ru.ru_maxrss) * 1024;
  result->user_seconds = static_cast<double>(ru.ru_utime.tv_sec) + 1e-6 * static_cast<double>(ru.ru_utime.tv_usec);
  result->system_seconds = static_cast<double>(ru.ru_stime.tv_sec) + 1e-6 * static_cast<double>(ru.ru_stime.tv_usec);
  result->disk_read_bytes = static_cast<uint64_t>(ru.ru_inblock) * 512;
  result->disk_write_bytes = static_cast<uint64_t>(ru.ru_oublock) * 512;
  if (WIFEXITED(status)) result->exit_code = WEXITSTATUS(status);
  if (WIFSIGNALED(status)) result->term_signal = WTERMSIG(status);
}

}  // namespace

Result<ChildResult> RunChild(const std::vector<std::string>& argv, const ChildIo& io) {
  if (argv.empty()) return InvalidArgument("RunChild: empty command");
  LogSink log(io.log_path);
  if (!log.ok()) return IoError(io.log_path + ": cannot open the stage log for appending", errno);
  log.Add("$ " + ShellQuote(argv) + "\n");

  int out_pipe[2], err_pipe[2];
  if (::pipe2(out_pipe, O_CLOEXEC) != 0) return IoError("pipe", errno);
  if (::pipe2(err_pipe, O_CLOEXEC) != 0) {
    int e = errno;
    ::close(out_pipe[0]);
    ::close(out_pipe[1]);
    return IoError("pipe", e);
  }
  std::vector<char*> args;
  for (const auto& a : argv) args.push_back(const_cast<char*>(a.c_str()));
  args.push_back(nullptr);

  const pid_t parent = ::getpid();
  auto start = std::chrono::steady_clock::now();
  pid_t pid = ::fork();
  if (pid < 0) {
    int e = errno;
    for (int fd : {out_pipe[0], out_pipe[1], err_pipe[0], err_pipe[1]}) ::close(fd);
    return IoError("fork", e);
  }
  if (pid == 0) {
    ExecChild(parent, out_pipe[1], err_pipe[1], args.data());
  }
  ::close(out_pipe[1]);
  ::close(err_pipe[1]);

  ChildResult result;
  std::string err_line;
  bool forwarded = false, killed = false;
  std::chrono::steady_clock::time_point forwarded_at, killed_at;
  auto seconds_since = [](std::chrono::steady_clock::time_point t) {
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - t).count();
  };
  struct pollfd fds[2] = {{out_pipe[0], POLLIN, 0}, {err_pipe[0], POLLIN, 0}};
  int open_fds = 2;
  char buf[1 << 14];
  while (open_fds > 0) {
    if (!forwarded && io.pending_signal) {
      if (int sig = io.pending_signal(); sig != 0) {
        ::kill(pid, sig);
        forwarded = true;
        forwarded_at = std::chrono::steady_clock::now();
      }
    }
    if (!killed && ((forwarded && seconds_since(forwarded_at) > io.kill_after_seconds) ||
                    (io.deadline_seconds > 0 && seconds_since(start) > io.deadline_seconds))) {
      ::kill(pid, SIGKILL);  // its pipes close as it dies; wait4 below reaps it
      killed = true;
      killed_at = std::chrono::steady_clock::now();
    }
    if (killed && seconds_since(killed_at) > 2) break;  // a grandchild may still hold the pipes
    int n = ::poll(fds, 2, 100);
    if (n < 0) {
      if (errno == EINTR) continue;
      break;
    }
    for (int i = 0; i < 2; ++i) {
      if (fds[i].fd < 0 || (fds[i].revents & (POLLIN | POLLHUP | POLLERR)) == 0) continue;
      ssize_t got = ::read(fds[i].fd, buf, sizeof buf);
      if (got < 0 && errno == EINTR) continue;
      if (got <= 0) {
        ::close(fds[i].fd);
        fds[i].fd = -1;
        --open_fds;
        continue;
      }
      std::string_view text(buf, static_cast<size_t>(got));
      log.Add(text);
      if (i == 0) {
        result.stdout_text.append(text);
        if (io.on_stdout) io.on_stdout(text);
      } else {
        if (io.on_stderr) io.on_stderr(text);
        CollectErrorLines(text, &err_line, &result.errors);
      }
    }
  }
  for (auto& f : fds) {
    if (f.fd >= 0) ::close(f.fd);
  }
  int status = 0;
  struct rusage ru {};
  pid_t w;
  do {
    w = ::wait4(pid, &status, 0, &ru);
    if (w < 0 && errno == EINTR && !forwarded && io.pending_signal) {
      if (int sig = io.pending_signal(); sig != 0) {
        ::kill(pid, sig);
        forwarded = true;
      }
    }
  } while (w < 0 && errno == EINTR);
  log.Close();
  if (w < 0) return IoError("wait4 for " + argv[0], errno);
  if (err_line.rfind("ltbake: error: ", 0) == 0) result.errors.push_back(err_line.substr(15));
  result.wall_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  SetUsageAndStatus(ru, status, &result);
  return result;
}

}  // namespace ltb::pipeline
