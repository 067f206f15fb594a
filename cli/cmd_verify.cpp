// ltbake verify FILE... [--allow-incomplete] [--json]
#include <iostream>
#include <nlohmann/json.hpp>

#include "cli/commands.h"
#include "cli/common.h"
#include "format/io/verifier.h"
#include "format/json_text.h"

namespace ltb::cli {
namespace {

class VerifyCommand : public Command {
 public:
  explicit VerifyCommand(CLI::App* parent) {
    auto* app = parent->add_subcommand(
        "verify", "check every checksum and structural invariant; exit 0 when all files are intact and complete");
    app->add_option("FILE", paths_, "the .ltm files")->required();
    app->add_flag("--allow-incomplete", allow_incomplete_,
                  "accept files that are intact but not finished (a writer was interrupted)");
    app->add_flag("--json", json_, "print one JSON object per file");
    AddCommonFlags(app, &flags_);
  }

  int Run() override {
    bool all_good = true;
    nlohmann::json list = nlohmann::json::array();
    for (const std::string& path : paths_) {
      io::VerifyReport r = io::VerifyContainer(path, flags_.jobs);
      bool incomplete = r.readable && r.problems.empty() && !r.complete;
      bool good = r.problems.empty() && (r.complete || (incomplete && allow_incomplete_));
      all_good = all_good && good;
      if (json_) {
        list.push_back({{"file", path},
                        {"ok", good},
                        {"readable", r.readable},
                        {"sealed", r.sealed},
                        {"complete", r.complete},
                        {"chunks_expected", r.chunks_expected},
                        {"chunks_ok", r.chunks_ok},
                        {"uncommitted_tail_bytes", r.uncommitted_tail_bytes},
                        {"content_hash", r.content_hash},
                        {"recorded_content_hash", r.recorded_content_hash},
                        {"problems", r.problems},
                        {"notes", r.notes}});
        continue;
      }
      if (!r.problems.empty()) {
        std::cout << "FAIL " << path << ": " << r.problems.size() << " problem" << (r.problems.size() > 1 ? "s" : "")
                  << "\n";
        for (const auto& p : r.problems) std::cout << "  " << p << "\n";
      } else if (incomplete) {
        std::cout << (allow_incomplete_ ? "ok   " : "INCOMPLETE ") << path << ": " << r.chunks_ok << " of "
                  << r.chunks_expected << " chunks committed and intact, not sealed"
                  << (r.uncommitted_tail_bytes
                          ? "; " + std::to_string(r.uncommitted_tail_bytes) + " uncommitted bytes at the end"
                          : "")
                  << " (rerun the stage that writes it to resume)\n";
      } else if (!flags_.quiet) {
        std::cout << "ok   " << path << ": " << r.chunks_ok << " chunks, sealed, complete\n";
      }
      if (flags_.verbose)
        for (const auto& n : r.notes) std::cout << "  note: " << n << "\n";
    }
    if (json_) std::cout << JsonText(list, 2) << "\n";
    return all_good ? kExitOk : kExitFailed;
  }

 private:
  std::vector<std::string> paths_;
  bool allow_incomplete_ = false, json_ = false;
  CommonFlags flags_;
};

}  // namespace

std::unique_ptr<Command> RegisterVerify(CLI::App* parent) { return std::make_unique<VerifyCommand>(parent); }

}  // namespace ltb::cli
