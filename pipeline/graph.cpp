#include "pipeline/graph.h"

#include <algorithm>
#include <cctype>
#include <filesystem>
#include <functional>
#include <set>

#include "pipeline/stage_table.h"
#include "stages/common/channels.h"

namespace ltb::pipeline {

namespace fs = std::filesystem;
using nlohmann::json;

namespace {

// "phong:64" -> "material-phong-64.ltm".
std::string MaterialFile(const std::string& spec) {
  std::string name = spec;
  for (char& ch : name) {
    if (!std::isalnum(static_cast<unsigned char>(ch)) && ch != '.') ch = '-';
  }
  return "material-" + name + ".ltm";
}

std::string Vec3Text(const glm::dvec3& v) { return Shortest(v.x) + "," + Shortest(v.y) + "," + Shortest(v.z); }

// The triple-product path's steps: one `ltbake material` per [triple] materials entry, or
// one `ltbake relight vis.ltm --material ...` view per map.
Status AddTripleNodes(const Recipe& r, const std::string& stage,
                      const std::function<std::string(const std::string&)>& path, Graph* g) {
  const auto& t = r.triple;
  if (!t.present) return InvalidArgument(r.path + ": " + stage + " is asked for but the recipe has no [triple] table");
  if (stage == "material") {
    for (const std::string& spec : t.materials) {
      Node m;
      m.name = "material:" + spec;
      m.stages = {"material"};
      m.output = MaterialFile(spec);
      m.params = {{"brdf", spec}, {"cube_res", t.cube_res}};
      m.args = {"material", "--brdf", spec, "--cube-res", std::to_string(t.cube_res)};
      g->nodes.push_back(std::move(m));
    }
    return Status::Ok();
  }
  for (const EnvMap& env : t.envs) {
    if (env.path.find("{face}") != std::string::npos) {
      return InvalidArgument(r.path + ": [triple] envs: " + env.path +
                             ": six-file {face} maps are not supported in recipes; convert it to one cubemap first");
    }
    Node m;
    m.name = "triple:" + env.name;
    m.stages = {"triple"};
    m.image = true;
    m.env = env.path;
    m.inputs = {"vis.ltm"};
    m.output = "view-" + env.name + "." + t.format;
    m.args = {"relight", path("vis.ltm")};
    for (const std::string& spec : t.materials) {
      m.inputs.push_back(MaterialFile(spec));
      m.args.insert(m.args.end(), {"--material", path(MaterialFile(spec))});
    }
    m.params = {{"env", env.path},
                {"eye", {t.eye.x, t.eye.y, t.eye.z}},
                {"target", {t.target.x, t.target.y, t.target.z}},
                {"up", {t.up.x, t.up.y, t.up.z}},
                {"fov", t.fov},
                {"size", {t.width, t.height}},
                {"method", t.method},
                {"terms", t.terms},
                {"brdf_terms", t.brdf_terms},
                {"clamp", t.clamp},
                {"format", t.format},
                {"exposure", t.exposure}};
    m.args.insert(
        m.args.end(),
        {"--env",        env.path,           "--eye",      Vec3Text(t.eye),
         "--target",     Vec3Text(t.target), "--up",       Vec3Text(t.up),
         "--fov",        Shortest(t.fov),    "--size",     std::to_string(t.width) + "x" + std::to_string(t.height),
         "--method",     t.method,           "--terms",    t.terms,
         "--brdf-terms", t.brdf_terms,       "--exposure", Shortest(t.exposure),
         "--json"});
    if (t.clamp) m.args.push_back("--clamp");
    g->nodes.push_back(std::move(m));
  }
  return Status::Ok();
}

// [sample] channels = "rgb" (docs/COLOUR.md): every container step becomes one step per
// colour channel, on the channel files (raw.ltm -> raw.r.ltm, ...); a sample step gains
// --channel. Relight steps read the three files of their matrix (relight takes the set).
void ExpandChannels(const std::function<std::string(const std::string&)>& path, Graph* g) {
  static const std::set<std::string> kPerChannel = {"sample",           "row-transform", "transpose",
                                                    "column-transform", "quantize",      "cpca"};
  auto per_channel = [&](const Node& n) {
    if (n.image || n.stages.empty() || n.params.contains("visibility")) return false;
    for (const std::string& s : n.stages)
      if (!kPerChannel.count(s)) return false;
    return true;
  };
  std::set<std::string> split;  // work files made per channel
  for (const Node& n : g->nodes)
    if (per_channel(n)) split.insert(n.output);
  std::vector<Node> nodes;
  for (Node& n : g->nodes) {
    if (!per_channel(n)) {
      std::vector<std::string> inputs;
      for (const std::string& in : n.inputs) {
        if (!split.count(in)) {
          inputs.push_back(in);
          continue;
        }
        for (int c = 0; c < stages::kChannels; ++c) inputs.push_back(stages::ChannelPath(in, c));
      }
      n.inputs = std::move(inputs);
      nodes.push_back(std::move(n));
      continue;
    }
    for (int c = 0; c < stages::kChannels; ++c) {
      Node m = n;
      const std::string ch = stages::ChannelName(c);
      m.name = n.name + "." + ch;
      m.output = stages::ChannelPath(n.output, c);
      for (std::string& in : m.inputs)
        if (split.count(in)) in = stages::ChannelPath(in, c);
      for (std::string& a : m.args) {
        for (const std::string& f : split)
          if (a == path(f)) a = path(stages::ChannelPath(f, c));
      }
      if (n.stages.front() == "sample") m.args.insert(m.args.begin() + 2, {"--channel", ch});
      m.params["channel"] = ch;
      nodes.push_back(std::move(m));
    }
  }
  g->nodes = std::move(nodes);
  std::set<std::string> wanted;
  for (const std::string& w : g->wanted) {
    if (!split.count(w)) {
      wanted.insert(w);
      continue;
    }
    for (int c = 0; c < stages::kChannels; ++c) wanted.insert(stages::ChannelPath(w, c));
  }
  g->wanted = std::move(wanted);
}

}  // namespace

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
    if (stage == "material" || stage == "triple") {
      LTB_RETURN_IF_ERROR(AddTripleNodes(r, stage, path, &g));
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
      if (!rl.sequence.empty()) {
        m.params["sequence"] = rl.sequence;
        m.params["method"] = rl.method;
        m.args.insert(m.args.end(), {"--sequence", rl.sequence, "--method", rl.method});
      }
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
    // The triple path's fields are what every later view reads: kept like final and cpca.
    if (target || n.image || r.Keeps(stem) || stem == "final" || stem == "cpca" || stem == "vis" ||
        stem.starts_with("material-")) {
      g.wanted.insert(n.output);
    }
  }
  if (r.sample.channels == "rgb") ExpandChannels(path, &g);
  return g;
}

}  // namespace ltb::pipeline
