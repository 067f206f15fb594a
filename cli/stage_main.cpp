// ltbake-<stage>: the stage as its own executable; `ltbake-STAGE ARGS` runs exactly
// `ltbake STAGE ARGS`. LTB_STAGE_NAME is set per executable by CMake.
#include <vector>

#include "cli/commands.h"

int main(int argc, char** argv) {
  std::vector<char*> args{argv[0], const_cast<char*>(LTB_STAGE_NAME)};
  for (int i = 1; i < argc; ++i) args.push_back(argv[i]);
  args.push_back(nullptr);
  return ltb::cli::LtbakeMain(static_cast<int>(args.size()) - 1, args.data());
}
