#include "cli/common.h"

#include <unistd.h>

#include <atomic>
#include <cctype>
#include <cerrno>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <iostream>

namespace ltb::cli {

namespace {
std::atomic<int> g_signal{0};  // signal handlers can only reach a global

void OnSignal(int sig) { g_signal.store(sig); }
}  // namespace

void AddCommonFlags(CLI::App* app, CommonFlags* f) {
  app->add_option("--jobs,-j", f->jobs, "worker threads")->default_val(2)->check(CLI::Range(1, 1024));
  app->add_option("--mem-limit", f->mem_limit, "memory budget for buffers, e.g. 512MiB, 4GiB")
      ->default_val("1GiB")
      ->check(SizeCheck());
  app->add_option("--progress", f->progress, "progress bar on stderr")
      ->default_val("auto")
      ->check(CLI::IsMember({"auto", "always", "never"}));
  app->add_flag("-q,--quiet", f->quiet, "print only errors");
  app->add_flag("-v,--verbose", f->verbose, "print more detail");
}

void AddShardFlags(CLI::App* app, ShardFlags* f) {
  app->add_option("--shard", f->shard,
                  "write shard I of --nshards (default: $SLURM_ARRAY_TASK_ID); `ltbake commit` joins the shards")
      ->check(CLI::Range(int64_t{0}, static_cast<int64_t>(format::kMaxShards) - 1));
  app->add_option("--nshards", f->nshards, "split the output into N shards (default: $SLURM_ARRAY_TASK_COUNT, else 1)")
      ->check(CLI::Range(int64_t{1}, static_cast<int64_t>(format::kMaxShards)));
}

Result<io::ShardSpec> ResolveShard(const ShardFlags& f) {
  auto from_env = [](const char* name, int64_t* out) -> Status {
    const char* v = std::getenv(name);
    if (v == nullptr || *v == '\0') return Status::Ok();
    char* end = nullptr;
    long long n = std::strtoll(v, &end, 10);
    if (*end != '\0' || n < 0) return InvalidArgument(std::string("$") + name + " is \"" + v + "\", not a number");
    *out = n;
    return Status::Ok();
  };
  int64_t index = f.shard, count = f.nshards;
  const bool index_from_env = index < 0, count_from_env = count < 0;
  if (index < 0) LTB_RETURN_IF_ERROR(from_env("SLURM_ARRAY_TASK_ID", &index));
  if (count < 0) LTB_RETURN_IF_ERROR(from_env("SLURM_ARRAY_TASK_COUNT", &count));
  if (count < 0) count = 1;
  if (index < 0) index = 0;
  if (count < 1 || count > static_cast<int64_t>(format::kMaxShards)) {
    return InvalidArgument("--nshards " + std::to_string(count) + " (from $SLURM_ARRAY_TASK_COUNT): expected 1.." +
                           std::to_string(format::kMaxShards));
  }
  if (index >= count) {
    std::string src = std::string(index_from_env ? "$SLURM_ARRAY_TASK_ID" : "--shard") + " " + std::to_string(index) +
                      " is not below " + (count_from_env ? "$SLURM_ARRAY_TASK_COUNT" : "--nshards") + " " +
                      std::to_string(count);
    return InvalidArgument(src + (count_from_env ? "; a job array that runs only some of the shards (e.g. "
                                                   "--array=2) must pass --nshards N"
                                                 : ""));
  }
  return io::ShardSpec{static_cast<uint64_t>(index), static_cast<uint64_t>(count)};
}

std::string OutputName(const std::string& output, const io::ShardSpec& shard) {
  if (!shard.sharded()) return output;
  return "shard " + std::to_string(shard.index) + " of " + std::to_string(shard.count) + " of " + output + " (" +
         io::ShardPath(output, shard.index, shard.count) + ")";
}

namespace {

// A validator from a stages:: parser: the parser's message on failure.
template <typename Parse>
CLI::Validator ParsedCheck(Parse parse, const char* name) {
  return CLI::Validator(
      [parse](std::string& text) -> std::string {
        auto r = parse(text);
        return r.ok() ? std::string() : r.status().message();
      },
      name);
}

// A decimal integer in [1, max] written with digits only; false otherwise.
bool ParseCount(const std::string& text, uint64_t max, uint64_t* value) {
  char* end = nullptr;
  errno = 0;
  const unsigned long long v = std::strtoull(text.c_str(), &end, 10);
  if (text.empty() || !std::isdigit(static_cast<unsigned char>(text[0])) || *end != '\0' || errno != 0 || v == 0 ||
      v > max) {
    return false;
  }
  *value = v;
  return true;
}

}  // namespace

std::string HumanBytes(uint64_t b) {
  char s[32];
  if (b >= (1ull << 30))
    std::snprintf(s, sizeof s, "%.2f GiB", b / double(1ull << 30));
  else if (b >= (1ull << 20))
    std::snprintf(s, sizeof s, "%.1f MiB", b / double(1ull << 20));
  else if (b >= 1024)
    std::snprintf(s, sizeof s, "%.1f KiB", b / 1024.0);
  else
    std::snprintf(s, sizeof s, "%llu B", static_cast<unsigned long long>(b));
  return s;
}

CLI::Validator SizeCheck() { return ParsedCheck(stages::ParseByteSize, "SIZE"); }
CLI::Validator FractionCheck() { return ParsedCheck(stages::ParseFraction, "FRACTION"); }
CLI::Validator BudgetCheck() { return ParsedCheck(stages::ParseBudget, "BUDGET"); }

CLI::Validator DecimalCheck(double min, double max) {
  return ParsedCheck([min, max](const std::string& text) { return stages::ParseDecimal(text, min, max); }, "NUMBER");
}

CLI::Validator PowerOfTwoCheck(uint64_t max) {
  return CLI::Validator(
      [max](std::string& text) -> std::string {
        uint64_t v = 0;
        if (!ParseCount(text, max, &v) || (v & (v - 1)) != 0) {
          return "\"" + text + "\" is not a power of two in 1.." + std::to_string(max);
        }
        return std::string();
      },
      "POW2");
}

CLI::Validator TermsCheck() {
  return CLI::Validator(
      [](std::string& text) -> std::string {
        uint64_t v = 0;
        if (text != "all" && !ParseCount(text, uint64_t{1} << 62, &v)) {
          return "\"" + text + "\" is not a number of terms (1, 2, ... or all; 0 would relight nothing)";
        }
        return std::string();
      },
      "N|all");
}

int ResolveStageFlags(const CommonFlags& flags, const ShardFlags* shard_flags, StageFlags* out) {
  if (shard_flags != nullptr) {
    auto shard = ResolveShard(*shard_flags);
    if (!shard.ok()) return ReportUsage(shard.status());
    out->shard = *shard;
  }
  auto mem = stages::ParseByteSize(flags.mem_limit);
  if (!mem.ok()) return ReportUsage(mem.status().WithContext("--mem-limit"));
  out->mem_limit = *mem;
  out->jobs = flags.jobs;
  return kExitOk;
}

int ExitCodeFor(Ending ending, int signal) {
  switch (ending) {
    case Ending::kOk:
      return kExitOk;
    case Ending::kFailed:
      return kExitFailed;
    case Ending::kUsage:
      return kExitUsage;
    case Ending::kInterrupted:
      return signal == SIGTERM ? kExitSigterm : kExitSigint;
  }
  return kExitFailed;
}

Ending EndingOf(const Status& status) {
  if (status.ok()) return Ending::kOk;
  return status.code() == StatusCode::kCancelled || ReceivedSignal() != 0 ? Ending::kInterrupted : Ending::kFailed;
}

int ReportUsage(const Status& status) {
  std::cerr << "ltbake: usage error: " << status.message() << "\n"
            << "Run 'ltbake --help' (or 'ltbake COMMAND --help') for usage.\n";
  return ExitCodeFor(Ending::kUsage);
}

void InstallSignalHandlers() {
  struct sigaction sa {};
  sa.sa_handler = OnSignal;
  sigemptyset(&sa.sa_mask);
  sigaction(SIGINT, &sa, nullptr);
  sigaction(SIGTERM, &sa, nullptr);
}

int ReceivedSignal() { return g_signal.load(); }

int ReportFailure(const Status& status) {
  const Ending ending = EndingOf(status);
  const bool interrupted = ending == Ending::kInterrupted;
  // A stage started by `ltbake run` leaves an interruption to its parent, which says what
  // stopped and how to resume the bake (one message, not two).
  const char* run_pid = std::getenv(kRunPidVariable);
  const bool child_of_run = run_pid != nullptr && std::to_string(::getpid()) != run_pid;
  if (!(interrupted && child_of_run)) std::cerr << "ltbake: error: " << status.message() << "\n";
  return ExitCodeFor(ending, ReceivedSignal());
}

ProgressBar::ProgressBar(const CommonFlags& flags, std::string label) : label_(std::move(label)) {
  enabled_ = !flags.quiet && (flags.progress == "always" || (flags.progress == "auto" && ::isatty(2)));
  start_ = last_ = std::chrono::steady_clock::now();
}

ProgressBar::~ProgressBar() { Done(); }

Progress ProgressBar::hook() {
  Progress p;
  p.update = [this](uint64_t done, uint64_t total, const char* unit) { Update(done, total, unit); };
  p.cancelled = [] { return ReceivedSignal() != 0; };
  return p;
}

void ProgressBar::Update(uint64_t done, uint64_t total, const char* unit) {
  if (!enabled_) return;
  std::lock_guard<std::mutex> lock(mu_);
  auto now = std::chrono::steady_clock::now();
  if (unit_ != unit) {  // another phase: its own rate
    unit_ = unit;
    start_ = now;
  }
  if (done < total && now - last_ < std::chrono::milliseconds(160)) return;
  last_ = now;
  double secs = std::chrono::duration<double>(now - start_).count();
  double rate = secs > 0 ? static_cast<double>(done) / secs : 0;
  double frac = total ? static_cast<double>(done) / static_cast<double>(total) : 1;
  int width = 24, filled = static_cast<int>(frac * width);
  std::string bar(filled, '#');
  bar.resize(width, ' ');
  char eta[32] = "";
  if (rate > 0 && done < total) std::snprintf(eta, sizeof eta, " ETA %.0fs", static_cast<double>(total - done) / rate);
  std::fprintf(stderr, "\r%s [%s] %3.0f%% %llu/%llu %s, %.1f %s/s%s   ", label_.c_str(), bar.c_str(), frac * 100,
               static_cast<unsigned long long>(done), static_cast<unsigned long long>(total), unit, rate, unit, eta);
  drawn_ = true;
}

void ProgressBar::Done() {
  std::lock_guard<std::mutex> lock(mu_);
  if (drawn_) std::fprintf(stderr, "\n");
  drawn_ = false;
}

bool ParseVec3(const std::string& text, glm::dvec3* out) {
  double v[3];
  size_t pos = 0;
  for (int k = 0; k < 3; ++k) {
    const size_t end = k < 2 ? text.find(',', pos) : text.size();
    if (end == std::string::npos) return false;
    auto parsed = stages::ParseDecimal(text.substr(pos, end - pos), -kMaxCoordinate, kMaxCoordinate);
    if (!parsed.ok()) return false;
    v[k] = *parsed;
    pos = end + 1;
  }
  *out = glm::dvec3(v[0], v[1], v[2]);
  return true;
}

bool ParseViewSize(const std::string& text, uint32_t* width, uint32_t* height) {
  unsigned w = 0, h = 0;
  char tail = 0;
  if (std::sscanf(text.c_str(), "%ux%u%c", &w, &h, &tail) != 2 || w == 0 || h == 0 || w > 16384 || h > 16384)
    return false;
  *width = w;
  *height = h;
  return true;
}

}  // namespace ltb::cli
