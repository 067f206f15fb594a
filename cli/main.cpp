// ltbake: the command-line entry point. Each stage is also reachable as its own
// executable, ltbake-<stage> (a link to this binary, made by the build): started under
// that name, `ltbake-STAGE ARGS` runs exactly `ltbake STAGE ARGS`.
#include <cstring>
#include <vector>

// Declared here rather than through cli/commands.h, which pulls in CLI11 (13 s of compile
// time for this one-function file); a mismatch with the definition fails at link time.
namespace ltb::cli {
int LtbakeMain(int argc, char** argv);
}

int main(int argc, char** argv) {
  const char* base = argc > 0 && argv[0] ? argv[0] : "";
  if (const char* slash = std::strrchr(base, '/')) base = slash + 1;
  constexpr const char kPrefix[] = "ltbake-";
  constexpr size_t kPrefixLen = sizeof kPrefix - 1;
  if (std::strncmp(base, kPrefix, kPrefixLen) == 0 && base[kPrefixLen] != '\0') {
    // The stage name points into argv[0], which lives as long as main.
    std::vector<char*> args{argv[0], const_cast<char*>(base + kPrefixLen)};
    for (int i = 1; i < argc; ++i) args.push_back(argv[i]);
    args.push_back(nullptr);
    return ltb::cli::LtbakeMain(static_cast<int>(args.size()) - 1, args.data());
  }
  return ltb::cli::LtbakeMain(argc, argv);
}
