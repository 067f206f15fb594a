// ltbake inspect FILE [--json] [--chunks] [--content]
#include <cstdio>
#include <iostream>
#include <nlohmann/json.hpp>

#include "cli/commands.h"
#include "cli/common.h"
#include "format/json_text.h"
#include "stages/inspect/inspect.h"

namespace ltb::cli {
namespace {

using nlohmann::json;

class InspectCommand : public Command {
 public:
  explicit InspectCommand(CLI::App* parent) {
    auto* app = parent->add_subcommand("inspect", "describe a container: shape, layout, chunks, content_hash, stats");
    app->add_option("FILE", path_, "the .ltm file")->required();
    app->add_flag("--json", json_, "print one JSON object (stable keys, for scripts)");
    app->add_flag("--chunks", chunks_, "list every committed chunk frame");
    app->add_flag("--content", content_,
                  "read every chunk: value statistics, content_hash recomputed and checked against the recorded "
                  "one, the nonzeros of a quantized matrix (without it: the header, metadata, index and the recorded "
                  "content_hash, milliseconds for any size)");
    // The default since 2026-12-02; still accepted for scripts written before.
    app->add_flag("--no-content", no_content_, "")->group("");
    AddCommonFlags(app, &flags_);
  }

  std::vector<std::string*> ChannelSetPaths() override { return {&path_}; }

  int Run() override {
    stages::InspectOptions o;
    o.content = content_ && !no_content_;
    o.chunk_list = chunks_;
    o.jobs = flags_.jobs;
    ProgressBar bar(flags_, "inspect");
    auto out_or = stages::InspectContainer(path_, o, bar.hook());
    bar.Done();
    if (!out_or.ok()) return ReportFailure(out_or.status());
    const json& out = *out_or;
    if (json_) {
      std::cout << JsonText(out, 2) << "\n";
    } else {
      PrintText(out);
    }
    return kExitOk;
  }

 private:
  void PrintText(const json& out) {
    std::cout << path_ << ": .ltm format " << out["format_version"].get<std::string>() << ", "
              << HumanBytes(out["file_bytes"]) << ", " << (out["complete"].get<bool>() ? "complete" : "INCOMPLETE")
              << (out["sealed"].get<bool>() ? " (sealed)" : " (not sealed)") << "\n";
    if (out.contains("manifest")) {
      std::cout << "  stage manifest of " << JsonText(out["manifest"]["nshards"]) << " shards:";
      for (const json& s : out["manifest"]["shards"]) std::cout << " " << s["file"].get<std::string>();
      std::cout << "\n";
    }
    if (out.contains("shard")) {
      std::cout << "  shard " << JsonText(out["shard"]["index"]) << " of " << JsonText(out["shard"]["count"])
                << " (holds only its own chunks; `ltbake commit` joins the shards)\n";
    }
    {
      const json& d = out["on_disk"];
      char pct[32];
      std::snprintf(pct, sizeof pct, "%.1f%%", 100 * d["overhead_fraction"].get<double>());
      std::cout << "  on disk: " << HumanBytes(d["total_bytes"]) << " = matrix " << HumanBytes(d["matrix_bytes"])
                << " + side tables " << HumanBytes(d["side_table_bytes"]) << " + container "
                << HumanBytes(d["overhead_bytes"]) << " (" << pct << ": headers, index, content hashes, padding)\n";
    }
    for (const json& a : out["arrays"]) {
      const json& c = a["chunks"];
      std::cout << "  " << a["name"].get<std::string>() << ": " << JsonText(a["shape"][0]) << " x "
                << JsonText(a["shape"][1]) << " " << a["dtype"].get<std::string>() << ", layout "
                << a["layout"].get<std::string>() << " (block " << JsonText(a["block"]) << "), chunks "
                << JsonText(c["committed"]) << "/" << JsonText(c["expected"]) << " (raw " << JsonText(c["raw"])
                << ", zero " << JsonText(c["zero"]) << ", zstd " << JsonText(c["zstd"])
                << (c.contains("sparse")
                        ? ", sparse " + JsonText(c["sparse"]) + ", sparse+zstd " + JsonText(c["sparse_zstd"]) +
                              ", sparse-coded " + JsonText(c["sparse_coded"])
                        : std::string())
                << "), stored " << HumanBytes(c["stored_bytes"]) << "\n";
      if (a.contains("content_hash")) {
        std::cout << "    content_hash: "
                  << (a["content_hash"].is_null() ? "(incomplete)" : a["content_hash"].get<std::string>())
                  << (a.contains("stats") ? "" : " (as its writer recorded it)") << "\n";
      }
      if (a.contains("stats")) {  // with --content
        const json& s = a["stats"];
        auto num = [](const json& v) {
          if (v.is_null()) return std::string("-");
          char buf[32];
          std::snprintf(buf, sizeof buf, "%.6g", v.get<double>());
          return std::string(buf);
        };
        char nz[32];
        std::snprintf(nz, sizeof nz, "%.2f%%", 100 * s["nonzero_fraction"].get<double>());
        std::cout << "    stats: min " << num(s["min"]) << ", max " << num(s["max"]) << ", mean " << num(s["mean"])
                  << ", nonzero " << nz << ", NaN " << JsonText(s["nan_count"]) << ", Inf " << JsonText(s["inf_count"])
                  << "\n";
      }
    }
    if (!content_ || no_content_) {
      std::cout << "  payloads not read: --content reads every chunk (value statistics, content_hash recomputed); "
                   "`ltbake verify` checks every checksum\n";
    }
    if (!out["basis"].is_null()) std::cout << "  basis: " << JsonText(out["basis"]) << "\n";
    if (!out["provenance"].is_null()) std::cout << "  provenance: " << JsonText(out["provenance"]) << "\n";
    // A set member: a colour channel, a factored bake's term, or both (docs/COLOUR.md, docs/GLOSSY.md).
    for (const char* key : {"channel", "term"}) {
      if (!out.contains(key) || !out[key].is_object()) continue;
      const json& m = out[key];
      const bool term = m.contains("factor");
      std::cout << "  " << (term ? "factored term: " : "colour channel: ") << m.value("name", std::string("?"))
                << " of " << (m.contains("names") && m["names"].is_array() ? m["names"].size() : 0)
                << (term ? " (docs/GLOSSY.md)\n" : " (docs/COLOUR.md)\n");
    }
    PrintStageSummaries(out);
    if (out["uncommitted_tail_bytes"].get<uint64_t>() > 0) {
      std::cout << "  uncommitted tail: " << JsonText(out["uncommitted_tail_bytes"])
                << " bytes (a chunk in flight when the writer stopped; a rerun discards it)\n";
    }
    for (const json& p : out["problems"]) std::cout << "  problem: " << p.get<std::string>() << "\n";
    if (out.contains("chunk_list")) {
      std::cout << "  chunks (array index offset encoding stored decoded checksum):\n";
      for (const json& c : out["chunk_list"]) {
        std::cout << "    " << c["array"].get<std::string>() << " " << JsonText(c["index"]) << " "
                  << JsonText(c["offset"]) << " " << c["encoding"].get<std::string>() << " "
                  << JsonText(c["stored_bytes"]) << " " << JsonText(c["decoded_bytes"]) << " "
                  << c["checksum"].get<std::string>() << "\n";
      }
    }
  }

