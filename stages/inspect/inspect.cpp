#include "stages/inspect/inspect.h"

#include <algorithm>
#include <cmath>

#include "format/bytes.h"
#include "format/io/array_summary.h"
#include "format/io/container_reader.h"
#include "stages/column_transform/column_transform.h"
#include "stages/quantize/quantize.h"

namespace ltb::stages {
namespace {

using namespace ltb::format;
using nlohmann::json;

json NumberOrNull(double v) { return std::isfinite(v) ? json(v) : json(nullptr); }

// Per array: its chunks expected, committed and missing, by encoding, and their stored bytes.
json ChunkCounts(const io::ContainerReader& reader, uint32_t i) {
  const uint64_t expected = reader.metadata().OwnedChunks(i);  // a shard file: the chunks it owns
  json chunks = {{"expected", expected},
                 {"committed", reader.committed(i)},
                 {"missing", expected - std::min(expected, reader.committed(i))}};
  uint64_t by_enc[6] = {0, 0, 0, 0, 0, 0}, stored = 0;
  for (const auto& e : reader.chunk_frames()) {
    if (e.header.array != i) continue;
    if (e.header.encoding < 6) by_enc[e.header.encoding]++;  // the reader refuses unknown encodings
    stored += e.header.payload_length;
  }
  chunks["raw"] = by_enc[0];
  chunks["zero"] = by_enc[1];
  chunks["zstd"] = by_enc[2];
  if (by_enc[3] + by_enc[4] + by_enc[5] > 0) {
    chunks["sparse"] = by_enc[3];
    chunks["sparse_zstd"] = by_enc[4];
    chunks["sparse_coded"] = by_enc[5];
  }
  chunks["stored_bytes"] = stored;
  return chunks;
}

// An array's content_hash and value statistics.
void AddContent(const io::ArraySummary& summary, json& j) {
  const io::ArrayStats& s = summary.stats;
  j["content_hash"] = summary.content_hash.empty() ? json(nullptr) : json(summary.content_hash);
  uint64_t finite = s.count - s.nan - s.inf;
  j["stats"] = {{"count", s.count},
                {"min", NumberOrNull(finite ? s.min : NAN)},
                {"max", NumberOrNull(finite ? s.max : NAN)},
                {"mean", NumberOrNull(finite ? s.sum / static_cast<double>(finite) : NAN)},
                {"nan_count", s.nan},
                {"inf_count", s.inf},
                {"nonzero_fraction", s.count ? static_cast<double>(s.nonzero) / static_cast<double>(s.count) : 0.0}};
}

// Bytes on disk: payloads of the matrix and of the side tables, and the container's own
// bytes (header, metadata, frame headers, padding, index, trailer; a manifest's text).
json OnDisk(const io::ContainerReader& reader, const json& arrays) {
  uint64_t total = reader.file_size(), matrix = 0, side = 0;
  if (reader.is_manifest()) {
    for (const auto& sh : reader.shards()) total += sh->file_size();
  }
  for (const json& a : arrays) {
    (a["name"] == reader.metadata().arrays[0].name ? matrix : side) += a["chunks"]["stored_bytes"].get<uint64_t>();
  }
  const uint64_t overhead = total - std::min(total, matrix + side);
  return {{"total_bytes", total},
          {"matrix_bytes", matrix},
          {"side_table_bytes", side},
          {"overhead_bytes", overhead},
          {"overhead_fraction", total ? static_cast<double>(overhead) / static_cast<double>(total) : 0.0}};
}

// --chunks: every committed chunk frame.
json ChunkList(const io::ContainerReader& reader) {
  const Metadata& meta = reader.metadata();
  json list = json::array();
  for (const auto& e : reader.chunk_frames()) {
    list.push_back({{"array", meta.arrays[e.header.array].name},
                    {"index", e.header.chunk_index},
                    {"offset", e.frame_offset},
                    {"file", reader.Holder(e.header.array, e.header.chunk_index).path()},
                    {"encoding", EncodingName(static_cast<Encoding>(e.header.encoding))},
                    {"stored_bytes", e.header.payload_length},
                    {"decoded_bytes", e.header.decoded_length},
                    {"checksum", Hex64(e.header.payload_checksum)}});
  }
  return list;
}

// A sparse bake (docs/SPARSE.md) and every row-block container derived from it: the rows
// per kind, the entries traced and the rays and thread-seconds (summed over rows) per phase,
// from its side tables. Phase 2 includes the rows it traced in full.
}  // namespace

Result<json> SummarizeSparse(const io::ContainerReader& r) {
  const Metadata& meta = r.metadata();
  const int kind_a = meta.FindArray("sparse_kind"), traced_a = meta.FindArray("sparse_traced"),
            rays_a = meta.FindArray("sparse_rays"), res_a = meta.FindArray("sparse_residual"),
            secs_a = meta.FindArray("sparse_seconds");
  if (kind_a < 0 || traced_a < 0 || rays_a < 0 || res_a < 0 || secs_a < 0) return json(nullptr);
  const json& cols = meta.json["basis"]["cols"];
  const uint64_t res = cols.is_object() && cols.contains("cube_res") && cols["cube_res"].is_number_unsigned()
                           ? cols["cube_res"].get<uint64_t>()
                           : 0;
  // Rows by phase: 0 no geometry, 1 dense (phase 1), 2 sparse (reconstructed in phase 2),
  // 3 traced in full in phase 2 (kind 1 with a residual: the fit failed or had no neighbours).
  uint64_t rows[4] = {0, 0, 0, 0}, traced[4] = {0, 0, 0, 0}, rays[4] = {0, 0, 0, 0};
  double secs[4] = {0, 0, 0, 0};
  std::vector<float> residuals;
  const ArraySpec& ks = meta.arrays[static_cast<uint32_t>(kind_a)];
  for (uint64_t c = 0; c < ks.ChunkCount(); ++c) {
    LTB_ASSIGN_OR_RETURN(io::Chunk k, r.ReadChunk(static_cast<uint32_t>(kind_a), c));
    LTB_ASSIGN_OR_RETURN(io::Chunk t, r.ReadChunk(static_cast<uint32_t>(traced_a), c));
    LTB_ASSIGN_OR_RETURN(io::Chunk y, r.ReadChunk(static_cast<uint32_t>(rays_a), c));
    LTB_ASSIGN_OR_RETURN(io::Chunk e, r.ReadChunk(static_cast<uint32_t>(res_a), c));
    LTB_ASSIGN_OR_RETURN(io::Chunk s, r.ReadChunk(static_cast<uint32_t>(secs_a), c));
    auto kv = k.as<uint8_t>();
    auto tv = t.as<uint32_t>();
    auto yv = y.as<uint64_t>();
    auto ev = e.as<float>();
    auto sv = s.as<float>();
    if (tv.size() != kv.size() || yv.size() != kv.size() || ev.size() != kv.size() || sv.size() != kv.size()) {
      return DataLoss(r.path() + ": the sparse side tables of chunk " + std::to_string(c) + " differ in length");
    }
    for (size_t i = 0; i < kv.size(); ++i) {
      uint8_t kind = kv[i] <= 2 ? kv[i] : 0;
      if (kind == 1 && ev[i] > 0) kind = 3;
      rows[kind]++;
      traced[kind] += tv[i];
      rays[kind] += yv[i];
      secs[kind] += sv[i];
      if (kind == 2) residuals.push_back(ev[i]);
    }
  }
  const uint64_t entries = (rows[1] + rows[2] + rows[3]) * 6 * res * res;
  json out = {
      {"rows", {{"dense", rows[1]}, {"sparse", rows[2]}, {"traced_in_full", rows[3]}, {"no_geometry", rows[0]}}},
      {"dense_rows", rows[1]},
      {"entries", entries},
      {"traced_entries", {{"dense", traced[1]}, {"sparse", traced[2] + traced[3]}}},
      {"traced_fraction", entries ? static_cast<double>(traced[1] + traced[2] + traced[3]) / entries : 0.0},
      {"rays", {{"dense", rays[1]}, {"sparse", rays[2] + rays[3]}}},
      {"seconds", {{"dense", secs[1]}, {"sparse", secs[2] + secs[3]}}}};
  if (!residuals.empty()) {
    std::sort(residuals.begin(), residuals.end());
    auto at = [&](double q) { return residuals[static_cast<size_t>(q * static_cast<double>(residuals.size() - 1))]; };
    out["residual"] = {{"median", at(0.5)}, {"p90", at(0.9)}, {"max", residuals.back()}};
  }
  const json& prov = meta.json.value("provenance", json::object());
  if (prov.is_object() && prov.contains("parameters") && prov["parameters"].is_object() &&
      prov["parameters"].contains("sparse")) {
    out["parameters"] = prov["parameters"]["sparse"];
  }
  return out;
}

// A sample output's rays: the sum of its sample_rays side table (every row's rays, whichever
// run traced them; a converged bake's pilot not included; a shard's file: its own rows'),
// null without one.
Result<json> SumSampleRays(const io::ContainerReader& r) {
  const int a = r.metadata().FindArray("sample_rays");
  if (a < 0) return json(nullptr);
  uint64_t rays = 0;
  const ArraySpec& spec = r.metadata().arrays[static_cast<uint32_t>(a)];
  for (uint64_t c = 0; c < spec.ChunkCount(); ++c) {
    if (r.Find(static_cast<uint32_t>(a), c) == nullptr) continue;  // a shard's file holds only its own chunks
    LTB_ASSIGN_OR_RETURN(io::Chunk y, r.ReadChunk(static_cast<uint32_t>(a), c));
    for (uint64_t v : y.as<uint64_t>()) rays += v;
  }
  return json(rays);
}

Result<json> SummarizeConverged(const io::ContainerReader& r) {
  const Metadata& meta = r.metadata();
  const int level_a = meta.FindArray("sample_level"), rays_a = meta.FindArray("sample_rays"),
            err_a = meta.FindArray("sample_error");
  if (level_a < 0 || rays_a < 0 || err_a < 0) return json(nullptr);
  uint64_t rays = 0;
  std::vector<uint64_t> levels;
  std::vector<float> errors;
  const ArraySpec& ls = meta.arrays[static_cast<uint32_t>(level_a)];
  for (uint64_t c = 0; c < ls.ChunkCount(); ++c) {
    if (r.Find(static_cast<uint32_t>(level_a), c) == nullptr)
      continue;  // a shard's file: its own chunks, as SumSampleRays
    LTB_ASSIGN_OR_RETURN(io::Chunk l, r.ReadChunk(static_cast<uint32_t>(level_a), c));
    LTB_ASSIGN_OR_RETURN(io::Chunk y, r.ReadChunk(static_cast<uint32_t>(rays_a), c));
    LTB_ASSIGN_OR_RETURN(io::Chunk e, r.ReadChunk(static_cast<uint32_t>(err_a), c));
    auto lv = l.as<uint8_t>();
    auto yv = y.as<uint64_t>();
    auto ev = e.as<float>();
    if (yv.size() != lv.size() || ev.size() != lv.size()) {
      return DataLoss(r.path() + ": the converged side tables of chunk " + std::to_string(c) + " differ in length");
    }
    for (size_t i = 0; i < lv.size(); ++i) {
      rays += yv[i];
      if (yv[i] == 0) continue;  // a row that sees no geometry
      if (levels.size() <= lv[i]) levels.resize(lv[i] + 1u, 0);
      levels[lv[i]]++;
      errors.push_back(ev[i]);
    }
  }
  json out = {{"rays", rays}, {"rows_by_highest_level", levels}};
  if (!errors.empty()) {
    std::sort(errors.begin(), errors.end());
    out["row_error"] = {{"median", errors[errors.size() / 2]}, {"max", errors.back()}};
  }
  const json& prov = meta.json.value("provenance", json::object());
  if (prov.is_object() && prov.contains("parameters") && prov["parameters"].is_object()) {
    for (const char* k : {"tolerance", "max_levels", "spp"}) {
      if (prov["parameters"].contains(k)) out[k] = prov["parameters"][k];
    }
  }
  return out;
}

namespace {

// Column-transform / quantize outputs: chosen depths, error, bytes per nonzero; cpca
// outputs: clusters, basis dimension, passes, error (docs/CPCA.md).
void AddStageSummaries(const std::string& path, const Metadata& meta, bool complete, bool content, json& out) {
  if (meta.json.contains("column_transform") && complete) {
    auto ct = stages::SummarizeColumnTransform(path);
    if (ct.ok()) {
      json c = meta.json["column_transform"];
      c["depth_histogram"] = ct->depth_histogram;
      c["empty_columns"] = ct->empty_columns;
      c["nonzeros_kept"] = ct->nonzeros;
      c["relative_rms_error"] = ct->energy > 0 ? std::sqrt(ct->error / ct->energy) : 0.0;
      out["column_transform"] = c;
    }
    if (meta.json.contains("quantization") && !content) {  // the payload bytes from the index alone
      json qj = meta.json["quantization"];
      qj["matrix_bytes"] = out["arrays"][0]["chunks"]["stored_bytes"];
      out["quantization"] = qj;
    } else if (meta.json.contains("quantization")) {
      auto q = stages::SummarizeQuantized(path);
      if (q.ok()) {
        json qj = meta.json["quantization"];
        qj["nonzeros"] = q->nonzeros_out;
        qj["matrix_bytes"] = q->matrix_bytes;
        qj["bytes_per_nonzero"] = q->BytesPerNonzero();
        out["quantization"] = qj;
      }
    }
  }
  if (meta.json.contains("cpca") && meta.json["cpca"].is_object()) out["cpca"] = meta.json["cpca"];
}

}  // namespace

Result<json> InspectContainer(const std::string& path, const InspectOptions& options, const Progress& progress) {
  auto reader_or = io::ContainerReader::Open(path);
  if (!reader_or.ok()) return reader_or.status();
  const io::ContainerReader& reader = *reader_or;
  const Metadata& meta = reader.metadata();

  json out;
  out["file"] = path;
  out["file_bytes"] = reader.file_size();
  out["format_version"] = std::to_string(reader.header().major) + "." + std::to_string(reader.header().minor);
  out["sealed"] = reader.sealed();
  out["complete"] = reader.complete();
  out["uncommitted_tail_bytes"] = reader.uncommitted_tail_bytes();
  out["problems"] = reader.problems();
  if (reader.is_manifest()) {  // a stage manifest: one matrix in shard files
    json shards = json::array();
    for (const auto& s : reader.shards()) shards.push_back({{"file", s->path()}, {"bytes", s->file_size()}});
    out["manifest"] = {{"nshards", reader.shards().size()}, {"shards", shards}};
  }
  if (meta.shard) {  // one shard file of a stage's output
    json ranges = json::array();
    for (const auto& [b, e] : meta.shard->chunks) ranges.push_back({b, e});
    out["shard"] = {{"index", meta.shard->index}, {"count", meta.shard->count}, {"chunks", ranges}};
  }
  out["basis"] = meta.json.value("basis", json(nullptr));
  out["provenance"] = meta.json.value("provenance", json(nullptr));
  if (meta.json.contains("channel")) out["channel"] = meta.json["channel"];  // docs/COLOUR.md
  if (meta.json.contains("term")) out["term"] = meta.json["term"];  // a colour factored bake's (docs/GLOSSY.md)
  out["arrays"] = json::array();
  for (uint32_t i = 0; i < meta.arrays.size(); ++i) {
    const ArraySpec& a = meta.arrays[i];
    json j = a.ToJson();
    j["chunks"] = ChunkCounts(reader, i);
    // What the writer recorded while writing; with content read, checked against it.
    const std::string recorded = reader.RecordedContentHash(i);
    if (!recorded.empty()) j["content_hash"] = recorded;
    if (options.content) {
      auto summary = io::SummarizeArray(reader, i, options.jobs, progress);
      if (!summary.ok()) return summary.status();
      AddContent(*summary, j);
      if (!recorded.empty() && recorded != summary->content_hash) {
        j["recorded_content_hash"] = recorded;
        out["problems"].push_back("array \"" + a.name + "\": the writer recorded content_hash " + recorded +
                                  ", but the chunks hash to " + summary->content_hash + " (run ltbake verify)");
      }
    }
    out["arrays"].push_back(j);
  }
  out["on_disk"] = OnDisk(reader, out["arrays"]);
  // The matrix (array 0) at top level, as DESIGN.md lists the keys.
  const json& m = out["arrays"][0];
  for (const char* k : {"shape", "dtype", "layout", "block", "chunks", "content_hash", "stats"}) {
    if (m.contains(k)) out[k] = m[k];
  }
  AddStageSummaries(path, meta, reader.complete(), options.content, out);
  if (reader.complete()) {
    auto sparse = SummarizeSparse(reader);
    if (!sparse.ok()) return sparse.status();
    if (!sparse->is_null()) out["sparse"] = *sparse;
    auto converged = SummarizeConverged(reader);
    if (!converged.ok()) return converged.status();
    if (!converged->is_null()) out["converged"] = *converged;
    // The rays of any sample output: full and converged ones per row (a converged summary
    // has summed them already), sparse ones by phase.
    auto rays = out.contains("converged") ? Result<json>(out["converged"]["rays"]) : SumSampleRays(reader);
    if (!rays.ok()) return rays.status();
    if (!rays->is_null()) {
      out["rays"] = *rays;
    } else if (out.contains("sparse") && out["sparse"].contains("rays")) {
      out["rays"] =
          out["sparse"]["rays"].value("dense", uint64_t{0}) + out["sparse"]["rays"].value("sparse", uint64_t{0});
    }
  }
  if (options.chunk_list) out["chunk_list"] = ChunkList(reader);
  return out;
}

}  // namespace ltb::stages
