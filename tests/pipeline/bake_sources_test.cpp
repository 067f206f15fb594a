// `ltbake run` and the files outside its work directory (issue 36, item 3): an environment
// map that changes while its relight step runs is recorded as changed, not with the hash
// taken when the run was planned, and the next run relights again; a map that stays put is
// up to date on the rerun. The bake is real (the ltbake binary of this tree runs each step);
// the change is made from the step's "starting" event, so no timing is involved.
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "format/npy.h"
#include "pipeline/bake.h"

namespace ltb::pipeline {
namespace {

namespace fs = std::filesystem;

void WriteText(const std::string& path, const std::string& text) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out << text;
}

// A cubemap environment of R = 2 (24 texels, RGB), every texel `value`, as a .npy.
void WriteEnv(const std::string& path, float value) {
  std::vector<std::byte> header = format::EncodeNpyHeader("<f4", {24, 3});
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out.write(reinterpret_cast<const char*>(header.data()), static_cast<std::streamsize>(header.size()));
  std::vector<float> v(72, value);
  out.write(reinterpret_cast<const char*>(v.data()), static_cast<std::streamsize>(v.size() * 4));
}

const nlohmann::json* Entry(const BakeOutcome& o, const std::string& prefix) {
  for (const auto& e : o.stages) {
    if (e.value("node", "").starts_with(prefix)) return &e;
  }
  return nullptr;
}

TEST(BakeSources, AMapChangedWhileItsStepRanIsRecordedAsChangedAndRelitAgain) {
  const fs::path dir = fs::path(::testing::TempDir()) / ("ltb_bake_sources_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  const std::string env = (dir / "env.npy").string();
  WriteEnv(env, 1.0f);
  WriteText((dir / "scene.toml").string(),
            "[camera]\neye = [0.0, -3.0, 1.0]\ntarget = [0.0, 0.0, 0.0]\nwidth = 8\nheight = 8\n"
            "[sampling]\ncube_res = 2\nspp = 1\n[[object]]\ntype = \"plane\"\n");
  WriteText((dir / "bake.toml").string(),
            "name = \"sources\"\nscene = \"scene.toml\"\nworkdir = \"w\"\ntargets = [\"relight\"]\n"
            "[column-transform]\ndepth = \"none\"\n[relight]\nenvs = [\"env.npy\"]\nformat = \"exr\"\n");
  BakeOptions o;
  o.recipe = (dir / "bake.toml").string();
  o.jobs = 1;
  o.quiet = true;
  o.ltbake = LTB_LTBAKE;
  int swapped = 0;
  o.on_step = [&](const StepEvent& e) {
    if (e.kind == StepEvent::Kind::kStarting && e.node.starts_with("relight") && swapped++ == 0) {
      WriteEnv(env, 5.0f);  // the user swaps the map as the step starts
    }
  };
  auto first = RunBake(o);
  ASSERT_TRUE(first.ok()) << first.status().message();
  ASSERT_EQ(first->end, BakeEnd::kOk) << first->failure;
  ASSERT_EQ(swapped, 1);
  const nlohmann::json* e = Entry(*first, "relight");
  ASSERT_NE(e, nullptr);
  EXPECT_TRUE(e->at("inputs").value("env", "").starts_with("changed while the step ran")) << e->dump(1);
  EXPECT_NE(e->value("warning", "").find("env.npy changed while"), std::string::npos) << e->dump(1);

  o.on_step = nullptr;
  auto second = RunBake(o);  // what the step read is unknown: it runs again
  ASSERT_TRUE(second.ok()) << second.status().message();
  ASSERT_EQ(second->end, BakeEnd::kOk) << second->failure;
  e = Entry(*second, "relight");
  ASSERT_NE(e, nullptr);
  EXPECT_NE(e->value("action", ""), "skip") << e->dump(1);
  EXPECT_FALSE(e->contains("warning")) << e->dump(1);
  // The earlier steps read no map: up to date.
  const nlohmann::json* q = Entry(*second, "quantize");
  ASSERT_NE(q, nullptr);
  EXPECT_EQ(q->value("action", ""), "skip");

  auto third = RunBake(o);  // nothing changed since: up to date
  ASSERT_TRUE(third.ok()) << third.status().message();
  e = Entry(*third, "relight");
  ASSERT_NE(e, nullptr);
  EXPECT_EQ(e->value("action", ""), "skip") << e->dump(1);
  fs::remove_all(dir);
}

}  // namespace
}  // namespace ltb::pipeline
