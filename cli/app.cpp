// The ltbake command line: parses the subcommand and hands over to it.
#include <iostream>
#include <map>
#include <stdexcept>

#include "cli/commands.h"
#include "cli/common.h"
#include "format/version.h"
#include "stages/common/channels.h"
#include "stages/common/suggest.h"

namespace {

void PrintVersion() {
  using namespace ltb;
  std::cout << "ltbake " << kToolVersion << "\n"
            << ".ltm format: writes " << format::kFormatMajor << "." << format::kFormatMinor << ", reads "
            << format::kFormatMajor << ".x\n";
}

}  // namespace

namespace ltb::cli {

namespace {

// Runs the command, once per member file when its input names a set (colour channels
// X.r.ltm ..., a factored bake's terms X.k0.ltm ...; stages/common/channels.h).
int RunOverMembers(Command& cmd) {
  std::vector<std::string*> paths = cmd.ChannelSetPaths();
  if (paths.empty()) return cmd.Run();
  auto members = stages::ChannelFiles(*paths.front());
  if (!members.ok()) return ReportFailure(members.status());
  if (members->empty()) return cmd.Run();
  std::vector<std::string> sets;
  for (const std::string* p : paths) sets.push_back(*p);
  for (const stages::SetMember& m : *members) {
    for (size_t i = 0; i < paths.size(); ++i) {
      if (!sets[i].empty()) *paths[i] = stages::SetMemberPath(sets[i], m.name);
    }
    // A member may be a set itself (a colour factored bake's term X.k0.ltm: X.k0.r.ltm ...).
    if (int code = RunOverMembers(cmd); code != kExitOk) return code;
  }
  return kExitOk;
}

}  // namespace

const std::vector<CommandInfo>& CommandList() {
  static const std::vector<CommandInfo> list = {
      {"inspect", RegisterInspect, false,
       "ltbake inspect final.ltm\n"
       "ltbake inspect rows.ltm --json --chunks  # every chunk's place, encoding and checksum\n"
       "ltbake inspect big.ltm --content  # also read every chunk: value statistics, content_hash recomputed"},
      {"verify", RegisterVerify, false,
       "ltbake verify raw.ltm rows.ltm final.ltm\n"
       "ltbake verify --allow-incomplete --json raw.ltm  # a bake still running or interrupted"},
      {"convert", RegisterConvert, false,
       "ltbake convert T.npy raw.ltm --cube-res 32 --image 256x256\n"
       "ltbake convert final.ltm T.npy --basis pixels  # decode to the pixel basis\n"
       "ltbake convert sky.exr sky.npy --cube-res 32  # an environment map as a 6R^2 x 3 cubemap"},
      {"row-transform", RegisterRowTransform, true,
       "ltbake row-transform raw.ltm -o rows.ltm\n"
       "ltbake row-transform raw.ltm -o rows.ltm --filter db2 --zstd"},
      {"transpose", RegisterTranspose, true, "ltbake transpose rows.ltm -o cols.ltm --mem-limit 1GiB"},
      {"sample", RegisterSample, true,
       "ltbake sample scene.toml -o raw.ltm\n"
       "ltbake sample scene.toml -o raw.ltm --cube-res 64 --spp 16 --bounces 1\n"
       "ltbake sample scene.toml -o raw.ltm --tolerance 1% --spp 2 --max-levels 6  # converged sampling\n"
       "ltbake sample scene.toml -o rows.ltm --row-transform haar  # sample and row-transform in one pass"},
      {"column-transform", RegisterColumnTransform, true,
       "ltbake column-transform cols.ltm -o cols4d.ltm  # adaptive depth, a 5% budget\n"
       "ltbake column-transform cols.ltm -o cols4d.ltm --target-error 2%"},
      {"quantize", RegisterQuantize, true,
       "ltbake quantize cols4d.ltm -o final.ltm\n"
       "ltbake quantize cols4d.ltm -o final.ltm --bits 9  # per-column maxima, as the 2007 paper"},
      {"cpca", RegisterCpca, true, "ltbake cpca rows.ltm -o cpca.ltm --clusters 16 --basis 8"},
      {"relight", RegisterRelight, true,
       "ltbake relight final.ltm --env sky.exr -o relit.png --terms 200\n"
       "ltbake relight final.ltm --env probe.hdr --env-layout angular -o relit.exr --reference rows.ltm\n"
       "ltbake relight final.ltm --env sky.exr --sequence rotate:3.6:100 -o relit.mp4  # docs/SEQUENCE.md"},
      {"run", RegisterRun, false,
       "ltbake run bake.toml\n"
       "ltbake run bake.toml --dry-run  # the plan, and why each step runs or is skipped\n"
       "ltbake run bake.toml --workdir out/b2 --shards 4 --engine slurm"},
      {"commit", RegisterCommit, false,
       "ltbake commit raw.ltm --nshards 4  # after ltbake sample ... --shard I --nshards 4"},
      {"merge", RegisterMerge, false, "ltbake merge raw.ltm -o raw-one-file.ltm"},
      {"material", RegisterMaterial, false, "ltbake material --brdf phong:64 --cube-res 32 -o phong64.ltm"},
      {"view", RegisterView, false,
       "ltbake view final.ltm --env sky.exr  # prints http://127.0.0.1:PORT/\n"
       "ltbake view final.ltm --env a.exr --env b.hdr --reference rows.ltm --sequence fade:a.exr+b.hdr:50  # A/B, "
       "time slider\n"
       "ltbake view glossy.ltm --env sky.exr --clamp --size 512x512  # a vertex bake (glossy.k0.ltm ..) from a moving "
       "eye"},
  };
  return list;
}

namespace {

// Each line of `text` indented by two spaces.
std::string Indented(const std::string& text) {
  std::string out = "  ";
  for (char ch : text) out += ch == '\n' ? std::string("\n  ") : std::string(1, ch);
  return out;
}

// The command line: the top-level flags and every command's subcommand.
struct CommandLine {
  CLI::App app{
      "ltbake: bake and compress light transport matrices for all-frequency relighting.\n"
      "Exit codes: 0 ok, 1 failed, 2 usage error, 130/143 interrupted (state committed; rerun resumes)."};
  bool version = false;
  std::map<CLI::App*, std::unique_ptr<Command>> commands;

