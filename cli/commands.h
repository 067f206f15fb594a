// The subcommands of `ltbake`. Each registers its flags on a CLI11 subcommand and runs
// after parsing, returning the process exit code.
#pragma once

#include <CLI/CLI.hpp>
#include <memory>
#include <string>
#include <vector>

namespace ltb::cli {

class Command {
 public:
  virtual ~Command() = default;
  virtual int Run() = 0;
  // The input (first) and output paths of a stage that runs once per file of a set
  // (stages/common/channels.h): given X.ltm where X.r.ltm, X.g.ltm and X.b.ltm (or a
  // factored bake's X.k0.ltm ...) exist instead, LtbakeMain runs it on each, with each
  // path's member file. Empty: the command does not (sample, relight and convert handle
  // sets themselves).
  virtual std::vector<std::string*> ChannelSetPaths() { return {}; }
};

std::unique_ptr<Command> RegisterInspect(CLI::App* parent);
std::unique_ptr<Command> RegisterVerify(CLI::App* parent);
std::unique_ptr<Command> RegisterConvert(CLI::App* parent);
std::unique_ptr<Command> RegisterRowTransform(CLI::App* parent);
std::unique_ptr<Command> RegisterTranspose(CLI::App* parent);
std::unique_ptr<Command> RegisterSample(CLI::App* parent);
std::unique_ptr<Command> RegisterColumnTransform(CLI::App* parent);
std::unique_ptr<Command> RegisterQuantize(CLI::App* parent);
std::unique_ptr<Command> RegisterRelight(CLI::App* parent);
std::unique_ptr<Command> RegisterCpca(CLI::App* parent);
std::unique_ptr<Command> RegisterRun(CLI::App* parent);
std::unique_ptr<Command> RegisterCommit(CLI::App* parent);
std::unique_ptr<Command> RegisterMerge(CLI::App* parent);
std::unique_ptr<Command> RegisterMaterial(CLI::App* parent);
std::unique_ptr<Command> RegisterView(CLI::App* parent);

// The whole ltbake command line (main and the ltbake-<stage> executables call it).
// Every ltbake command: the one list that dispatch, `ltbake --help` (in this order) and the
// stage executables read. A command with `stage_executable` is also ltbake-<name>, a link
// that the build and `cmake --install` make from `ltbake --list-commands`
// (scripts/stage_links.cmake); tests/pipeline/stage_commands_test.cpp checks the links.
struct CommandInfo {
  const char* name;  // its subcommand's name (checked when the command line is built)
  std::unique_ptr<Command> (*add)(CLI::App* parent);
  bool stage_executable;
  // Its --help's "Examples:" footer, one command line a line (each parses: a test runs them
  // through ParseOnly), a comment after "  # ".
  const char* examples;
};
const std::vector<CommandInfo>& CommandList();

int LtbakeMain(int argc, char** argv);

// Parses `args` (what follows "ltbake") exactly as LtbakeMain does, flags' checks included,
// and runs nothing: "" when they parse, else the usage error. For code that builds command
// lines for ltbake (the steps of a bake) and for their tests.
std::string ParseOnly(const std::vector<std::string>& args);

}  // namespace ltb::cli
