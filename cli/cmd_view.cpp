// ltbake view MATRIX --env MAP [--env MAP2 ...] [--terms N] [--method pbi|bi|nwa] [--reference M]
//             [--sequence SPEC] [--port P]
// An interactive relighting page on 127.0.0.1 (docs/VIEW.md); the URL is the first line of
// stdout. Ctrl-C stops it.
#include <iostream>

#include "cli/commands.h"
#include "cli/common.h"
#include "stages/images/envmap.h"
#include "stages/view/server.h"

namespace ltb::cli {
namespace {

class ViewCommand : public Command {
 public:
  explicit ViewCommand(CLI::App* parent) {
    auto* app = parent->add_subcommand(
        "view", "serve an interactive relighting page on 127.0.0.1: drag to rotate the environment (docs/VIEW.md)");
    app->add_option("MATRIX", o_.matrix,
                    "an image bake relight reads: final.ltm, cols4d.ltm, cols.ltm, cpca.ltm, rows.ltm")
        ->required();
    app->add_option("--env", o_.envs, "environment map (.exr or .hdr); repeat it to pick among several on the page")
        ->required()
        ->take_all();
    app->add_option("--terms", terms_text_, "lighting terms a frame to start with, N >= 1 or all")
        ->default_val("100")
        ->check(TermsCheck());
    app->add_option("--method", method_, "pbi, bi or nwa to start with")
        ->default_val("pbi")
        ->check(CLI::IsMember({"pbi", "bi", "nwa"}));
    app->add_option("--reference", o_.reference, "a matrix whose exact T·L each frame is compared with");
    app->add_option("--port", o_.port, "port on 127.0.0.1 (0: a free one)")
        ->default_val(0)
        ->check(CLI::Range(0, 65535));
    app->add_option("--env-layout", layout_, "auto, latlong, hcross, vcross, faces or angular (light probe)")
        ->default_val("auto")
        ->check(CLI::IsMember({"auto", "latlong", "hcross", "vcross", "faces", "angular"}));
    app->add_flag("--clamp", o_.clamp_env, "clamp negative, NaN and infinite radiance to valid values");
    app->add_option("--sequence", sequence_,
                    "a lighting sequence from each map (relight's grammar: rotate:DEG:FRAMES, hold:FRAMES, "
                    "maps:A+B, fade:A+B:FRAMES; docs/SEQUENCE.md): the page's time slider scrubs and plays it");
    AddCommonFlags(app, &flags_);
  }

  int Run() override {
    o_.terms = terms_text_ == "all" ? stages::RelightOptions::kAllTerms : std::stoull(terms_text_);
    o_.method = *stages::ParseSequenceMethod(method_);  // checked by IsMember
    o_.env_layout = *stages::ParseEnvLayout(layout_);   // checked by IsMember
    if (!sequence_.empty()) {
      auto seq = stages::ParseSequence(sequence_);
      if (!seq.ok()) return ReportUsage(seq.status().WithContext("--sequence " + sequence_));
      o_.sequence = std::move(*seq);
    }
    StageFlags sf;
    if (int code = ResolveStageFlags(flags_, nullptr, &sf); code != kExitOk) return code;
    o_.mem_limit = sf.mem_limit;
    o_.jobs = sf.jobs;
    Status s = stages::view::Serve(
        o_,
        [](const std::string& url) {
          std::cout << url << std::endl;
          std::cerr << "ltbake view: serving " << url << " (Ctrl-C stops)" << std::endl;
        },
        [] { return ReceivedSignal() != 0; });
    if (!s.ok()) return ReportFailure(s);
    if (ReceivedSignal() != 0) {  // Ctrl-C: the usual end of a view, exit 130/143 like any interruption
      std::cerr << "ltbake view: stopped\n";
      return ExitCodeFor(Ending::kInterrupted, ReceivedSignal());
    }
    return kExitOk;
  }

 private:
  stages::view::ViewOptions o_;
  std::string terms_text_ = "100", method_ = "pbi", layout_ = "auto", sequence_;
  CommonFlags flags_;
};

}  // namespace

std::unique_ptr<Command> RegisterView(CLI::App* parent) { return std::make_unique<ViewCommand>(parent); }

}  // namespace ltb::cli
