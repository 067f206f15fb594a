// Every command a bake runs parses in the real command line (cli::ParseOnly: the parser
// `ltbake` itself builds, flags' checks included, nothing run): recipes that between them set
// every stage's keys, through the recipe parser and the graph, each step as Bake runs it and
// each shard as the sharded steps run it. A flag renamed in a cmd_<stage>.cpp but not in the
// stage table fails here in milliseconds instead of in a bake. Also: the command list and the
// stage executables (ltbake-<stage> links) agree.
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include "cli/commands.h"
#include "format/npy.h"
#include "pipeline/graph.h"
#include "pipeline/recipe.h"
#include "pipeline/stage_table.h"

namespace ltb::pipeline {
namespace {

namespace fs = std::filesystem;

class StageCommands : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("ltb_stage_commands_" + std::to_string(getpid()));
    fs::create_directories(dir_);
    // The recipe reader checks a map's shape (a cubemap .npy's header), not its values.
    for (const char* name : {"sky.npy", "dusk.npy"}) {
      std::vector<std::byte> header = format::EncodeNpyHeader("<f4", {6, 3});  // R = 1
      std::ofstream out(dir_ / name, std::ios::binary);
      out.write(reinterpret_cast<const char*>(header.data()), static_cast<std::streamsize>(header.size()));
      out.write(std::string(72, '\0').data(), 72);
    }
  }
  void TearDown() override { fs::remove_all(dir_); }

  // Parses `body` (a recipe without its scene line) and checks every step and shard command;
  // `variants`: also with --progress always and --overwrite (each command line is a fresh
  // parser, ~50 ms under the sanitizers at -O0, so the other recipes check one variant).
  void CheckRecipe(const std::string& name, const std::string& body, bool variants = false) {
    SCOPED_TRACE(name);
    const fs::path path = dir_ / (name + ".toml");
    std::ofstream(path) << "scene = \"" << LTB_SOURCE_DIR << "/samples/tiny.toml\"\nworkdir = \""
                        << (dir_ / name).string() << "\"\n"
                        << body;
    auto recipe = ParseRecipe(path.string());
    ASSERT_TRUE(recipe.ok()) << recipe.status().message();
    BakeOptions o;
    o.ltbake = "ltbake";
    for (bool progress : {false, true}) {
      if (progress && !variants) break;
      o.progress = progress;
      auto graph = BuildGraph(*recipe, o, (dir_ / name).string(), (dir_ / name / "scene.toml").string());
      ASSERT_TRUE(graph.ok()) << graph.status().message();
      ASSERT_FALSE(graph->nodes.empty());
      for (const Node& n : graph->nodes) {
        const std::string out = (dir_ / name / n.output).string();
        Expect(n, StepArgs(n, out, o, /*overwrite=*/progress));
        const StageInfo* info = FindStage(n.stages.front());
        ASSERT_NE(info, nullptr) << n.name;
        if (info->shardable && !progress) {
          std::vector<std::string> shard = StepArgs(n, out, o, true, /*shard=*/true);
          shard.insert(shard.end(), {"--shard", "1", "--nshards", "3", "--jobs", "1"});
          Expect(n, shard);
        }
        stages_seen_.insert(n.stages.begin(), n.stages.end());
      }
    }
  }

  void Expect(const Node& n, const std::vector<std::string>& args) {
    std::string line;
    for (const auto& a : args) line += " " + a;
    const std::string error = cli::ParseOnly(args);
    EXPECT_EQ(error, "") << n.name << ": ltbake" << line;
    ++commands_;
  }

  fs::path dir_;
  std::set<std::string> stages_seen_;
  int commands_ = 0;
};

