// Crash consistency proven over every crash point, not sampled (issue 36, item 16).
//
// The writers' I/O is recorded (io::SetIoRecorder: every write, truncate, fdatasync, create,
// rename, remove and directory sync, in order). Each prefix of that sequence is replayed into
// a fresh directory as a crash there would leave the disk, under five models:
//   kill        the process died: every call made so far reached the page cache (it survives);
//   torn        the same, and the call in flight, a write, landed half;
//   power-names power lost: a file holds what it held at its last fdatasync, a directory the
//               names it had at its last fsync (creations and renames since are gone);
//   power-data  power lost with the names journaled: every name change stands, but file data
//               is as of the last fdatasync (the zero-length-file-after-rename hazard);
//   power-mix   as power-data, but each unsynced write independently kept or lost (reordering;
//               three seeds).
// From each disk the writer runs again (resume) and the outcome is classified: clean (the
// output equals the reference), loud (the writer or a reader refuses, naming the damage), or
// silent (wrong data accepted). Crash points after the writer returned success are held to
// more: the output must already be whole there, under every model ("acknowledged" data is
// never lost). Then each durability barrier is switched off in turn, and the same replay
// must find a violation for it — the harness has teeth.
#include <gtest/gtest.h>

#include <algorithm>
#include <cctype>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <map>
#include <mutex>
#include <optional>
#include <random>
#include <set>
#include <string>
#include <vector>

#include "format/io/atomic_file.h"
#include "format/io/container_reader.h"
#include "format/io/container_writer.h"
#include "format/io/io_trace.h"
#include "format/io/manifest.h"
#include "test_util.h"

namespace ltb {
namespace crash_replay {  // its own names: the unity build shares one file with other tests
namespace {

namespace fs = std::filesystem;
using io::IoOp;

class Recorder : public io::IoRecorder {
 public:
  void Record(IoOp op) override {
    std::lock_guard<std::mutex> lock(mu_);
    ops_.push_back(std::move(op));
  }
  std::vector<IoOp> Take() {
    std::lock_guard<std::mutex> lock(mu_);
    return std::move(ops_);
  }

 private:
  std::mutex mu_;
  std::vector<IoOp> ops_;
};

enum class Model { kKill, kTorn, kPowerNames, kPowerData, kPowerMix };
const char* ModelName(Model m) {
  switch (m) {
    case Model::kKill:
      return "kill";
    case Model::kTorn:
      return "torn";
    case Model::kPowerNames:
      return "power-names";
    case Model::kPowerData:
      return "power-data";
    case Model::kPowerMix:
      return "power-mix";
  }
  return "?";
}

// The disk as the ops leave it: names -> inode, each inode's bytes now and as last synced.
struct Disk {
  struct Inode {
    std::vector<std::byte> data, synced;
    std::vector<std::pair<size_t, IoOp>> unsynced;  // writes and truncates since the last sync
  };
  std::vector<Inode> inodes;
  std::map<std::string, size_t> names, durable_names;

