// Shared pieces of the command-line mains: common flags, size parsing, progress bar,
// signal handling and the Status -> exit code mapping (DESIGN.md "CLI contract").
#pragma once

#include <CLI/CLI.hpp>
#include <chrono>
#include <cstdint>
#include <glm/vec3.hpp>
#include <mutex>
#include <string>

#include "format/io/manifest.h"
#include "format/progress.h"
#include "format/status.h"
#include "stages/common/quantity.h"

namespace ltb::cli {

// The exit codes (README "CLI contract"), and the one table that maps how a command ended
// to them: every command returns kExitOk, ReportUsage(), ReportFailure() or ExitCodeFor().
inline constexpr int kExitOk = 0;
inline constexpr int kExitFailed = 1;  // bad input, I/O, corruption, a stage of a bake failed
inline constexpr int kExitUsage = 2;   // bad flags or values (found while parsing or after), a bad recipe
inline constexpr int kExitSigint = 130;
inline constexpr int kExitSigterm = 143;

enum class Ending { kOk, kFailed, kUsage, kInterrupted };
// kInterrupted: 143 after SIGTERM, 130 after SIGINT (or a cancellation without a signal).
int ExitCodeFor(Ending ending, int signal = 0);
// How a command that failed with `status` ended: interrupted when the status says cancelled
// or a signal was received, failed otherwise.
Ending EndingOf(const Status& status);

struct CommonFlags {
  int jobs = 2;
  std::string mem_limit = "1GiB";
  std::string progress = "auto";  // auto | always | never
  bool quiet = false;
  int verbose = 0;
};

// Adds --jobs, --mem-limit, --progress, -q, -v to a subcommand.
void AddCommonFlags(CLI::App* app, CommonFlags* flags);

// --shard I --nshards N: which slice of its output a stage writes (format/io/manifest.h).
struct ShardFlags {
  int64_t shard = -1;    // -1: not given
  int64_t nshards = -1;  // -1: not given
};
void AddShardFlags(CLI::App* app, ShardFlags* flags);
// The flags, each defaulting from the Slurm job array's SLURM_ARRAY_TASK_ID /
// SLURM_ARRAY_TASK_COUNT when set; neither given nor set: the whole output.
Result<io::ShardSpec> ResolveShard(const ShardFlags& flags);
// "OUT", or "shard I of N of OUT (its file)" for the messages of a stage.
std::string OutputName(const std::string& output, const io::ShardSpec& shard);

// The flags every stage command resolves before it runs, parsed: --jobs, --mem-limit and
// (for stages that write shards) the shard.
struct StageFlags {
  int jobs = 2;
  uint64_t mem_limit = 0;
  io::ShardSpec shard;  // the whole output unless --shard/--nshards (or Slurm's) say otherwise
};
// Resolves them; `shard_flags` may be null (a stage without shards). On a bad value prints
// the usage error and returns kExitUsage, else kExitOk:
//   if (int code = ResolveStageFlags(flags_, &shard_flags_, &sf); code != kExitOk) return code;
int ResolveStageFlags(const CommonFlags& flags, const ShardFlags* shard_flags, StageFlags* out);

// "812 B", "3.4 KiB", "71.2 MiB", "1.25 GiB": sizes as the commands print them.
std::string HumanBytes(uint64_t bytes);

// Flag validators, so a bad value is a usage error (exit 2) found while parsing, with the
// flag and the value named ("--mem-limit: size \"0\" is ..."), before any file is opened.
// A size, as stages::ParseByteSize takes it ("1GiB", "512M", "4096").
CLI::Validator SizeCheck();
// A power of two in [1, max].
CLI::Validator PowerOfTwoCheck(uint64_t max);
// A decimal number in [min, max], as stages::ParseDecimal takes it ("-12.5", "2e3"; not
// "nan", "inf", "0x10" or "1e20" when max is smaller). Give the option a std::string and read
// it with stages::ParseDecimal after parsing, so that the flag and the check agree.
CLI::Validator DecimalCheck(double min, double max);
// A fraction in (0, 1], as stages::ParseFraction takes it ("0.05", "5%").
CLI::Validator FractionCheck();
// A nonzero budget, as stages::ParseBudget takes it ("2%", "150000", "64MiB").
CLI::Validator BudgetCheck();
// A number of terms: an integer >= 1, or "all".
CLI::Validator TermsCheck();

// Camera coordinates: anything a scene could hold, with room to square it.
inline constexpr double kMaxCoordinate = 1e30;
// "X,Y,Z" -> vector; false when it is not three decimal numbers within ±kMaxCoordinate.
bool ParseVec3(const std::string& text, glm::dvec3* out);
// "WIDTHxHEIGHT" (each 1..16384) of a view; false otherwise.
bool ParseViewSize(const std::string& text, uint32_t* width, uint32_t* height);

// For usage errors found after parsing: prints "ltbake: usage error: MESSAGE" and a pointer
// to --help on stderr, returns kExitUsage (2).
int ReportUsage(const Status& status);

// Installs SIGINT/SIGTERM handlers that ask running work to stop and commit.
void InstallSignalHandlers();
int ReceivedSignal();

// Prints the error to stderr and returns the exit code: 130/143 after SIGINT/SIGTERM,
// 1 otherwise.
int ReportFailure(const Status& status);
// Set by `ltbake run` to its PID for the stages it starts (see ReportFailure).
inline constexpr const char* kRunPidVariable = "LTBAKE_RUN_PID";

// A progress bar on stderr: only on a TTY unless --progress always; at most ~6 updates/s;
// shows rate and ETA.
class ProgressBar {
 public:
  ProgressBar(const CommonFlags& flags, std::string label);
  ~ProgressBar();
  // The callback struct handed to libraries (also carries cancellation).
  Progress hook();
  void Done();

 private:
  void Update(uint64_t done, uint64_t total, const char* unit);
  bool enabled_;
  std::string label_;
  std::mutex mu_;
  std::chrono::steady_clock::time_point start_, last_;
  // The phase being shown (its unit): a new unit starts the rate (and so the ETA) afresh, so
  // that loading a mesh does not count against the rays traced after it.
  std::string unit_;
  bool drawn_ = false;
};

}  // namespace ltb::cli
