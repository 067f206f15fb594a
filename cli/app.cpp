// The ltbake command line: parses the subcommand and hands over to it.
#include <iostream>
#include <map>

#include "cli/commands.h"
#include "cli/common.h"
#include "format/version.h"
#include "stages/common/channels.h"

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
    if (int code = cmd.Run(); code != kExitOk) return code;
  }
  return kExitOk;
}

}  // namespace

int LtbakeMain(int argc, char** argv) {
  CLI::App app{
      "ltbake: bake and compress light transport matrices for all-frequency relighting.\n"
      "Exit codes: 0 ok, 1 failed, 2 usage error, 130/143 interrupted (state committed; rerun resumes)."};
  app.name("ltbake");
  app.require_subcommand(0, 1);
  bool version = false;
  app.add_flag("--version", version, "print the tool version and the .ltm format versions it reads and writes");

  std::map<CLI::App*, std::unique_ptr<Command>> commands;
  for (auto reg : {RegisterInspect, RegisterVerify, RegisterConvert, RegisterRowTransform, RegisterTranspose,
                   RegisterSample, RegisterColumnTransform, RegisterQuantize, RegisterCpca, RegisterRelight,
                   RegisterRun, RegisterCommit, RegisterMerge, RegisterMaterial, RegisterView}) {
    auto cmd = reg(&app);
    commands[app.get_subcommands({}).back()] = std::move(cmd);
  }

  if (argc > 1 && argv[1][0] != '-') {
    std::string name = argv[1];
    bool known = false;
    std::string names;
    for (const auto* sub : app.get_subcommands({})) {
      known = known || sub->get_name() == name;
      names += (names.empty() ? "" : ", ") + sub->get_name();
    }
    if (!known) {
      std::cerr << "ltbake: usage error: unknown command '" << name << "' (commands: " << names << ")\n"
                << "Run 'ltbake --help' for usage.\n";
      return kExitUsage;
    }
  }
  try {
    app.parse(argc, argv);
  } catch (const CLI::CallForHelp& e) {
    return app.exit(e);  // help goes to stdout, exit 0
  } catch (const CLI::CallForAllHelp& e) {
    return app.exit(e);
  } catch (const CLI::ParseError& e) {
    std::cerr << "ltbake: usage error: " << e.what() << "\n"
              << "Run 'ltbake --help' (or 'ltbake COMMAND --help') for usage.\n";
    return kExitUsage;
  }
  if (version) {
    PrintVersion();
    return kExitOk;
  }
  auto chosen = app.get_subcommands();
  if (chosen.empty()) {
    std::cerr << "ltbake: usage error: no command given\n" << app.help();
    return kExitUsage;
  }
  InstallSignalHandlers();
  return RunOverMembers(*commands.at(chosen.front()));
}

}  // namespace ltb::cli
