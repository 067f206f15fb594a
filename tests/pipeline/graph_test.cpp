// The bake graph as pure logic (pipeline/graph.h): what a recipe's targets need, the fused
// sample + row-transform step, --until and --from, one relight step per map.
#include "pipeline/graph.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <string>
#include <vector>

namespace ltb::pipeline {
namespace {

std::vector<std::string> Names(const Graph& g) {
  std::vector<std::string> n;
  for (const Node& node : g.nodes) n.push_back(node.name);
  return n;
}

Recipe Base() {
  Recipe r;
  r.path = "/w/r.toml";
  r.targets = {"quantize"};
  r.keep = {"rows", "cols", "cols4d"};
  return r;
}

TEST(Graph, QuantizeFusesSampleAndRowTransform) {
  auto g = BuildGraph(Base(), BakeOptions{}, "/work", "/work/scene.toml");
  ASSERT_TRUE(g.ok()) << g.status().message();
  EXPECT_EQ(Names(*g), (std::vector<std::string>{"sample+row-transform", "transpose", "column-transform", "quantize"}));
  EXPECT_EQ(g->nodes[0].output, "rows.ltm");
  EXPECT_EQ(g->nodes[3].output, "final.ltm");
  EXPECT_EQ(g->nodes[3].inputs, std::vector<std::string>{"cols4d.ltm"});
  EXPECT_TRUE(g->wanted.count("final.ltm") && g->wanted.count("cols4d.ltm") && !g->wanted.count("raw.ltm"));
  EXPECT_EQ(g->nodes[0].args[0], "sample");
  EXPECT_EQ(g->nodes[0].args[1], "/work/scene.toml");
  // The fused step from the table (StageInfo::fused_args): both stages' params, sample's
  // command with the row-transform flags.
  EXPECT_EQ(g->nodes[0].stages, (std::vector<std::string>{"sample", "row-transform"}));
  EXPECT_EQ(g->nodes[0].params["row-transform"], (nlohmann::json{{"filter", "haar"}, {"zstd", false}}));
  EXPECT_TRUE(g->nodes[0].params.contains("sample"));
  const auto& a = g->nodes[0].args;
  const auto at = std::find(a.begin(), a.end(), "--row-transform");
  ASSERT_NE(at, a.end());
  EXPECT_EQ(*(at + 1), "haar");
}

TEST(Graph, KeepingRawSplitsTheFusedStep) {
  Recipe r = Base();
  r.keep.insert("raw");
  auto g = BuildGraph(r, BakeOptions{}, "/work", "/work/scene.toml");
  ASSERT_TRUE(g.ok());
  EXPECT_EQ(Names(*g),
            (std::vector<std::string>{"sample", "row-transform", "transpose", "column-transform", "quantize"}));
  EXPECT_EQ(g->nodes[1].inputs, std::vector<std::string>{"raw.ltm"});
}

TEST(Graph, UntilAndFrom) {
  BakeOptions o;
  o.until = "transpose";
  auto g = BuildGraph(Base(), o, "/work", "/work/scene.toml");
  ASSERT_TRUE(g.ok());
  EXPECT_EQ(Names(*g), (std::vector<std::string>{"sample+row-transform", "transpose"}));
  o = BakeOptions{};
  o.from = "cpca";  // not needed by quantize
  auto bad = BuildGraph(Base(), o, "/work", "/work/scene.toml");
  ASSERT_FALSE(bad.ok());
  EXPECT_NE(bad.status().message().find("not part of this bake"), std::string::npos);
  o.from = "colour";
  bad = BuildGraph(Base(), o, "/work", "/work/scene.toml");
  ASSERT_FALSE(bad.ok());
  EXPECT_NE(bad.status().message().find("is not a stage"), std::string::npos);
}

TEST(Graph, OneRelightStepPerMapWithItsReference) {
  Recipe r = Base();
  r.targets = {"quantize", "relight"};
  r.relight.present = true;
  r.relight.reference = true;
  r.relight.envs = {{"sunset", "/maps/sunset.exr"}, {"forest", "/maps/forest.exr"}};
  auto g = BuildGraph(r, BakeOptions{}, "/work", "/work/scene.toml");
  ASSERT_TRUE(g.ok()) << g.status().message();
  ASSERT_EQ(g->nodes.size(), 6u);
  EXPECT_EQ(g->nodes[4].name, "relight:sunset");
  EXPECT_EQ(g->nodes[5].output, "relit-forest.png");
  EXPECT_EQ(g->nodes[4].inputs, (std::vector<std::string>{"final.ltm", "rows.ltm"}));
  EXPECT_TRUE(g->nodes[4].image);
  r.relight.present = false;
  EXPECT_FALSE(BuildGraph(r, BakeOptions{}, "/work", "/work/scene.toml").ok());
}

TEST(Graph, ASequenceMakesOneVideoPerMap) {
  Recipe r = Base();
  r.targets = {"relight"};
  r.relight.present = true;
  r.relight.envs = {{"sunset", "/maps/sunset.exr"}};
  r.relight.sequence = "rotate:3.6:100,hold:25";
  r.relight.method = "bi";
  r.relight.format = "mp4";
  auto g = BuildGraph(r, BakeOptions{}, "/work", "/work/scene.toml");
  ASSERT_TRUE(g.ok()) << g.status().message();
  const auto& n = g->nodes.back();
  EXPECT_EQ(n.output, "relit-sunset.mp4");
  const std::vector<std::string> tail(n.args.end() - 4, n.args.end());
  EXPECT_EQ(tail, (std::vector<std::string>{"--sequence", "rotate:3.6:100,hold:25", "--method", "bi"}));
  EXPECT_EQ(n.params["sequence"], "rotate:3.6:100,hold:25");  // a new sequence is a new output
}

TEST(Graph, TriplePathMakesTheFieldsThenOneViewPerMap) {
  Recipe r = Base();
  r.targets = {"triple"};
  r.triple.present = true;
  r.triple.cube_res = 16;
  r.triple.spp = 2;
  r.triple.materials = {"lambert", "phong:64"};
  r.triple.envs = {{"sky", "/maps/sky.exr"}, {"dusk", "/maps/dusk.hdr"}};
  r.triple.eye = {1, -2, 0.5};
  auto g = BuildGraph(r, BakeOptions{}, "/work", "/work/scene.toml");
  ASSERT_TRUE(g.ok()) << g.status().message();
  EXPECT_EQ(Names(*g), (std::vector<std::string>{"visibility", "material:lambert", "material:phong:64", "triple:sky",
                                                 "triple:dusk"}));
  EXPECT_EQ(g->nodes[0].output, "vis.ltm");
  EXPECT_EQ(g->nodes[0].args,
            (std::vector<std::string>{"sample", "/work/scene.toml", "--visibility", "--cube-res", "16", "--spp", "2"}));
  EXPECT_EQ(g->nodes[2].output, "material-phong-64.ltm");
  EXPECT_EQ(g->nodes[2].args, (std::vector<std::string>{"material", "--brdf", "phong:64", "--cube-res", "16"}));
  const Node& view = g->nodes[3];
  EXPECT_TRUE(view.image);
  EXPECT_EQ(view.output, "view-sky.png");
  EXPECT_EQ(view.inputs, (std::vector<std::string>{"vis.ltm", "material-lambert.ltm", "material-phong-64.ltm"}));
  auto at = [&](const std::string& flag) {
    for (size_t k = 0; k + 1 < view.args.size(); ++k)
      if (view.args[k] == flag) return view.args[k + 1];
    return std::string("(missing)");
  };
  EXPECT_EQ(at("--eye"), "1,-2,0.5");
  EXPECT_EQ(at("--env"), "/maps/sky.exr");
  EXPECT_EQ(at("--material"), "/work/material-lambert.ltm");
  // The fields are kept for later views, like final.ltm.
  EXPECT_TRUE(g->wanted.count("vis.ltm") && g->wanted.count("material-lambert.ltm"));
  r.triple.present = false;
  EXPECT_FALSE(BuildGraph(r, BakeOptions{}, "/work", "/work/scene.toml").ok());
}

}  // namespace
}  // namespace ltb::pipeline