TEST_F(StageCommands, EveryStepOfTheseRecipesParses) {
  CheckRecipe("defaults", "", /*variants=*/true);
  CheckRecipe("everything", R"(
targets = ["quantize", "cpca", "relight"]
keep = ["raw", "rows", "cols", "cols4d"]
[sample]
cube_res = 16
spp = 2
bounces = 1
seed = 3
[row-transform]
filter = "db2"
zstd = true
[transpose]
zstd = true
[column-transform]
filter = "cdf97"
depth = 2
target_error = "2%"
zstd = false
[quantize]
bits = 9
scaling = "none"
dither = true
seed = 4
[cpca]
clusters = 4
basis = 3
max_iterations = 5
seed = 2
[relight]
envs = ["sky.npy", "dusk.npy"]
matrix = "final"
terms = 50
weighting = "transport"
clamp = true
exposure = 2
format = "exr"
reference = true
)");
  CheckRecipe("budgets", R"(
targets = ["relight"]
[column-transform]
depth = "full"
terms = 12
[quantize]
error_ratio = 1.05
[relight]
envs = ["sky.npy"]
matrix = "cpca"
sequence = "rotate:3.6:10,hold:2"
method = "bi"
[cpca]
clusters = 2
)");
  CheckRecipe("keep-fraction", R"(
[sample]
tolerance = "2%"
max_levels = 4
[column-transform]
depth = "none"
keep = 0.1
)");
  CheckRecipe("sparse", R"(
[sample]
sparse = true
dense_fraction = 0.3
neighbours = 8
l1_lambda = 0.002
max_residual = 0.2
)");
  CheckRecipe("colour", R"(
targets = ["quantize", "relight"]
[sample]
channels = "rgb"
bounces = 1
[relight]
envs = ["sky.npy"]
)");
  CheckRecipe("factored", R"(
targets = ["quantize", "relight"]
[sample]
factor = 3
[column-transform]
depth = "none"
[relight]
envs = ["sky.npy"]
eye = [0.0, -3.0, 2.0]
target = [0.0, 0.0, 1.0]
fov = 30.0
size = [64, 48]
)");
  CheckRecipe("triple", R"(
[triple]
materials = ["lambert", "phong:32"]
envs = ["sky.npy"]
cube_res = 16
spp = 2
eye = [0.0, -3.0, 1.5]
method = "linear"
terms = 64
brdf_terms = 8
clamp = true
format = "npy"
)");
  // Every stage of the table ran in one of the recipes above.
  for (const StageInfo& s : StageTable()) EXPECT_TRUE(stages_seen_.count(std::string(s.name))) << s.name;
  EXPECT_GT(commands_, 40);
}

TEST_F(StageCommands, ARenamedFlagIsCaught) {
  EXPECT_EQ(cli::ParseOnly({"quantize", "in.ltm", "-o", "out.ltm", "--bits", "9"}), "");
  EXPECT_NE(cli::ParseOnly({"quantize", "in.ltm", "-o", "out.ltm", "--bit", "9"}), "");
  EXPECT_NE(cli::ParseOnly({"quantise", "in.ltm"}).find("unknown command 'quantise'; did you mean 'quantize'?"),
            std::string::npos);
  // No suggestion for a name three edits or more from every command.
  EXPECT_EQ(cli::ParseOnly({"frobnicate"}).find("did you mean"), std::string::npos);
}

// The command list is what the binary dispatches, and its stage executables are the links
// the build made next to ltbake from `ltbake --list-commands` (scripts/stage_links.cmake),
// no more, no fewer.
TEST(CommandList, StageExecutablesAreTheLinksNextToLtbake) {
  const fs::path bin = fs::path(LTB_LTBAKE).parent_path();
  std::set<std::string> want, have;
  for (const auto& c : cli::CommandList()) {
    EXPECT_EQ(cli::ParseOnly({c.name, "--help"}).find("unknown command"), std::string::npos) << c.name;
    if (c.stage_executable) want.insert(std::string("ltbake-") + c.name);
  }
  for (const auto& e : fs::directory_iterator(bin)) {
    const std::string f = e.path().filename().string();
    if (f.rfind("ltbake-", 0) == 0 && fs::is_symlink(e.symlink_status())) have.insert(f);
  }
  EXPECT_EQ(have, want);
}

// Every command's --help shows examples, and each example parses as it is written (in a
// directory holding the files it names, for the flags that check a file exists).
TEST(CommandList, EveryExampleParses) {
  const fs::path dir = fs::temp_directory_path() / ("ltb_examples_" + std::to_string(getpid()));
  fs::create_directories(dir);
  const fs::path was = fs::current_path();
  fs::current_path(dir);
  for (const auto& c : cli::CommandList()) {
    ASSERT_NE(c.examples, nullptr) << c.name;
    std::istringstream lines(c.examples);
    int n = 0;
    for (std::string line; std::getline(lines, line);) {
      line = line.substr(0, line.find("  # "));
      std::istringstream words(line);
      std::vector<std::string> args;
      for (std::string w; words >> w;) args.push_back(w);
      ASSERT_GE(args.size(), 2u) << c.name << ": " << line;
      EXPECT_EQ(args[0], "ltbake") << line;
      EXPECT_EQ(args[1], c.name) << line;
      args.erase(args.begin());
      for (const std::string& a : args) {
        if (a[0] != '-' && a.find('.') != std::string::npos) std::ofstream(a).put('x');
      }
      EXPECT_EQ(cli::ParseOnly(args), "") << line;
      ++n;
    }
    EXPECT_GE(n, 1) << c.name;
  }
  fs::current_path(was);
  fs::remove_all(dir);
}

}  // namespace
}  // namespace ltb::pipeline