  CommandLine() {
    app.name("ltbake");
    app.require_subcommand(0, 1);
    app.add_flag("--version", version, "print the tool version and the .ltm format versions it reads and writes");
    for (const CommandInfo& c : CommandList()) {
      auto cmd = c.add(&app);
      CLI::App* sub = app.get_subcommands({}).back();
      if (sub->get_name() != c.name) {
        throw std::logic_error(std::string("command list: '") + c.name + "' registers '" + sub->get_name() + "'");
      }
      sub->footer(std::string("\nExamples:\n") + Indented(c.examples));
      commands[sub] = std::move(cmd);
    }
  }

  // "" when argv[1] is no flag and names a command (or is absent), else the usage error.
  std::string UnknownCommand(int argc, char** argv) const {
    if (argc <= 1 || argv[1][0] == '-') return "";
    const std::string name = argv[1];
    std::string names;
    std::vector<std::string> all;
    for (const CommandInfo& c : CommandList()) {
      if (name == c.name) return "";
      names += (names.empty() ? "" : ", ") + std::string(c.name);
      all.emplace_back(c.name);
    }
    const std::string nearest = Nearest(name, all);
    const std::string hint = nearest.empty() ? "" : "; did you mean '" + nearest + "'?";
    return "unknown command '" + name + "'" + hint + " (commands: " + names + ")";
  }
};

}  // namespace

std::string ParseOnly(const std::vector<std::string>& args) {
  CommandLine cl;
  std::vector<std::string> storage = {"ltbake"};
  storage.insert(storage.end(), args.begin(), args.end());
  std::vector<char*> argv;
  for (auto& a : storage) argv.push_back(a.data());
  if (std::string e = cl.UnknownCommand(static_cast<int>(argv.size()), argv.data()); !e.empty()) return e;
  try {
    cl.app.parse(static_cast<int>(argv.size()), argv.data());
  } catch (const CLI::ParseError& e) {
    return e.what();
  }
  return "";
}

int LtbakeMain(int argc, char** argv) {
  // `ltbake --list-commands` (for the build's stage links and shell completion; not in
  // --help): every command, one a line, then " stage" when it is also ltbake-<name>.
  if (argc == 2 && std::string(argv[1]) == "--list-commands") {
    for (const CommandInfo& c : CommandList()) std::cout << c.name << (c.stage_executable ? " stage\n" : "\n");
    return kExitOk;
  }
  CommandLine cl;
  if (std::string e = cl.UnknownCommand(argc, argv); !e.empty()) {
    std::cerr << "ltbake: usage error: " << e << "\nRun 'ltbake --help' for usage.\n";
    return kExitUsage;
  }
  try {
    cl.app.parse(argc, argv);
  } catch (const CLI::CallForHelp& e) {
    return cl.app.exit(e);  // help goes to stdout, exit 0
  } catch (const CLI::CallForAllHelp& e) {
    return cl.app.exit(e);
  } catch (const CLI::ParseError& e) {
    std::cerr << "ltbake: usage error: " << e.what() << "\n"
              << "Run 'ltbake --help' (or 'ltbake COMMAND --help') for usage.\n";
    return kExitUsage;
  }
  if (cl.version) {
    PrintVersion();
    return kExitOk;
  }

  auto chosen = cl.app.get_subcommands();
  if (chosen.empty()) {
    std::cerr << "ltbake: usage error: no command given\n" << cl.app.help();
    return kExitUsage;
  }
  InstallSignalHandlers();
  return RunOverMembers(*cl.commands.at(chosen.front()));
}

}  // namespace ltb::cli
