#include "pipeline/workdir.h"

#include <xxhash.h>

#include <cstdio>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <vector>

#include "format/io/atomic_file.h"
#include "format/io/container_reader.h"
#include "format/io/file.h"
#include "format/io/file_hash.h"
#include "format/io/manifest.h"
#include "stages/common/basis.h"

namespace ltb::pipeline {

namespace fs = std::filesystem;

std::string Now() {
  std::time_t t = std::time(nullptr);
  char b[32];
  std::strftime(b, sizeof b, "%Y-%m-%dT%H:%M:%S%z", std::localtime(&t));
  return b;
}

OutputState InspectOutput(const Node& n, const std::string& path) {
  OutputState s;
  std::error_code ec;
  if (!fs::exists(path, ec)) return s;
  s.exists = true;
  s.bytes = fs::file_size(path, ec);
  if (n.image) {
    auto h = io::HashFileHex(path);
    s.complete = h.ok();
    if (h.ok()) s.fingerprint = *h;
    return s;
  }
  auto reader = io::ContainerReader::Open(path);
  if (!reader.ok()) {
    s.problem = reader.status().message();
    return s;
  }
  s.complete = reader->sealed();
  if (reader->is_manifest()) s.bytes = reader->file_size();  // the manifest and its shards
  for (uint32_t a = 0; a < reader->metadata().arrays.size(); ++a) {
    s.committed += reader->committed(a);
    s.total += reader->metadata().arrays[a].ChunkCount();
  }
  if (s.complete) s.fingerprint = stages::Fingerprint(*reader);
  return s;
}

Status WriteTextIfChanged(const std::string& path, const std::string& text) {
  std::ifstream in(path, std::ios::binary);
  if (in) {
    std::string old((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    if (old == text) return Status::Ok();
  }
  return io::WriteFileAtomically(path, text);
}

Result<io::FileLock> LockWorkdir(const std::string& workdir, const std::function<int()>& pending_signal) {
  io::LockOptions o;
  if (pending_signal) o.cancelled = [&pending_signal] { return pending_signal() != 0; };
  o.wait_seconds = 5;  // a run that is just finishing
  o.inherit = true;
  o.remove_on_release = false;
  o.busy_message = [&workdir](const std::string& holder) {
    return "work directory " + workdir + " is in use by " + holder +
           " (another `ltbake run`, or a stage it started that is still finishing); wait for it, or use another "
           "--workdir";
  };
  return io::FileLock::Acquire((fs::path(workdir) / ".ltbake-run.lock").string(), o);
}

void RemoveOutput(const std::string& path, std::error_code& ec) {
  fs::remove(path, ec);
  if (ec) return;
  const std::string dir = io::ShardDirectory(path);
  if (fs::exists(dir, ec)) fs::remove_all(dir, ec);
}

}  // namespace ltb::pipeline
