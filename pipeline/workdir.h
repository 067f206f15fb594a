// The work directory of a bake (`ltbake run`): its lock, what is on disk at a step's output,
// the hashes of plain files, and removing an output. Everything here touches the disk; the
// decisions made from it are in pipeline/plan.h.
#pragma once

#include <cstdint>
#include <functional>
#include <string>
#include <system_error>

#include "format/io/file_lock.h"
#include "format/status.h"
#include "pipeline/graph.h"

namespace ltb::pipeline {

// The run report's file name in the work directory.
inline constexpr const char* kRunReport = "run.json";
// ... and as a page (pipeline/run_report.h), rewritten with it.
inline constexpr const char* kRunReportPage = "run.html";

// What is on disk at a node's output.
struct OutputState {
  bool exists = false;
  bool complete = false;    // sealed container, or an image file
  std::string fingerprint;  // stages::Fingerprint, or the image file's hash
  uint64_t committed = 0, total = 0;
  uint64_t bytes = 0;
  std::string problem;  // unreadable: why
};

// Looks at `path`, the output of `n` (a container, a stage manifest, or an image).
OutputState InspectOutput(const Node& n, const std::string& path);

// The local time, ISO 8601 with the UTC offset ("2026-11-26T01:43:35+0000").
std::string Now();

// Writes `text` to `path` atomically unless the file already holds exactly that.
Status WriteTextIfChanged(const std::string& path, const std::string& text);

// Holds the work directory for one bake at a time (io::FileLock, the same lock as a stage
// output's). The descriptor is inherited by the stage processes, so a stage orphaned by a
// killed run still holds it until it dies; for that the lock file is never removed.
Result<io::FileLock> LockWorkdir(const std::string& workdir, const std::function<int()>& pending_signal);

// Removes a step's output: the file, and for a stage manifest its shard directory.
void RemoveOutput(const std::string& path, std::error_code& ec);

}  // namespace ltb::pipeline