  // The column-transform, quantize, cpca and sparse summaries of PrintText.
  static void PrintStageSummaries(const json& out) {
    if (out.contains("column_transform")) {
      const json& c = out["column_transform"];
      std::cout << "  column transform: filter " << c.value("filter", "?") << ", depth " << c.value("depth", "?")
                << ", " << JsonText(c["nonzeros_kept"]) << " nonzeros kept, relative RMS error "
                << JsonText(c["relative_rms_error"]) << "\n    columns per depth:";
      for (size_t d = 0; d < c["depth_histogram"].size(); ++d)
        std::cout << " " << d << ":" << JsonText(c["depth_histogram"][d]);
      std::cout << " (and " << JsonText(c["empty_columns"]) << " empty)\n";
    }
    if (out.contains("quantization")) {
      const json& q = out["quantization"];
      std::cout << "  quantization: " << JsonText(q.value("bits", json())) << " bits, scaling "
                << q.value("scaling", "?") << ", matrix payload " << HumanBytes(q.value("matrix_bytes", json(0)));
      if (q.contains("nonzeros") && q.contains("bytes_per_nonzero") && q["bytes_per_nonzero"].is_number()) {
        std::cout << ", " << JsonText(q["nonzeros"]) << " nonzeros (" << q["bytes_per_nonzero"].get<double>()
                  << " bytes per nonzero)";
      } else {
        std::cout << " (--content counts its nonzeros)";
      }
      std::cout << "; the whole file: `on disk` above\n";
    }
    if (out.contains("cpca")) {
      const json& c = out["cpca"];
      std::cout << "  cpca: " << JsonText(c.value("clusters", json())) << " clusters x "
                << JsonText(c.value("basis_dim", json())) << " directions, " << JsonText(c.value("rows", json()))
                << " rows of " << JsonText(c.value("dims", json())) << ", " << JsonText(c.value("iterations", json()))
                << " passes, relative RMS error " << JsonText(c.value("relative_rms_error", json()))
                << ", empty clusters " << JsonText(c.value("empty_clusters", json())) << "\n";
    }
    if (out.contains("sparse")) {
      const json& sp = out["sparse"];
      char line[400];
      std::snprintf(
          line, sizeof line,
          "  sparse bake: %s dense rows, %s sparse (%s of them traced in full); traced %.2f%% of the "
          "entries; rays phase 1 %s, phase 2 %s; thread-seconds phase 1 %.3g, phase 2 %.3g\n",
          JsonText(sp["rows"]["dense"]).c_str(),
          std::to_string(sp["rows"]["sparse"].get<uint64_t>() + sp["rows"]["traced_in_full"].get<uint64_t>()).c_str(),
          JsonText(sp["rows"]["traced_in_full"]).c_str(), 100 * sp["traced_fraction"].get<double>(),
          JsonText(sp["rays"]["dense"]).c_str(), JsonText(sp["rays"]["sparse"]).c_str(),
          sp["seconds"]["dense"].get<double>(), sp["seconds"]["sparse"].get<double>());
      std::cout << line;
    }
  }

  std::string path_;
  bool json_ = false, chunks_ = false, content_ = false, no_content_ = false;
  CommonFlags flags_;
};

}  // namespace

std::unique_ptr<Command> RegisterInspect(CLI::App* parent) { return std::make_unique<InspectCommand>(parent); }

}  // namespace ltb::cli
