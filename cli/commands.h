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
int LtbakeMain(int argc, char** argv);

}  // namespace ltb::cli
