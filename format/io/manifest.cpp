#include "format/io/manifest.h"

#include <fcntl.h>
#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <set>

#include "format/content_hash.h"
#include "format/io/array_summary.h"
#include "format/io/atomic_file.h"
#include "format/io/container_writer.h"
#include "format/io/file.h"
#include "format/io/file_lock.h"
#include "format/json_text.h"

namespace ltb::io {

using namespace ltb::format;

namespace {

constexpr size_t kMagicLength = sizeof(kManifestMagic) - 1;

std::string ShardName(uint64_t index, uint64_t count, const std::string& path) {
  return "shard " + std::to_string(index) + " of " + std::to_string(count) + " (" + path + ")";
}

// The first place two metadata objects differ, as "key.path: A here, B there".
std::string FirstJsonDifference(const nlohmann::json& a, const nlohmann::json& b, const std::string& at = "") {
  if (a.is_object() && b.is_object()) {
    std::set<std::string> keys;
    for (auto it = a.begin(); it != a.end(); ++it) keys.insert(it.key());
    for (auto it = b.begin(); it != b.end(); ++it) keys.insert(it.key());
    for (const std::string& k : keys) {
      const std::string path = at.empty() ? k : at + "." + k;
      if (!a.contains(k)) return path + ": absent here, " + JsonText(b[k]) + " expected";
      if (!b.contains(k)) return path + ": " + JsonText(a[k]) + " here, absent in the others";
      if (a[k] != b[k]) return FirstJsonDifference(a[k], b[k], path);
    }
    return "";
  }
  if (a.is_array() && b.is_array() && a.size() == b.size()) {
    for (size_t i = 0; i < a.size(); ++i)
      if (a[i] != b[i]) return FirstJsonDifference(a[i], b[i], at + "[" + std::to_string(i) + "]");
    return "";
  }
  std::string va = JsonText(a), vb = JsonText(b);
  if (va.size() > 120) va = va.substr(0, 117) + "...";
  if (vb.size() > 120) vb = vb.substr(0, 117) + "...";
  return (at.empty() ? std::string("metadata") : at) + ": " + va + " here, " + vb + " expected";
}

nlohmann::json WithoutShard(const nlohmann::json& meta) {
  nlohmann::json j = meta;
  j.erase("shard");
  return j;
}

std::string Directory(const std::string& path) {
  std::string d = std::filesystem::path(path).parent_path().string();
  return d.empty() ? "." : d;
}

Result<uint64_t> ParseHexSum(const nlohmann::json& j, const std::string& where) {
  if (!j.is_string() || j.get<std::string>().size() != 16) return DataLoss(where + " is not 16 hex digits");
  const std::string s = j.get<std::string>();
  uint64_t v = 0;
  for (char c : s) {
    int d = (c >= '0' && c <= '9') ? c - '0' : (c >= 'a' && c <= 'f') ? c - 'a' + 10 : -1;
    if (d < 0) return DataLoss(where + " is not 16 lowercase hex digits");
    v = (v << 4) | static_cast<uint64_t>(d);
  }
  return v;
}

// Opens shard `index` of `count` at `full` and checks what a shard must be on its own:
// readable, undamaged, sealed, complete, and the shard it is named as.
Result<ContainerReader> OpenShard(const std::string& owner, uint64_t index, uint64_t count, const std::string& full) {
  const std::string name = ShardName(index, count, full);
  const std::string rerun = "; rerun shard " + std::to_string(index) +
                            " of the stage and commit again (`ltbake run` does both, only for the shards it needs)";
  // Checked before opening: a manifest naming itself (or another manifest naming it back)
  // as a shard would otherwise recurse without end.
  if (LooksLikeManifest(full)) return DataLoss(owner + ": " + name + " is itself a manifest; a shard is a container");
  auto r = ContainerReader::Open(full);
  if (!r.ok()) return Status(r.status().code(), owner + ": " + name + ": " + r.status().message() + rerun);
  if (r->is_manifest()) return DataLoss(owner + ": " + name + " is itself a manifest; a shard is a container");
  const auto& info = r->metadata().shard;
  if (!info) return FailedPrecondition(owner + ": " + name + " is a whole container, not a shard" + rerun);
  if (info->index != index || info->count != count) {
    return FailedPrecondition(owner + ": " + name + " says it is shard " + std::to_string(info->index) + " of " +
                              std::to_string(info->count) + rerun);
  }
  if (!r->problems().empty()) return DataLoss(owner + ": " + name + " is damaged: " + r->problems().front() + rerun);
  if (!r->sealed() || !r->complete()) {
    uint64_t have = 0, want = 0;
    for (uint32_t a = 0; a < r->metadata().arrays.size(); ++a) {
      have += r->committed(a);
      want += r->metadata().OwnedChunks(a);
    }
    return FailedPrecondition(owner + ": " + name + " is incomplete (" + std::to_string(have) + " of " +
                              std::to_string(want) + " chunks" + (r->sealed() ? "" : ", not sealed") + ")" + rerun);
  }
  return r;
}

}  // namespace

bool LooksLikeManifest(const std::string& path) {
  // Through File::Open: a FIFO or a device is not read here (the caller's own open refuses it).
  auto f = File::Open(path, File::Mode::kRead);
  if (!f.ok()) return false;
  char buf[kMagicLength];
  ssize_t n = ::pread(f->fd(), buf, kMagicLength, 0);
  return n == static_cast<ssize_t>(kMagicLength) && std::memcmp(buf, kManifestMagic, kMagicLength) == 0;
}

std::string ShardDirectory(const std::string& output) {
  std::filesystem::path p(output);
  std::string stem = p.extension() == ".ltm" ? p.stem().string() : p.filename().string();
  return (p.parent_path() / (stem + ".shards")).string();
}

std::string ShardPath(const std::string& output, uint64_t index, uint64_t count) {
  char name[64];
  std::snprintf(name, sizeof name, "%05llu-of-%05llu.ltm", static_cast<unsigned long long>(index),
                static_cast<unsigned long long>(count));
  return ShardDirectory(output) + "/" + name;
}

Result<ContainerWriter> OpenStageOutput(const std::string& output, const nlohmann::json& metadata,
                                        const WriterOptions& options, const ShardSpec& shard) {
  if (!shard.sharded()) {
    if (shard.index != 0) return InvalidArgument("--shard " + std::to_string(shard.index) + " of --nshards 1");
    return ContainerWriter::Open(output, metadata, options);
  }
  LTB_ASSIGN_OR_RETURN(nlohmann::json meta, ShardMetadataJson(metadata, shard.index, shard.count,
                                                              shard.bounds.empty() ? nullptr : &shard.bounds));
  const std::string dir = ShardDirectory(output);
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  if (ec) return IoError(dir + ": cannot create the shard directory", ec.value());
  return ContainerWriter::Open(ShardPath(output, shard.index, shard.count), meta, options);
}

Result<ManifestInfo> ReadManifest(const std::string& path) {
  LTB_ASSIGN_OR_RETURN(File f, File::Open(path, File::Mode::kRead));
  LTB_ASSIGN_OR_RETURN(uint64_t size, f.Size());
  if (size > kMaxManifestBytes) {
    return DataLoss(path + ": a manifest of " + std::to_string(size) + " bytes (the cap is " +
                    std::to_string(kMaxManifestBytes) + "): not a manifest ltbake wrote");
  }
  std::string text(size, '\0');
  LTB_RETURN_IF_ERROR(f.ReadAt(0, MutableByteSpan(reinterpret_cast<std::byte*>(text.data()), text.size())));
  if (text.compare(0, kMagicLength, kManifestMagic) != 0)
    return DataLoss(path + ": not a stage manifest (no magic line)");
  auto bad = [&](const std::string& what) {
    return DataLoss(path + ": manifest " + what + "; commit the shards again (`ltbake commit`) or rerun the stage");
  };
  auto parsed = ParseJson(std::string_view(text).substr(kMagicLength));
  if (!parsed.ok() || !parsed->is_object()) return bad("is not valid JSON after its magic line");
  nlohmann::json j = std::move(*parsed);
  if (!j.contains("version") || !j["version"].is_number_unsigned()) return bad("lacks \"version\"");
  if (j["version"].get<uint64_t>() != 1) {
    return Unimplemented(path + ": manifest version " + JsonText(j["version"]) +
                         " is newer than this build reads (1); upgrade ltbake");
  }
  for (const char* key : {"metadata", "nshards", "content_hash", "shards"})
    if (!j.contains(key)) return bad(std::string("lacks \"") + key + "\"");
  ManifestInfo info;
  if (!j["metadata"].is_object()) return bad("metadata is not an object");
  info.metadata = j["metadata"];
  if (!j["nshards"].is_number_unsigned() || j["nshards"].get<uint64_t>() == 0 ||
      j["nshards"].get<uint64_t>() > kMaxShards) {
    return bad("nshards is " + JsonText(j["nshards"]) + " (expected 1.." + std::to_string(kMaxShards) + ")");
  }
  info.count = j["nshards"].get<uint64_t>();
  if (!j["content_hash"].is_string()) return bad("content_hash is not a string");
  info.content_hash = j["content_hash"].get<std::string>();
  if (!j["shards"].is_array() || j["shards"].size() != info.count) {
    return bad("lists " + std::to_string(j["shards"].is_array() ? j["shards"].size() : 0) + " shards for nshards " +
               std::to_string(info.count));
  }
  for (uint64_t i = 0; i < info.count; ++i) {
    const auto& s = j["shards"][i];
    const std::string where = "shards[" + std::to_string(i) + "]";
    if (!s.is_object()) return bad(where + " is not an object");
    for (const char* key : {"index", "path", "bytes", "fingerprint", "content_hash", "hash_sum"})
      if (!s.contains(key)) return bad(where + " lacks \"" + key + "\"");
    ShardRecord r;
    if (!s["index"].is_number_unsigned() || s["index"].get<uint64_t>() != i)
      return bad(where + ".index is not " + std::to_string(i));
    r.index = i;
    if (!s["path"].is_string()) return bad(where + ".path is not a string");
    r.path = s["path"].get<std::string>();
    std::filesystem::path rel(r.path);
    bool climbs = false;
    for (const auto& part : rel) climbs = climbs || part == "..";
    if (r.path.empty() || rel.is_absolute() || climbs) {
      return bad(where + ".path \"" + r.path + "\" is not a path below the manifest's directory");
    }
    if (!s["bytes"].is_number_unsigned()) return bad(where + ".bytes is not a size");
    r.bytes = s["bytes"].get<uint64_t>();
    if (!s["fingerprint"].is_string() || !s["content_hash"].is_string()) return bad(where + " has non-string hashes");
    r.fingerprint = s["fingerprint"].get<std::string>();
    r.content_hash = s["content_hash"].get<std::string>();
    auto sum = ParseHexSum(s["hash_sum"], path + ": manifest " + where + ".hash_sum");
    if (!sum.ok()) return sum.status();
    r.hash_sum = *sum;
    info.shards.push_back(std::move(r));
  }
  return info;
}

Status ContainerReader::LoadManifest() {
  const std::string mpath = path();
  LTB_ASSIGN_OR_RETURN(ManifestInfo info, ReadManifest(mpath));
  auto meta = MetadataFromJson(info.metadata);
  if (!meta.ok()) return DataLoss(mpath + ": manifest metadata: " + meta.status().message());
  if (meta->shard) return DataLoss(mpath + ": manifest metadata describes a shard, not the whole matrix");
  metadata_ = std::move(meta).value();
  committed_.assign(metadata_.arrays.size(), 0);
  const std::string dir = Directory(mpath);
  std::vector<uint64_t> next(metadata_.arrays.size(), 0);
  uint64_t total = file_size_;
  for (const ShardRecord& rec : info.shards) {
    const std::string full = dir + "/" + rec.path;
    const std::string name = ShardName(rec.index, info.count, full);
    const std::string rerun = "; rerun shard " + std::to_string(rec.index) +
                              " of the stage and commit again (`ltbake run` does both, only for shards it needs)";
    if (!PathExists(full)) return NotFound(mpath + ": " + name + " is missing" + rerun);
    LTB_ASSIGN_OR_RETURN(ContainerReader r, OpenShard(mpath, rec.index, info.count, full));
    const std::string diff = FirstJsonDifference(WithoutShard(r.metadata().json), metadata_.json);
    if (!diff.empty()) {
      return FailedPrecondition(mpath + ": " + name + " was written with other parameters than the manifest (" + diff +
                                ")" + rerun);
    }
    if (r.file_size() != rec.bytes) {
      return DataLoss(mpath + ": " + name + " is " + std::to_string(r.file_size()) + " bytes; the manifest recorded " +
                      std::to_string(rec.bytes) + ": it changed after the commit" + rerun);
    }
    const std::string fp = IndexFingerprint(r);
    if (fp != rec.fingerprint) {
      return DataLoss(mpath + ": " + name + " holds other chunks than the manifest recorded (fingerprint " + fp +
                      ", recorded " + rec.fingerprint + "): it was rewritten after the commit" + rerun);
    }
    for (uint32_t a = 0; a < metadata_.arrays.size(); ++a) {
      const auto& [b, e] = r.metadata().shard->chunks[a];
      if (b != next[a]) {
        return DataLoss(mpath + ": " + name + " starts array \"" + metadata_.arrays[a].name + "\" at chunk " +
                        std::to_string(b) + ", but the shards before it end at chunk " + std::to_string(next[a]));
      }
      next[a] = e;
    }
    for (const IndexEntry& e : r.chunk_frames()) {
      by_key_[(uint64_t{e.header.array} << 40) | e.header.chunk_index] = chunk_frames_.size();
      chunk_frames_.push_back(e);
      frame_part_.push_back(static_cast<uint32_t>(parts_.size()));
      committed_[e.header.array] += 1;
    }
    total += r.file_size();
    parts_.push_back(std::make_shared<const ContainerReader>(std::move(r)));
  }
  for (uint32_t a = 0; a < metadata_.arrays.size(); ++a) {
    if (next[a] != metadata_.arrays[a].ChunkCount()) {
      return DataLoss(mpath + ": the shards cover chunks 0-" + std::to_string(next[a]) + " of array \"" +
                      metadata_.arrays[a].name + "\", which has " + std::to_string(metadata_.arrays[a].ChunkCount()));
    }
  }
  header_ = parts_.front()->header();
  file_size_ = total;
  sealed_ = true;
  return Status::Ok();
}

Result<CommitResult> CommitShards(const std::string& output, uint64_t count, const CommitOptions& options) {
  if (count == 0 || count > kMaxShards) {
    return InvalidArgument("--nshards " + std::to_string(count) + ": expected 1.." + std::to_string(kMaxShards));
  }
  if (count == 1) {
    return InvalidArgument("--nshards 1: a stage run as one shard writes " + output +
                           " itself, as a whole container; there is nothing to commit");
  }
  // One writer of OUT at a time: a commit, a merge into it, or a whole-output stage run.
  LTB_ASSIGN_OR_RETURN(FileLock lock, LockOutput(output));
  std::vector<std::string> missing;
  for (uint64_t i = 0; i < count; ++i)
    if (!PathExists(ShardPath(output, i, count))) missing.push_back(std::to_string(i));
  if (!missing.empty()) {
    std::string list;
    for (size_t k = 0; k < missing.size() && k < 16; ++k) list += (k ? ", " : "") + missing[k];
    if (missing.size() > 16) list += ", ...";
    return NotFound(output + ": cannot commit: " + std::to_string(missing.size()) + " of " + std::to_string(count) +
                    " shards missing (shard " + list + "; files " + ShardPath(output, std::stoull(missing[0]), count) +
                    " ...); run them with `--shard I --nshards " + std::to_string(count) +
                    "` (`ltbake run` reruns only missing shards)");
  }
  if (PathExists(output) && !LooksLikeManifest(output) && !options.overwrite) {
    return FailedPrecondition(output +
                              " exists and is not a stage manifest; pass --overwrite to replace it with the "
                              "manifest of its " +
                              std::to_string(count) + " shards");
  }
  CommitResult result;
  nlohmann::json whole;
  std::vector<uint64_t> next;
  ContentHasher total;
  const std::string dir = Directory(output);
  std::vector<std::byte> buffer(1 << 20);
  for (uint64_t i = 0; i < count; ++i) {
    if (options.progress.Cancelled()) return Cancelled("interrupted before the manifest was written; nothing changed");
    const std::string full = ShardPath(output, i, count);
    const std::string name = ShardName(i, count, full);
    LTB_ASSIGN_OR_RETURN(ContainerReader r, OpenShard(output, i, count, full));
    nlohmann::json meta = WithoutShard(r.metadata().json);
    if (i == 0) {
      whole = meta;
      next.assign(r.metadata().arrays.size(), 0);
    } else if (std::string diff = FirstJsonDifference(meta, whole); !diff.empty()) {
      return FailedPrecondition(output + ": " + name + " was written with other parameters than shard 0 (" + diff +
                                "); rerun the shards whose parameters are out of date");
    }
    for (uint32_t a = 0; a < next.size(); ++a) {
      const auto& [b, e] = r.metadata().shard->chunks[a];
      if (b != next[a]) {
        return DataLoss(output + ": " + name + " starts array \"" + r.metadata().arrays[a].name + "\" at chunk " +
                        std::to_string(b) + " where chunk " + std::to_string(next[a]) + " was expected");
      }
      next[a] = e;
      for (uint64_t c = b; c < e; ++c) {
        Status s = r.VerifyChunk(a, c, buffer);
        if (!s.ok())
          return DataLoss(output + ": " + name + " is damaged: " + s.message() + "; rerun shard " + std::to_string(i));
      }
    }
    // The shard's slice of the matrix: its content_hash as its writer recorded it (shards
    // written before 2026-11-26 have no record and are read back). `verify` recomputes it.
    std::optional<uint64_t> recorded = r.RecordedHashSum(0);
    if (!recorded) {
      auto summary = SummarizeArray(r, 0, options.threads);
      if (!summary.ok()) {
        return DataLoss(output + ": " + name + " is damaged: " + summary.status().message() + "; rerun shard " +
                        std::to_string(i));
      }
      recorded = summary->hash_sum;
    }
    ContentHasher slice;
    slice.AddSum(*recorded);
    ShardRecord rec;
    rec.index = i;
    rec.path = std::filesystem::path(full).lexically_relative(dir).string();
    rec.bytes = r.file_size();
    rec.fingerprint = IndexFingerprint(r);
    rec.content_hash = slice.Finish(r.metadata().matrix());
    rec.hash_sum = *recorded;
    total.AddSum(*recorded);
    result.bytes += rec.bytes;
    result.shards.push_back(rec);
    options.progress.Report(i + 1, count, "shards");
  }
  LTB_ASSIGN_OR_RETURN(Metadata m, MetadataFromJson(whole));
  for (uint32_t a = 0; a < m.arrays.size(); ++a) {
    if (next[a] != m.arrays[a].ChunkCount()) {
      return DataLoss(output + ": the shards cover chunks 0-" + std::to_string(next[a]) + " of array \"" +
                      m.arrays[a].name + "\", which has " + std::to_string(m.arrays[a].ChunkCount()));
    }
  }
  result.content_hash = total.Finish(m.matrix());
  nlohmann::json shards = nlohmann::json::array();
  for (const ShardRecord& r : result.shards) {
    shards.push_back({{"index", r.index},
                      {"path", r.path},
                      {"bytes", r.bytes},
                      {"fingerprint", r.fingerprint},
                      {"content_hash", r.content_hash},
                      {"hash_sum", Hex64(r.hash_sum).substr(2)}});
  }
  nlohmann::json manifest = {{"version", 1},
                             {"nshards", count},
                             {"content_hash", result.content_hash},
                             {"metadata", whole},
                             {"shards", shards}};
  LTB_RETURN_IF_ERROR(WriteFileAtomically(output, std::string(kManifestMagic) + JsonText(manifest, 1) + "\n"));
  return result;
}

VerifyReport VerifyManifest(const std::string& path, int threads) {
  VerifyReport report;
  report.path = path;
  auto info = ReadManifest(path);
  if (!info.ok()) {
    report.problems.push_back(info.status().message());
    return report;
  }
  report.readable = true;
  auto joined = ContainerReader::Open(path);
  if (!joined.ok()) report.problems.push_back(joined.status().message());
  bool sealed = joined.ok();
  const std::string dir = Directory(path);
  // The recorded hashes are recomputed from the shards' data: a manifest whose hashes were
  // edited (or that was committed from other shards) does not pass.
  ContentHasher total;
  bool all_hashed = true;
  for (const ShardRecord& rec : info->shards) {
    const std::string full = dir + "/" + rec.path;
    const std::string name = ShardName(rec.index, info->count, full);
    if (!PathExists(full) || LooksLikeManifest(full)) {
      sealed = false;  // already reported by Open (verifying a manifest here could recurse without end)
      continue;
    }
    VerifyReport s = VerifyContainer(full, threads);
    report.chunks_expected += s.chunks_expected;
    report.chunks_ok += s.chunks_ok;
    report.uncommitted_tail_bytes += s.uncommitted_tail_bytes;
    for (const std::string& p : s.problems) report.problems.push_back(name + ": " + p);
    for (const std::string& n : s.notes) report.notes.push_back(name + ": " + n);
    sealed = sealed && s.sealed;
    if (!s.problems.empty() || !s.sealed) {
      all_hashed = false;
      continue;
    }
    // Recomputed from the shard's chunks by VerifyContainer (the shard is complete here).
    if (s.hash_sum.empty() || s.content_hash.empty() || s.content_hash[0].empty()) {
      report.problems.push_back(name + ": its content_hash was not recomputed");
      all_hashed = false;
      continue;
    }
    if (s.content_hash[0] != rec.content_hash) {
      report.problems.push_back(
          path + ": shards[" + std::to_string(rec.index) + "].content_hash is " + rec.content_hash + ", but " + name +
          " holds content_hash " + s.content_hash[0] +
          ": the manifest does not describe this shard; commit the shards again (`ltbake commit`)");
    }
    if (s.hash_sum[0] != rec.hash_sum) {
      report.problems.push_back(
          path + ": shards[" + std::to_string(rec.index) + "].hash_sum is " + Hex64(rec.hash_sum).substr(2) + ", but " +
          name + " sums to " + Hex64(s.hash_sum[0]).substr(2) +
          ": the manifest does not describe this shard; commit the shards again (`ltbake commit`)");
    }
    total.AddSum(s.hash_sum[0]);
  }
  if (all_hashed && joined.ok()) {
    const std::string whole = total.Finish(joined->metadata().matrix());
    if (whole != info->content_hash) {
      report.problems.push_back(path + ": content_hash is " + info->content_hash +
                                ", but its shards hold content_hash " + whole +
                                "; commit the shards again (`ltbake commit`)");
    }
  }
  report.sealed = sealed;
  report.complete = sealed && report.problems.empty() && report.chunks_ok == report.chunks_expected;
  return report;
}

Result<MergeResult> MergeManifest(const std::string& manifest, const std::string& output, bool overwrite,
                                  const Progress& progress) {
  LTB_ASSIGN_OR_RETURN(ContainerReader in, ContainerReader::Open(manifest));
  if (!in.is_manifest()) return InvalidArgument(manifest + " is a container, not a stage manifest: nothing to merge");
  std::error_code ec;
  if (std::filesystem::exists(output, ec) && std::filesystem::equivalent(manifest, output, ec)) {
    return InvalidArgument(output +
                           " is the manifest itself; merge into another file, then rename it over the manifest");
  }
  WriterOptions wo;
  wo.overwrite_mismatch = overwrite;
  LTB_ASSIGN_OR_RETURN(ContainerWriter out, ContainerWriter::Open(output, in.metadata().json, wo));
  MergeResult result;
  uint64_t total = 0, done = 0;
  for (uint32_t a = 0; a < in.metadata().arrays.size(); ++a) total += out.Missing(a).size();
  for (uint32_t a = 0; a < in.metadata().arrays.size(); ++a) {
    for (uint64_t c : out.Missing(a)) {
      if (progress.Cancelled()) return Cancelled("interrupted; committed chunks are kept, rerun to resume");
      LTB_ASSIGN_OR_RETURN(EncodedChunk e, in.ReadEncoded(a, c));
      LTB_RETURN_IF_ERROR(out.Append(a, c, e));
      result.chunks++;
      result.bytes += e.payload.size();
      progress.Report(++done, total, "chunks");
    }
  }
  LTB_RETURN_IF_ERROR(out.Finish());
  return result;
}

}  // namespace ltb::io