  size_t Lookup(const std::string& path) {
    auto it = names.find(path);
    if (it != names.end()) return it->second;
    inodes.emplace_back();  // a file the test did not see created: make it exist, empty
    names[path] = durable_names[path] = inodes.size() - 1;
    return inodes.size() - 1;
  }
  static void Apply(std::vector<std::byte>& d, const IoOp& op, size_t keep) {
    if (op.kind == IoOp::Kind::kTruncate) {
      d.resize(op.offset);
    } else {
      if (d.size() < op.offset + keep) d.resize(op.offset + keep);
      std::copy(op.data.begin(), op.data.begin() + static_cast<long>(keep), d.begin() + static_cast<long>(op.offset));
    }
  }
  void Do(const IoOp& op, size_t index, size_t keep) {
    switch (op.kind) {
      case IoOp::Kind::kCreate:
        if (!names.count(op.path)) {
          inodes.emplace_back();
          names[op.path] = inodes.size() - 1;
        }
        break;
      case IoOp::Kind::kWrite:
      case IoOp::Kind::kTruncate: {
        Inode& n = inodes[Lookup(op.path)];
        Apply(n.data, op, keep);
        n.unsynced.push_back({index, op});
        break;
      }
      case IoOp::Kind::kSync: {
        Inode& n = inodes[Lookup(op.path)];
        n.synced = n.data;
        n.unsynced.clear();
        break;
      }
      case IoOp::Kind::kRename: {
        const size_t id = Lookup(op.path);
        names.erase(op.path);
        names[op.to] = id;
        break;
      }
      case IoOp::Kind::kRemove:
        names.erase(op.path);
        break;
      case IoOp::Kind::kSyncDir: {
        const std::string dir = op.path + "/";
        for (auto it = durable_names.begin(); it != durable_names.end();) {
          it = it->first.starts_with(dir) ? durable_names.erase(it) : std::next(it);
        }
        for (const auto& [name, id] : names) {
          if (name.starts_with(dir)) durable_names[name] = id;
        }
        break;
      }
    }
  }
};

// The files a crash after ops[0..k) leaves (op k torn in half under kTorn), as name -> bytes.
std::map<std::string, std::vector<std::byte>> CrashState(const std::map<std::string, std::vector<std::byte>>& before,
                                                         const std::vector<IoOp>& ops, size_t k, Model model,
                                                         uint32_t seed) {
  Disk disk;
  for (const auto& [name, bytes] : before) {
    disk.inodes.push_back({bytes, bytes, {}});
    disk.names[name] = disk.durable_names[name] = disk.inodes.size() - 1;
  }
  for (size_t i = 0; i < k; ++i) disk.Do(ops[i], i, ops[i].data.size());
  if (model == Model::kTorn && k < ops.size() && ops[k].kind == IoOp::Kind::kWrite) {
    disk.Do(ops[k], k, ops[k].data.size() / 2);
  }
  std::mt19937 rng(seed);
  std::map<std::string, std::vector<std::byte>> out;
  const auto& names = model == Model::kPowerNames ? disk.durable_names : disk.names;
  for (const auto& [name, id] : names) {
    const Disk::Inode& n = disk.inodes[id];
    if (model == Model::kKill || model == Model::kTorn) {
      out[name] = n.data;
    } else if (model == Model::kPowerMix) {
      std::vector<std::byte> d = n.synced;
      for (const auto& [index, op] : n.unsynced) {
        if (rng() % 2 == 0) Disk::Apply(d, op, op.kind == IoOp::Kind::kWrite ? op.data.size() : 0);
      }
      out[name] = std::move(d);
    } else {
      out[name] = n.synced;
    }
  }
  return out;
}

void Materialize(const std::map<std::string, std::vector<std::byte>>& files, const std::string& from,
                 const std::string& to) {
  for (const auto& [name, bytes] : files) {
    if (!name.starts_with(from)) continue;  // outside the test's directory (none expected)
    const fs::path target = to + name.substr(from.size());
    fs::create_directories(target.parent_path());
    std::ofstream f(target, std::ios::binary | std::ios::trunc);
    f.write(reinterpret_cast<const char*>(bytes.data()), static_cast<std::streamsize>(bytes.size()));
  }
}

std::map<std::string, std::vector<std::byte>> Snapshot(const std::string& dir) {
  std::map<std::string, std::vector<std::byte>> out;
  for (const auto& e : fs::recursive_directory_iterator(dir)) {
    if (!e.is_regular_file()) continue;
    std::vector<char> b = test::ReadFileBytes(e.path().string());
    out[e.path().string()] = std::vector<std::byte>(reinterpret_cast<std::byte*>(b.data()),
                                                    reinterpret_cast<std::byte*>(b.data()) + b.size());
  }
  return out;
}

struct Tally {
  int clean = 0, loud = 0, silent = 0, lost = 0;
  std::map<std::string, int> loud_reasons;  // the refusal's message (its path cut), how often
  std::vector<std::string> violations;      // silent and lost cases, described
  bool Violated() const { return silent + lost > 0; }
};

// --- the container writer: a matrix and a side table, a zstd chunk among them ----------------
constexpr uint64_t kRows = 48, kCols = 16, kBlock = 8;

nlohmann::json Meta() {
  nlohmann::json m = test::MatrixMetadata(kRows, kCols, format::Layout::kRows, kBlock);
  format::ArraySpec side;
  side.name = "side";
  side.rows = kRows;
  side.cols = 1;
  side.block = 16;
  m["arrays"].push_back(side.ToJson());
  return m;
}

// Writes (or resumes) the container at path; Ok when it is sealed.
Status WriteContainer(const std::string& path) {
  const std::vector<float> m = test::MakeMatrix(kRows, kCols, 11), s = test::MakeMatrix(kRows, 1, 12);
  io::WriterOptions wo;  // direct_io off: every write goes through File (and the recorder)
  LTB_ASSIGN_OR_RETURN(io::ContainerWriter w, io::ContainerWriter::Open(path, Meta(), wo));
  for (uint32_t a = 0; a < 2; ++a) {
    const format::ArraySpec& spec = w.metadata().arrays[a];
    for (uint64_t c = 0; c < spec.ChunkCount(); ++c) {
      if (w.Has(a, c)) continue;
      format::EncodeOptions eo;
      eo.zstd = c == 1;  // the pattern rows compress
      LTB_RETURN_IF_ERROR(w.Put(a, c, test::AsBytes(test::ChunkValues(spec, a == 0 ? m : s, c)), eo));
    }
  }
  return w.Finish();
}

// Whether the file at path holds exactly the reference content, sealed and verifying (every
// checksum, and each array's content_hash recomputed against the recorded one).
bool HoldsReference(const std::string& path, const std::string& /*reference_hash*/) {
  auto r = io::ContainerReader::Open(path);
  if (!r.ok() || !r->sealed() || !r->complete() || !r->problems().empty()) return false;
  auto v = io::LooksLikeManifest(path) ? io::VerifyManifest(path, 1) : io::VerifyContainer(path, 1);
  if (!v.problems.empty() || !v.complete) return false;
  const std::vector<float> m = test::MakeMatrix(kRows, kCols, 11), s = test::MakeMatrix(kRows, 1, 12);
  for (uint32_t a = 0; a < 2; ++a) {
    const format::ArraySpec& spec = r->metadata().arrays[a];
    for (uint64_t c = 0; c < spec.ChunkCount(); ++c) {
      auto chunk = r->ReadChunk(a, c);
      const std::vector<float> want = test::ChunkValues(spec, a == 0 ? m : s, c);
      if (!chunk.ok() || chunk->bytes().size() != want.size() * 4 ||
          std::memcmp(chunk->bytes().data(), want.data(), want.size() * 4) != 0) {
        return false;
      }
    }
  }
  return true;
}

// Every crash state of ops (recorded in `dir`, over the files `before`), materialised in a
// directory of its own: after the writer returned (k >= ack) `output` (relative to it) must
// hold the reference already; otherwise `resume(root)`, the same command run again there,
// must give the reference (clean) or refuse (loud), never succeed with other content.
Tally Replay(const std::map<std::string, std::vector<std::byte>>& before, const std::vector<IoOp>& ops, size_t ack,
             const std::string& dir, const std::string& output, uint32_t mix_seeds,
             const std::function<Status(const std::string& root)>& resume) {
  Tally t;
  for (size_t k = 0; k <= ops.size(); ++k) {
    for (Model model : {Model::kKill, Model::kTorn, Model::kPowerNames, Model::kPowerData, Model::kPowerMix}) {
      if (model == Model::kTorn && (k == ops.size() || ops[k].kind != IoOp::Kind::kWrite)) continue;
      for (uint32_t seed = 0; seed < (model == Model::kPowerMix ? mix_seeds : 1u); ++seed) {
        test::TempDir replay;
        const std::string base = replay.File("");
        const std::string root = base.substr(0, base.size() - 1);
        Materialize(CrashState(before, ops, k, model, seed), dir, root);
        const std::string path = root + "/" + output;
        const std::string what = std::string(ModelName(model)) + " after op " + std::to_string(k) + "/" +
                                 std::to_string(ops.size()) + (seed ? " seed " + std::to_string(seed) : "");
        if (k >= ack && !HoldsReference(path, "")) {
          ++t.lost;
          t.violations.push_back(what + ": the writer had returned success, the output is not whole");
          continue;
        }
        Status s = resume(root);
        if (!s.ok()) {
          ++t.loud;  // refused, naming the damage (the file is left as it was)
          std::string m = s.message();
          for (size_t at; (at = m.find(root)) != std::string::npos;) m.erase(at, root.size());
          for (char& c : m) c = std::isdigit(static_cast<unsigned char>(c)) ? '#' : c;
          t.loud_reasons[what.substr(0, what.find(' ')) + ": " + m]++;
        } else if (HoldsReference(path, "")) {
          ++t.clean;
        } else {
          ++t.silent;
          t.violations.push_back(what + ": resumed without an error to content other than the reference");
        }
      }
    }
  }
  return t;
}

Tally ReplayContainer(const std::vector<IoOp>& ops, size_t ack, const std::string& dir,
                      const std::string& /*reference_hash*/, uint32_t mix_seeds = 3) {
  return Replay({}, ops, ack, dir, "out.ltm", mix_seeds,
                [](const std::string& root) { return WriteContainer(root + "/out.ltm"); });
}

struct Recorded {
  std::vector<IoOp> ops;
  size_t ack = 0;  // ops[0..ack) were done when the writer returned success
  std::string dir, reference_hash;
};

Recorded RecordContainer(const test::TempDir& dir, unsigned skipped) {
  Recorded r;
  r.dir = dir.File("");
  r.dir.pop_back();
  Recorder rec;
  io::SetSkippedBarriers(skipped);
  io::SetIoRecorder(&rec);
  Status s = WriteContainer(r.dir + "/out.ltm");
  r.ops = rec.Take();
  io::SetIoRecorder(nullptr);
  io::SetSkippedBarriers(0);
  EXPECT_TRUE(s.ok()) << s.message();
  r.ack = r.ops.size();
  EXPECT_TRUE(HoldsReference(r.dir + "/out.ltm", ""));
  return r;
}

TEST(CrashReplay, EveryCrashPointOfAContainerWriterResumesOrRefusesNeverSilently) {
  test::TempDir dir;
  Recorded r = RecordContainer(dir, 0);
  ASSERT_GT(r.ops.size(), 20u);
  Tally t = ReplayContainer(r.ops, r.ack, r.dir, r.reference_hash);
  std::string v;
  for (const auto& s : t.violations) v += "\n  " + s;
  EXPECT_FALSE(t.Violated()) << t.silent << " silent, " << t.lost << " lost:" << v;
  EXPECT_GT(t.clean, 0);
  RecordProperty("ops", static_cast<int>(r.ops.size()));
  RecordProperty("clean", t.clean);
  RecordProperty("loud", t.loud);
  std::printf("container writer: %zu ops, %d crash states clean, %d loud, %d silent, %d lost\n", r.ops.size(), t.clean,
              t.loud, t.silent, t.lost);
  for (const auto& [m, count] : t.loud_reasons) std::printf("  loud x%d: %s\n", count, m.c_str());
}

// The replay notices each barrier missing. Without the seal's fdatasync a sealed output can
// be lost to power after the writer returned; without the AtomicFile's directory sync the
// container's name can be; without the AtomicFile's fdatasync the header it starts as can be
// renamed into place empty, which no data loss follows from but which turns resumes into
// refusals ("exists and is not a readable .ltm container": the user must remove the file) —
// noticed as more loud states than with every barrier in place. Writing a chunk's header
// before its payload lets a kill between them leave a committed chunk of zeros.
TEST(CrashReplay, TheReplayFindsEachBarrierOfTheContainerWriterMissing) {
  test::TempDir base_dir;
  Recorded base = RecordContainer(base_dir, 0);
  const Tally all = ReplayContainer(base.ops, base.ack, base.dir, base.reference_hash, 1);
  for (unsigned barrier :
       {io::kBarrierSealSync, io::kBarrierAtomicDataSync, io::kBarrierAtomicDirSync, io::kBarrierHeaderLast}) {
    test::TempDir dir;
    Recorded r = RecordContainer(dir, barrier);
    Tally t = ReplayContainer(r.ops, r.ack, r.dir, r.reference_hash, 1);  // one mixed state a point is enough here
    std::printf("container writer without barrier %u: %d clean, %d loud, %d silent, %d lost (every barrier: %d loud)\n",
                barrier, t.clean, t.loud, t.silent, t.lost, all.loud);
    EXPECT_TRUE(t.Violated() || t.loud > all.loud) << "barrier " << barrier << " removed, and no crash state shows it";
  }
}

// --- a sharded output: its commit (the manifest) and its merge into one container ----------
// The same content as WriteContainer's, as two shards written through OpenStageOutput.
Status WriteShards(const std::string& out) {
  const std::vector<float> m = test::MakeMatrix(kRows, kCols, 11), s = test::MakeMatrix(kRows, 1, 12);
  for (uint64_t i = 0; i < 2; ++i) {
    LTB_ASSIGN_OR_RETURN(io::ContainerWriter w, io::OpenStageOutput(out, Meta(), {}, io::ShardSpec{i, 2}));
    for (uint32_t a = 0; a < 2; ++a) {
      const format::ArraySpec& spec = w.metadata().arrays[a];
      for (uint64_t c : w.Missing(a)) {
        LTB_RETURN_IF_ERROR(w.Put(a, c, test::AsBytes(test::ChunkValues(spec, a == 0 ? m : s, c))));
      }
    }
    LTB_RETURN_IF_ERROR(w.Finish());
  }
  return Status::Ok();
}

struct RecordedStep {
  std::map<std::string, std::vector<std::byte>> before;
  std::vector<IoOp> ops;
  std::string dir;
};
// Runs `step` in a directory holding the shards (and, for `committed`, their manifest),
// recording its I/O.
RecordedStep RecordShardStep(const test::TempDir& dir, bool committed, unsigned skipped,
                             const std::function<Status(const std::string& dir)>& step) {
  RecordedStep r;
  r.dir = dir.File("");
  r.dir.pop_back();
  EXPECT_TRUE(WriteShards(r.dir + "/out.ltm").ok());
  if (committed) EXPECT_TRUE(io::CommitShards(r.dir + "/out.ltm", 2).ok());
  r.before = Snapshot(r.dir);
  Recorder rec;
  io::SetSkippedBarriers(skipped);
  io::SetIoRecorder(&rec);
  Status s = step(r.dir);
  r.ops = rec.Take();
  io::SetIoRecorder(nullptr);
  io::SetSkippedBarriers(0);
  EXPECT_TRUE(s.ok()) << s.message();
  return r;
}
Status Commit(const std::string& dir) { return io::CommitShards(dir + "/out.ltm", 2).status(); }
Status Merge(const std::string& dir) {
  return io::MergeManifest(dir + "/out.ltm", dir + "/merged.ltm", false).status();
}

// Committing writes the manifest by an AtomicFile; merging copies the shards' chunks through
// a ContainerWriter. Every crash state of each: the manifest (the merged container) whole
// once the command returned, and a rerun gives it or refuses, never other content.
TEST(CrashReplay, EveryCrashPointOfACommitAndAMergeCompletesOrRefusesNeverSilently) {
  for (const bool merge : {false, true}) {
    test::TempDir dir;
    const RecordedStep r = RecordShardStep(dir, merge, 0, merge ? Merge : Commit);
    ASSERT_GE(r.ops.size(), merge ? 20u : 4u);
    const Tally t =
        Replay(r.before, r.ops, r.ops.size(), r.dir, merge ? "merged.ltm" : "out.ltm", 1, merge ? Merge : Commit);
    std::string v;
    for (const auto& s : t.violations) v += "\n  " + s;
    EXPECT_FALSE(t.Violated()) << (merge ? "merge: " : "commit: ") << t.silent << " silent, " << t.lost
                               << " lost:" << v;
    EXPECT_GT(t.clean, 0);
    std::printf("%s: %zu ops, %d crash states clean, %d loud, %d silent, %d lost\n", merge ? "merge" : "commit",
                r.ops.size(), t.clean, t.loud, t.silent, t.lost);
  }
}

// And the replay notices the barriers they rely on: the manifest's AtomicFile syncs (data and
// directory), the merged container's seal sync.
TEST(CrashReplay, TheReplayFindsEachBarrierOfACommitAndAMergeMissing) {
  for (const auto& [merge, barrier] : std::vector<std::pair<bool, unsigned>>{
           {false, io::kBarrierAtomicDataSync}, {false, io::kBarrierAtomicDirSync}, {true, io::kBarrierSealSync}}) {
    test::TempDir dir;
    const RecordedStep r = RecordShardStep(dir, merge, barrier, merge ? Merge : Commit);
    const Tally t =
        Replay(r.before, r.ops, r.ops.size(), r.dir, merge ? "merged.ltm" : "out.ltm", 1, merge ? Merge : Commit);
    std::printf("%s without barrier %u: %d clean, %d loud, %d silent, %d lost\n", merge ? "merge" : "commit", barrier,
                t.clean, t.loud, t.silent, t.lost);
    EXPECT_TRUE(t.Violated()) << (merge ? "merge" : "commit") << ": barrier " << barrier
                              << " removed, and no crash state shows it";
  }
}

// --- an AtomicFile replacing an old file: old or new, whole, never anything else -----------
Tally ReplayAtomic(const std::vector<IoOp>& ops, size_t ack,
                   const std::map<std::string, std::vector<std::byte>>& before, const std::string& dir,
                   const std::string& old_text, const std::string& new_text) {
  Tally t;
  for (size_t k = 0; k <= ops.size(); ++k) {
    for (Model model : {Model::kKill, Model::kTorn, Model::kPowerNames, Model::kPowerData, Model::kPowerMix}) {
      if (model == Model::kTorn && (k == ops.size() || ops[k].kind != IoOp::Kind::kWrite)) continue;
      for (uint32_t seed = 0; seed < (model == Model::kPowerMix ? 3u : 1u); ++seed) {
        auto files = CrashState(before, ops, k, model, seed);
        auto it = files.find(dir + "/out.json");
        const std::string got = it == files.end()
                                    ? std::string("(missing)")
                                    : std::string(reinterpret_cast<const char*>(it->second.data()), it->second.size());
        const std::string what = std::string(ModelName(model)) + " after op " + std::to_string(k) + "/" +
                                 std::to_string(ops.size()) + ": out.json holds \"" + got + "\"";
        if (k >= ack ? got != new_text : got != old_text && got != new_text) {
          ++(k >= ack ? t.lost : t.silent);
          t.violations.push_back(what);
        } else {
          ++t.clean;
        }
      }
    }
  }
  return t;
}

Tally RecordAndReplayAtomic(unsigned skipped, size_t* op_count) {
  test::TempDir dir;
  std::string d = dir.File("");
  d.pop_back();
  const std::string old_text = "the old content, longer than the new", new_text = "the new content";
  {
    std::ofstream f(d + "/out.json", std::ios::binary);
    f << old_text;
  }
  const auto before = Snapshot(d);
  Recorder rec;
  io::SetSkippedBarriers(skipped);
  io::SetIoRecorder(&rec);
  Status s = io::WriteFileAtomically(d + "/out.json", new_text);
  std::vector<IoOp> ops = rec.Take();
  io::SetIoRecorder(nullptr);
  io::SetSkippedBarriers(0);
  EXPECT_TRUE(s.ok()) << s.message();
  *op_count = ops.size();
  return ReplayAtomic(ops, ops.size(), before, d, old_text, new_text);
}

TEST(CrashReplay, AnAtomicFileIsOldOrNewAtEveryCrashPointAndNewOnceCommitted) {
  size_t n = 0;
  Tally t = RecordAndReplayAtomic(0, &n);
  std::string v;
  for (const auto& s : t.violations) v += "\n  " + s;
  EXPECT_FALSE(t.Violated()) << v;
  EXPECT_GE(n, 5u);  // create, write, sync, rename, directory sync
  std::printf("atomic file: %zu ops, %d crash states clean, %d violations\n", n, t.clean, t.silent + t.lost);
}

TEST(CrashReplay, TheReplayFindsEachBarrierOfAnAtomicFileMissing) {
  for (unsigned barrier : {io::kBarrierAtomicDataSync, io::kBarrierAtomicDirSync}) {
    size_t n = 0;
    Tally t = RecordAndReplayAtomic(barrier, &n);
    std::printf("atomic file without barrier %u: %d clean, %d silent, %d lost\n", barrier, t.clean, t.silent, t.lost);
    EXPECT_TRUE(t.Violated()) << "barrier " << barrier << " removed, and no crash state shows it";
  }
}

}  // namespace
}  // namespace crash_replay
}  // namespace ltb
