// ltbake view MATRIX --env MAP [--env MAP2 ...] [--terms N] [--method pbi|bi|nwa] [--reference M]
//             [--sequence SPEC] [--port P] [--eye X,Y,Z --target X,Y,Z --up --fov --size --brdf-terms]
// An interactive relighting page on 127.0.0.1 (docs/VIEW.md); the URL is the first line of
// stdout. Ctrl-C stops it.
#include <iostream>
#include <tuple>

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
                    "a bake relight reads: final.ltm, cols4d.ltm, cols.ltm, cpca.ltm, rows.ltm; a vertex bake (plain "
                    "or a factored set X.ltm of sample --factor K) is seen from an eye the page moves")
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
    app->add_option("--eye", eye_, "a vertex bake: where the eye starts, X,Y,Z (default: in front of the mesh)");
    app->add_option("--target", target_, "a vertex bake: the point looked at, X,Y,Z (default: the mesh's centre)");
    app->add_option("--up", up_, "a vertex bake: the camera's up, X,Y,Z")->default_val("0,0,1");
    app->add_option("--fov", o_.fov_degrees, "a vertex bake: vertical field of view, degrees")
        ->default_val(40)
        ->check(CLI::Range(0.01, 179.0));
    app->add_option("--size", size_, "a vertex bake: the image, WIDTHxHEIGHT")->default_val("256x256");
    app->add_option("--brdf-terms", o_.brdf_terms, "a factored vertex bake: the BRDF terms used (0: all)")
        ->default_val(0)
        ->check(CLI::Range(0, 64));
    AddCommonFlags(app, &flags_);
    app_ = app;
  }

  int Run() override {
    o_.terms = terms_text_ == "all" ? stages::RelightOptions::kAllTerms : std::stoull(terms_text_);
    o_.terms_given = app_->count("--terms") > 0;
    o_.method = *stages::ParseSequenceMethod(method_);  // checked by IsMember
    o_.env_layout = *stages::ParseEnvLayout(layout_);   // checked by IsMember
    if (!sequence_.empty()) {
      auto seq = stages::ParseSequence(sequence_);
      if (!seq.ok()) return ReportUsage(seq.status().WithContext("--sequence " + sequence_));
      o_.sequence = std::move(*seq);
    }
    for (auto [text, dst, name] : {std::tuple{&eye_, &o_.eye, "--eye"}, std::tuple{&target_, &o_.target, "--target"}}) {
      if (text->empty()) continue;
      glm::dvec3 v;
      if (!ParseVec3(*text, &v))
        return ReportUsage(InvalidArgument(std::string(name) + " " + *text + ": expected X,Y,Z"));
      *dst = v;
    }
    if (!ParseVec3(up_, &o_.up)) return ReportUsage(InvalidArgument("--up " + up_ + ": expected X,Y,Z"));
    for (const char* flag : {"--eye", "--target", "--up", "--fov", "--size", "--brdf-terms"}) {
      if (app_->count(flag) > 0) o_.eye_flags += std::string(o_.eye_flags.empty() ? "" : ", ") + flag;
    }
    if (!ParseViewSize(size_, &o_.width, &o_.height)) {
      return ReportUsage(InvalidArgument("--size " + size_ + ": expected WIDTHxHEIGHT, each 1..16384, e.g. 512x384"));
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
  std::string terms_text_ = "100", method_ = "pbi", layout_ = "auto", sequence_, eye_, target_, up_ = "0,0,1",
              size_ = "256x256";
  CommonFlags flags_;
  CLI::App* app_ = nullptr;
};

}  // namespace

std::unique_ptr<Command> RegisterView(CLI::App* parent) { return std::make_unique<ViewCommand>(parent); }

}  // namespace ltb::cli
