// Planning a bake as pure logic (pipeline/plan.h): each rule of docs/RECIPE.md "What runs"
// on hand-made records and outputs, the remaking of intermediates that were not kept, and
// the --from check. The expected decisions follow from the rules, stated beside each case.
#include "pipeline/plan.h"

#include <gtest/gtest.h>

#include <map>
#include <string>
#include <vector>

namespace ltb::pipeline {
namespace {

using nlohmann::json;

Node MakeNode(const std::string& stage, std::vector<std::string> inputs, const std::string& output) {
  Node n;
  n.name = stage;
  n.stages = {stage};
  n.inputs = std::move(inputs);
  n.output = output;
  n.params = {{"cube_res", 8}};
  return n;
}

OutputState Complete(const std::string& fingerprint) {
  OutputState s;
  s.exists = s.complete = true;
  s.fingerprint = fingerprint;
  s.bytes = 100;
  return s;
}

json Done(const Node& n, const json& inputs, const std::string& fingerprint, const std::string& hash) {
  return {{"node", n.name},
          {"status", "done"},
          {"params", n.params},
          {"inputs", inputs},
          {"output", {{"file", n.output}, {"fingerprint", fingerprint}, {"content_hash", hash}}}};
}

TEST(Decide, NoRecordAndNoOutputRuns) {
  Node n = MakeNode("transpose", {"rows.ltm"}, "cols.ltm");
  Decision d = Decide(n, nullptr, json{{"rows.ltm", "aa"}}, OutputState{}, false, "", false);
  EXPECT_EQ(d.action, Action::kRun);
  EXPECT_EQ(d.reason, "not made yet");
  EXPECT_TRUE(d.runs());
}

TEST(Decide, UpToDateIsSkipped) {
  Node n = MakeNode("transpose", {"rows.ltm"}, "cols.ltm");
  json in = {{"rows.ltm", "aa"}};
  json rec = Done(n, in, "f1", "h1");
  Decision d = Decide(n, &rec, in, Complete("f1"), false, "", false);
  EXPECT_EQ(d.action, Action::kSkip);
  EXPECT_FALSE(d.runs());
  // --force redoes it all the same.
  EXPECT_EQ(Decide(n, &rec, in, Complete("f1"), true, "", false).action, Action::kRedo);
}

TEST(Decide, ChangedParametersRedoAndSayWhich) {
  Node n = MakeNode("transpose", {"rows.ltm"}, "cols.ltm");
  json in = {{"rows.ltm", "aa"}};
  json rec = Done(n, in, "f1", "h1");
  n.params["cube_res"] = 16;
  n.params["jobs"] = 2;
  Decision d = Decide(n, &rec, in, Complete("f1"), false, "", false);
  EXPECT_EQ(d.action, Action::kRedo);
  EXPECT_EQ(d.reason, "parameters changed: cube_res 8 -> 16, jobs (default) -> 2");
  // With no output on disk it is a run, not a redo (nothing to remove).
  EXPECT_EQ(Decide(n, &rec, in, OutputState{}, false, "", false).action, Action::kRun);
}

TEST(Decide, ChangedInputRedoes) {
  Node n = MakeNode("transpose", {"rows.ltm"}, "cols.ltm");
  json rec = Done(n, json{{"rows.ltm", "aa"}}, "f1", "h1");
  Decision d = Decide(n, &rec, json{{"rows.ltm", "bb"}}, Complete("f1"), false, "", false);
  EXPECT_EQ(d.action, Action::kRedo);
  EXPECT_EQ(d.reason, "input changed: rows.ltm aa -> bb");
}

TEST(Decide, AnInputBeingRemadeMeansRunningAgain) {
  Node n = MakeNode("transpose", {"rows.ltm"}, "cols.ltm");
  json in = {{"rows.ltm", FileHash::BeingRemade().ForRecord()}};
  json rec = Done(n, json{{"rows.ltm", "aa"}}, "f1", "h1");
  EXPECT_EQ(Decide(n, &rec, in, Complete("f1"), false, "", false).action, Action::kRedo);
  EXPECT_EQ(Decide(n, nullptr, in, OutputState{}, false, "", false).action, Action::kRun);
}

TEST(Decide, InterruptedOutputResumes) {
  Node n = MakeNode("transpose", {"rows.ltm"}, "cols.ltm");
  json in = {{"rows.ltm", "aa"}};
  json rec = Done(n, in, "f1", "h1");
  rec["status"] = "running";
  OutputState partial;
  partial.exists = true;
  partial.committed = 3;
  partial.total = 8;
  Decision d = Decide(n, &rec, in, partial, false, "", false);
  EXPECT_EQ(d.action, Action::kResume);
  EXPECT_EQ(d.reason, "interrupted: 3 of 8 chunks committed");
}

TEST(Decide, UnreadableOrChangedOutputsAreRedone) {
  Node n = MakeNode("transpose", {"rows.ltm"}, "cols.ltm");
  json in = {{"rows.ltm", "aa"}};
  json rec = Done(n, in, "f1", "h1");
  OutputState bad;
  bad.exists = true;
  bad.problem = "not an .ltm file";
  EXPECT_EQ(Decide(n, &rec, in, bad, false, "", false).action, Action::kRedo);
  EXPECT_EQ(Decide(n, nullptr, in, bad, false, "", false).action, Action::kRun);
  Decision d = Decide(n, &rec, in, Complete("f2"), false, "", false);
  EXPECT_EQ(d.action, Action::kRedo);
  EXPECT_EQ(d.reason, "cols.ltm changed since it was made (fingerprint f1 -> f2)");
}

TEST(Decide, AnIntermediateNotKeptIsRemadeOnlyWhenNeeded) {
  Node n = MakeNode("transpose", {"rows.ltm"}, "cols.ltm");
  json in = {{"rows.ltm", "aa"}};
  json rec = Done(n, in, "f1", "h1");
  rec["output"]["deleted"] = true;
  EXPECT_EQ(Decide(n, &rec, in, OutputState{}, false, "", false).action, Action::kSkip);
  Decision d = Decide(n, &rec, in, OutputState{}, false, "column-transform needs it", true);
  EXPECT_EQ(d.action, Action::kRun);
  EXPECT_EQ(d.reason, "cols.ltm is missing and column-transform needs it");
}

TEST(FileHash, RecordsAsRunJsonHasThem) {
  EXPECT_EQ(FileHash::Known("0123").ForRecord(), "0123");
  EXPECT_EQ(FileHash::BeingRemade().ForRecord(), "");
  EXPECT_EQ(FileHash::OnDisk().ForRecord(), "(computed when run)");
  EXPECT_FALSE(FileHash().known());
}

// A three-step chain where the middle output was not kept: when the last step must run
// again (its parameters changed), the middle one has to be remade first, and the first is
// still skipped.
TEST(PlanSteps, RemakesAnIntermediateThatALaterStepNeeds) {
  Graph g;
  g.nodes = {MakeNode("sample", {}, "rows.ltm"), MakeNode("transpose", {"rows.ltm"}, "cols.ltm"),
             MakeNode("column-transform", {"cols.ltm"}, "cols4d.ltm")};
  g.wanted = {"rows.ltm", "cols4d.ltm"};
  std::map<std::string, json> previous;
  previous["sample"] = Done(g.nodes[0], json::object(), "f0", "h0");
  previous["transpose"] = Done(g.nodes[1], json{{"rows.ltm", "h0"}}, "f1", "h1");
  previous["transpose"]["output"]["deleted"] = true;
  previous["column-transform"] = Done(g.nodes[2], json{{"cols.ltm", "h1"}}, "f2", "h2");
  g.nodes[2].params["budget"] = "5%";  // changed since

  std::map<std::string, OutputState> disk = {{"rows.ltm", Complete("f0")}, {"cols4d.ltm", Complete("f2")}};
  PlanInput in;
  in.graph = &g;
  in.previous = &previous;
  in.before_from = [](const Node&) { return false; };
  in.forced = [](const Node&) { return false; };
  in.inspect = [&disk](const Node& n) { return disk.count(n.output) ? disk[n.output] : OutputState{}; };
  in.inputs_of = [](const Node& n, const std::map<std::string, FileHash>& h) {
    json j = json::object();
    for (const auto& f : n.inputs) j[f] = h.count(f) ? h.at(f).ForRecord() : std::string();
    return j;
  };
  Plan plan = PlanSteps(in);
  ASSERT_EQ(plan.steps.size(), 3u);
  EXPECT_EQ(plan.steps[0].action, Action::kSkip);
  EXPECT_EQ(plan.steps[1].action, Action::kRun);
  EXPECT_EQ(plan.steps[1].reason, "cols.ltm is missing and column-transform needs it");
  EXPECT_EQ(plan.steps[2].action, Action::kRedo);
  EXPECT_EQ(plan.needed_by.at("transpose"), "column-transform needs it");

  // Unchanged parameters: nothing runs and nothing is remade.
  g.nodes[2].params = previous["column-transform"]["params"];
  plan = PlanSteps(in);
  for (const Decision& d : plan.steps) EXPECT_EQ(d.action, Action::kSkip) << d.reason;
  EXPECT_TRUE(plan.needed_by.empty());

  // --from transpose: the sample step is given; its output is complete, so nothing to report.
  in.before_from = [](const Node& n) { return n.name == "sample"; };
  in.from = "transpose";
  g.nodes[2].params["budget"] = "5%";
  plan = PlanSteps(in);
  EXPECT_EQ(plan.steps[0].action, Action::kGiven);
  EXPECT_EQ(plan.steps[0].reason, "before --from transpose");
  auto path = [](const std::string& f) { return "/w/" + f; };
  EXPECT_TRUE(CheckGivenInputs(g, plan, in, "transpose", path).ok());
  // ... but when rows.ltm is gone, the step that reads it cannot run.
  disk.erase("rows.ltm");
  plan = PlanSteps(in);
  Status s = CheckGivenInputs(g, plan, in, "transpose", path);
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.message().find("transpose reads /w/rows.ltm, which does not exist or is incomplete (sample makes it)"),
            std::string::npos)
      << s.message();
}

TEST(ActionName, NamesEveryAction) {
  EXPECT_STREQ(ActionName(Action::kRun), "run");
  EXPECT_STREQ(ActionName(Action::kResume), "resume");
  EXPECT_STREQ(ActionName(Action::kRedo), "redo");
  EXPECT_STREQ(ActionName(Action::kSkip), "skip");
  EXPECT_STREQ(ActionName(Action::kGiven), "given");
}

}  // namespace
}  // namespace ltb::pipeline
