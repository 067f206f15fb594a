// What the I/O layer did to the disk, for crash-consistency tests (tests/format/
// crash_replay_test.cpp): every File write, truncate and fdatasync, every file creation,
// rename, removal and directory sync, in order, reported to the recorder set here (none by
// default: then each call costs one relaxed atomic load). The test replays every prefix of
// the sequence as a crash would leave the disk, and resumes from it.
//
// Barriers (the syncs that order writes for durability) can be switched off one at a time,
// so the same test shows that its replay notices each one missing. Only tests do that.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "format/bytes.h"

namespace ltb::io {

struct IoOp {
  enum class Kind { kCreate, kWrite, kTruncate, kSync, kRename, kSyncDir, kRemove };
  Kind kind = Kind::kWrite;
  std::string path;             // the file (kSyncDir: the directory; kRename: from)
  std::string to;               // kRename
  uint64_t offset = 0;          // kWrite; kTruncate: the new size
  std::vector<std::byte> data;  // kWrite
};

class IoRecorder {
 public:
  virtual ~IoRecorder() = default;
  // Called from the thread doing the I/O, after the call succeeded; may be called from
  // several threads at once.
  virtual void Record(IoOp op) = 0;
};

// The recorder every File, AtomicFile and SyncParentDirectory reports to (nullptr: none).
void SetIoRecorder(IoRecorder* recorder);
bool Recording();
void RecordIo(IoOp op);  // no-op without a recorder

// The barriers of the writers: fdatasync of an AtomicFile before its rename, the directory
// sync after it, the fdatasync that ends sealing a container, and the order of a chunk's
// writes (payload first, the header that commits it last; skipped: header first).
enum Barrier : unsigned {
  kBarrierAtomicDataSync = 1u << 0,
  kBarrierAtomicDirSync = 1u << 1,
  kBarrierSealSync = 1u << 2,
  kBarrierHeaderLast = 1u << 3,
};
// For crash tests only: the barriers in `mask` are skipped (0: none, the default).
void SetSkippedBarriers(unsigned mask);
bool BarrierSkipped(Barrier barrier);

}  // namespace ltb::io
