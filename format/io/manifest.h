// Stage manifests: one matrix stored as shard files.
//
// A stage run as n shards (`--shard i --nshards n`) writes shard i to
// ShardPath(OUT, i, n); each shard file is an ordinary container with the whole output's
// metadata plus a "shard" key, holding only the chunks it owns. CommitShards validates every
// shard (checksums, coverage, parameters) and atomically writes OUT as a small text manifest
// listing them. ContainerReader::Open reads a manifest as the one matrix it describes, so
// every reader (inspect, verify, convert, the next stage, relight) takes it where it takes a
// container; MergeManifest concatenates it into a single container. Byte-level description:
// docs/FORMAT.md "Shard files and stage manifests".
#pragma once

#include <cstdint>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "format/io/container_reader.h"
#include "format/io/container_writer.h"
#include "format/io/verifier.h"
#include "format/progress.h"
#include "format/status.h"

namespace ltb::io {

// The first line of every manifest file.
inline constexpr char kManifestMagic[] = "LTBAKE-MANIFEST 1\n";
inline constexpr uint64_t kMaxManifestBytes = 64ull << 20;

// Whether the file at path starts with kManifestMagic (false when it cannot be read).
bool LooksLikeManifest(const std::string& path);

// Where shard `index` of `count` of OUT lives: "dir/rows.ltm" -> "dir/rows.shards/00002-of-00004.ltm".
std::string ShardPath(const std::string& output, uint64_t index, uint64_t count);
// The directory holding OUT's shards ("dir/rows.shards").
std::string ShardDirectory(const std::string& output);

// Which slice of a stage's output a process writes: shard `index` of `count` (count 1: the
// whole output, as one ordinary container).
struct ShardSpec {
  uint64_t index = 0;
  uint64_t count = 1;
  // Chunk boundaries of the shards (count + 1 of them, ShardMetadataJson's `bounds`), when the
  // stage balances its shards by their work; empty: ShardChunkRange's even split.
  std::vector<uint64_t> bounds;
  bool sharded() const { return count > 1; }
};

// Opens the writer of a stage's output: `output` itself, or for a sharded run the shard
// file ShardPath(output, ...) (its directory made) with ShardMetadataJson(metadata).
Result<ContainerWriter> OpenStageOutput(const std::string& output, const nlohmann::json& metadata,
                                        const WriterOptions& options, const ShardSpec& shard);

struct ShardRecord {
  uint64_t index = 0;
  std::string path;          // as written in the manifest: relative to the manifest's directory
  uint64_t bytes = 0;        // file size
  std::string fingerprint;   // IndexFingerprint: metadata and every chunk's checksum
  std::string content_hash;  // of the shard's slice of the matrix (array 0)
  uint64_t hash_sum = 0;     // its content_hash sum: the shards' sums add to the matrix's
};

struct CommitOptions {
  bool overwrite = false;  // replace an OUT that is a container rather than a manifest
  int threads = 1;
  Progress progress;
};

struct CommitResult {
  std::string content_hash;  // of the whole matrix
  uint64_t bytes = 0;        // of all shard files
  std::vector<ShardRecord> shards;
};

// Validates shards 0..count-1 of `output` and writes the manifest at `output` (temp file,
// fsync, rename). Fails, writing nothing, naming every missing shard, or the first shard
// that is damaged, incomplete, from other parameters or does not fit the others.
Result<CommitResult> CommitShards(const std::string& output, uint64_t count, const CommitOptions& options = {});

// The shard records of a manifest (parsed and checked for form; the shards are not opened).
struct ManifestInfo {
  nlohmann::json metadata;
  uint64_t count = 0;
  std::string content_hash;
  std::vector<ShardRecord> shards;
};
Result<ManifestInfo> ReadManifest(const std::string& path);

// verify for a manifest: the manifest's own checks plus VerifyContainer of every shard, each
// problem prefixed with the shard it is in.
VerifyReport VerifyManifest(const std::string& path, int threads = 1);

struct MergeResult {
  uint64_t chunks = 0;
  uint64_t bytes = 0;
};
// Copies every chunk of the manifest's shards, encoded as stored, into one container at
// `output` (resumable like any writer; `overwrite` replaces a file with other metadata).
Result<MergeResult> MergeManifest(const std::string& manifest, const std::string& output, bool overwrite,
                                  const Progress& progress = {});

}  // namespace ltb::io
