#include "pipeline/graph.h"

#include <algorithm>
#include <filesystem>

#include "pipeline/stage_table.h"

namespace ltb::pipeline {

namespace fs = std::filesystem;
using nlohmann::json;

int StageIndex(const std::string& s) {
  const auto& n = StageNames();
  return static_cast<int>(std::find(n.begin(), n.end(), s) - n.begin());
}

Result<Graph> BuildGraph(const Recipe& r, const BakeOptions& o, const std::string& workdir,
                         const std::string& scene_file) {
  Graph g;
  auto valid_stage = [&](const std::string& s, const char* flag) -> Status {
    if (s.empty() || StageIndex(s) < static_cast<int>(StageNames().size())) return Status::Ok();
    std::string names;
    for (const auto& n : StageNames()) names += (names.empty() ? "" : ", ") + n;
    return InvalidArgument(std::string(flag) + " \"" + s + "\" is not a stage (stages: " + names + ")");
  };
  LTB_RETURN_IF_ERROR(valid_stage(o.from, "--from"));
  LTB_RETURN_IF_ERROR(valid_stage(o.until, "--until"));
  for (const auto& f : o.force) {
    if (f != "all") LTB_RETURN_IF_ERROR(valid_stage(f, "--force"));
  }
  if (!o.until.empty()) {
    g.targets = {o.until};
  } else {
    g.targets.insert(r.targets.begin(), r.targets.end());
  }
  if (g.targets.count("relight") && !r.relight.present) {
    return InvalidArgument(r.path + ": relight is asked for but the recipe has no [relight] table");
  }
  std::set<std::string> needed;
  std::vector<std::string> todo(g.targets.begin(), g.targets.end());
  while (!todo.empty()) {
    std::string s = todo.back();
    todo.pop_back();
    if (!needed.insert(s).second) continue;
    for (const auto& d : StageNeeds(r, s)) todo.push_back(d);
  }
  if (!o.from.empty() && !needed.count(o.from)) {
    return InvalidArgument("--from " + o.from + ": that stage is not part of this bake (its targets need: " + [&] {
      std::string s;
      for (const auto& n : StageNames())
        if (needed.count(n)) s += (s.empty() ? "" : ", ") + n;
      return s;
    }() + ")");
  }
  const bool fuse = needed.count("sample") && needed.count("row-transform") && !r.Keeps("raw") &&
                    !g.targets.count("sample") && o.from != "row-transform";

  auto path = [&](const std::string& file) { return (fs::path(workdir) / file).string(); };
  const StageContext ctx{path, scene_file};
  for (const StageInfo& info : StageTable()) {
    const std::string stage(info.name);
    if (!needed.count(stage)) continue;
    if (stage == "row-transform" && fuse) continue;  // done by the fused node
    Node n;
    n.name = stage;
    n.stages = {stage};
    if (info.command) {
      StageCommand c = info.command(r, ctx);
      n.inputs = std::move(c.inputs);
      n.params = std::move(c.params);
      n.args = std::move(c.args);
      n.output = info.output;
    }
    if (stage == "sample" && fuse) {  // sample + row-transform in one step: no raw.ltm
      n.name = "sample+row-transform";
      n.stages = {"sample", "row-transform"};
      n.output = "rows.ltm";
      n.params = {{"sample", n.params},
                  {"row-transform", {{"filter", r.row_transform.filter}, {"zstd", r.row_transform.zstd}}}};
      n.args.insert(n.args.end(), {"--row-transform", r.row_transform.filter});
      if (r.row_transform.zstd) n.args.push_back("--row-zstd");
    }
    if (info.command) {
      g.nodes.push_back(std::move(n));
      continue;
    }
    const auto& rl = r.relight;
    std::string matrix = rl.matrix == "cpca" ? "cpca.ltm" : "final.ltm";
    for (const EnvMap& env : rl.envs) {
      if (env.path.find("{face}") != std::string::npos) {
        return InvalidArgument(r.path + ": [relight] envs: " + env.path +
                               ": six-file {face} maps are not supported in recipes; convert it to one cubemap first "
                               "(ltbake convert MAP.exr MAP.npy --cube-res R) and name that file");
      }
      Node m;
      m.name = "relight:" + env.name;
      m.stages = {"relight"};
      m.image = true;
      m.env = env.path;
      m.inputs = {matrix};
      m.output = "relit-" + env.name + "." + rl.format;
      m.params = {{"env", env.path},     {"terms", rl.terms},       {"weighting", rl.weighting}, {"clamp", rl.clamp},
                  {"format", rl.format}, {"exposure", rl.exposure}, {"reference", rl.reference}};
      m.args = {"relight",     path(matrix),
                "--env",       env.path,
                "--terms",     std::to_string(rl.terms),
                "--weighting", rl.weighting,
                "--exposure",  Shortest(rl.exposure),
                "--json"};
      if (rl.clamp) m.args.push_back("--clamp");
      if (rl.reference) {
        m.inputs.push_back("rows.ltm");
        m.args.insert(m.args.end(), {"--reference", path("rows.ltm")});
      }
      g.nodes.push_back(std::move(m));
    }
  }
  // Files to leave on disk: the targets' outputs and the kept intermediates.
  for (const Node& n : g.nodes) {
    bool target = false;
    for (const auto& s : n.stages) target = target || g.targets.count(s);
    if (n.name == "sample+row-transform") target = g.targets.count("row-transform") > 0;
    std::string stem = fs::path(n.output).stem().string();
    if (target || n.image || r.Keeps(stem) || stem == "final" || stem == "cpca") g.wanted.insert(n.output);
  }
  return g;
}

}  // namespace ltb::pipeline
