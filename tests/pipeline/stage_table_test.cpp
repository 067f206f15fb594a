// The stage table against its own promises: graph order (a stage's needs come before it),
// one output file per stage, the names recipes accept are the table's, and each stage's
// command for the default recipe runs that stage on the outputs of the stages it needs.
#include "pipeline/stage_table.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <set>
#include <string>

namespace ltb::pipeline {
namespace {

TEST(StageTable, NeedsComeFirstAndOutputsAreDistinct) {
  std::set<std::string_view> seen, outputs;
  for (const StageInfo& s : StageTable()) {
    for (std::string_view n : s.needs) EXPECT_TRUE(seen.count(n)) << s.name << " needs " << n << ", listed after it";
    if (!s.output.empty()) {
      EXPECT_TRUE(outputs.insert(s.output).second) << s.output << " made twice";
    }
    seen.insert(s.name);
    EXPECT_EQ(FindStage(s.name), &s);
  }
  EXPECT_EQ(FindStage("colour"), nullptr);
  ASSERT_EQ(StageNames().size(), StageTable().size());
  for (size_t i = 0; i < StageNames().size(); ++i) EXPECT_EQ(StageNames()[i], StageTable()[i].name);
}

TEST(StageTable, DefaultCommandsReadWhatTheirNeedsMake) {
  Recipe r;  // every key at its default
  StageContext ctx{[](const std::string& f) { return "/work/" + f; }, "/work/scene.toml"};
  for (const StageInfo& s : StageTable()) {
    if (!s.command) continue;  // relight, material, triple: one step per item, built by the graph
    StageCommand c = s.command(r, ctx);
    ASSERT_FALSE(c.args.empty());
    if (s.name == "visibility") {  // the sample stage in its visibility mode
      EXPECT_EQ(c.args[0], "sample");
      EXPECT_NE(std::find(c.args.begin(), c.args.end(), "--visibility"), c.args.end());
    } else {
      EXPECT_EQ(c.args[0], s.name);
    }
    std::set<std::string> made;
    for (std::string_view n : s.needs) made.insert(std::string(FindStage(n)->output));
    for (const std::string& in : c.inputs) {
      EXPECT_TRUE(made.count(in)) << s.name << " reads " << in << " that no stage it needs makes";
      EXPECT_NE(std::find(c.args.begin(), c.args.end(), "/work/" + in), c.args.end()) << s.name << " " << in;
    }
    EXPECT_EQ(c.inputs.size(), s.needs.size()) << s.name;
  }
  // The recipe defaults (docs/RECIPE.md): one 5% budget, one quantization step with ratio 1.1.
  auto ct = FindStage("column-transform")->command(r, ctx).args;
  EXPECT_NE(std::find(ct.begin(), ct.end(), "--budget"), ct.end());
  auto q = FindStage("quantize")->command(r, ctx).args;
  EXPECT_EQ(q.back(), "1.1");
  EXPECT_EQ(StageNeeds(r, "relight"), std::vector<std::string>{"quantize"});
  r.relight.matrix = "cpca";
  r.relight.reference = true;
  EXPECT_EQ(StageNeeds(r, "relight"), (std::vector<std::string>{"cpca", "row-transform"}));
}

// The properties that used to live outside the table (the graph's per-set-member list, the
// reads-the-scene rule, the shard flags) are the rows' fields, and consistent with the rest
// of the row.
TEST(StageTable, SetMembersSceneReadsAndShardFlagsAreFieldsOfTheRows) {
  std::set<std::string> per_member, scene;
  for (const StageInfo& s : StageTable()) {
    if (s.per_set_member) {
      per_member.insert(std::string(s.name));
      EXPECT_TRUE(s.command) << s.name << ": a per-member step needs its command from the table";
      EXPECT_FALSE(s.output.empty()) << s.name << ": a per-member step makes one file a member";
    }
    if (s.reads_scene) scene.insert(std::string(s.name));
    if (!s.shard_args.empty()) {
      EXPECT_TRUE(s.shardable) << s.name << " has shard flags but cannot run as shards";
    }
  }
  EXPECT_EQ(per_member,
            (std::set<std::string>{"sample", "row-transform", "transpose", "column-transform", "quantize", "cpca"}));
  EXPECT_EQ(scene, (std::set<std::string>{"sample", "visibility"}));
  EXPECT_TRUE(ReadsScene({"sample", "row-transform"}));  // the fused step
  EXPECT_FALSE(ReadsScene({"transpose"}));
  EXPECT_FALSE(ReadsScene({}));
  for (const StageInfo& s : StageTable()) {  // only row-transform runs inside another stage
    EXPECT_EQ(bool(s.fused_args), s.name == "row-transform") << s.name;
  }
  ASSERT_EQ(FindStage("transpose")->shard_args.size(), 1u);
  EXPECT_EQ(FindStage("transpose")->shard_args[0], "--no-verify-input");
}

}  // namespace
}  // namespace ltb::pipeline
