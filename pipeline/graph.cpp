#include "pipeline/graph.h"

#include <algorithm>
#include <cctype>
#include <filesystem>
#include <functional>
#include <map>
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

// An image step of `stage` ([relight] or [triple]) under one map of its table, reading `input`.
Result<Node> EnvNode(const Recipe& r, const std::string& stage, const EnvMap& env, const std::string& input) {
  if (env.path.find("{face}") != std::string::npos) {
    return InvalidArgument(r.path + ": [" + stage + "] envs: " + env.path +
                           ": six-file {face} maps are not supported in recipes; convert it to one cubemap first "
                           "(ltbake convert MAP.exr MAP.npy --cube-res R) and name that file");
  }
  Node m;
  m.name = stage + ":" + env.name;
  m.stages = {stage};
  m.image = true;
  m.env = env.path;
  m.inputs = {input};
  return m;
}

// A table's env_layout other than "auto" is passed on (and is a parameter of the step); the
// default leaves both as they were before the key existed.
void AddEnvLayout(const EnvMap& env, Node* m) {
  if (env.layout == "auto") return;
  m->params["env_layout"] = env.layout;
  m->args.insert(m->args.end(), {"--env-layout", env.layout});
}

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
    LTB_ASSIGN_OR_RETURN(Node m, EnvNode(r, "triple", env, "vis.ltm"));
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
    AddEnvLayout(env, &m);
    g->nodes.push_back(std::move(m));
  }
  return Status::Ok();
}

// [sample] channels = "rgb" (docs/COLOUR.md) or factor = K (docs/GLOSSY.md): every
// container step becomes one step per set member, on the member files (raw.ltm ->
// raw.r.ltm or raw.k0.ltm, ...); a sample step gains the member's flags. Relight steps read
// every member (relight takes the set).
void ExpandSet(const std::function<std::string(const std::string&)>& path, const std::vector<std::string>& names,
               const std::function<std::vector<std::string>(size_t)>& sample_args, Graph* g) {
  auto per_member = [&](const Node& n) {
    if (n.image || n.stages.empty() || n.params.contains("visibility")) return false;
    for (const std::string& s : n.stages)
      if (const StageInfo* info = FindStage(s); info == nullptr || !info->per_set_member) return false;
    return true;
  };
  std::set<std::string> split;  // work files made per member
  for (const Node& n : g->nodes)
    if (per_member(n)) split.insert(n.output);
  std::vector<Node> nodes;
  for (Node& n : g->nodes) {
    if (!per_member(n)) {
      std::vector<std::string> inputs;
      for (const std::string& in : n.inputs) {
        if (!split.count(in)) {
          inputs.push_back(in);
          continue;
        }
        for (const std::string& name : names) inputs.push_back(stages::SetMemberPath(in, name));
      }
      n.inputs = std::move(inputs);
      nodes.push_back(std::move(n));
      continue;
    }
    for (size_t c = 0; c < names.size(); ++c) {
      Node m = n;
      m.name = n.name + "." + names[c];
      m.output = stages::SetMemberPath(n.output, names[c]);
      for (std::string& in : m.inputs)
        if (split.count(in)) in = stages::SetMemberPath(in, names[c]);
      for (std::string& a : m.args) {
        for (const std::string& f : split)
          if (a == path(f)) a = path(stages::SetMemberPath(f, names[c]));
      }
      if (n.stages.front() == "sample") {
        const std::vector<std::string> extra = sample_args(c);
        m.args.insert(m.args.begin() + 2, extra.begin(), extra.end());
      }
      m.params["member"] = names[c];
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
    for (const std::string& name : names) wanted.insert(stages::SetMemberPath(w, name));
  }
  g->wanted = std::move(wanted);
}

// [sample] channels = "rgb" and factor = K: the graph's container steps per set member
// (ExpandSet), with each member's sample flags.
void ExpandSets(const Recipe& r, const std::function<std::string(const std::string&)>& path, Graph* g) {
  if (r.sample.channels == "rgb" && r.sample.factor > 0) {  // a colour factored bake: member k<k>.<c>
    std::vector<std::string> names;
    for (uint64_t k = 0; k < r.sample.factor; ++k)
      for (const char* c : {"r", "g", "b"}) names.push_back("k" + std::to_string(k) + "." + c);
    const std::string terms = std::to_string(r.sample.factor);
    ExpandSet(
        path, names,
        [&](size_t i) {
          return std::vector<std::string>{
              "--factor", terms, "--factor-term", std::to_string(i / 3), "--channel", std::string(1, "rgb"[i % 3])};
        },
        g);
  } else if (r.sample.channels == "rgb") {
    ExpandSet(
        path, {"r", "g", "b"},
        [](size_t c) {
          return std::vector<std::string>{"--channel", std::string(1, "rgb"[c])};
        },
        g);
  } else if (r.sample.factor > 0) {
    std::vector<std::string> names;
    for (uint64_t k = 0; k < r.sample.factor; ++k) names.push_back("k" + std::to_string(k));
    const std::string terms = std::to_string(r.sample.factor);
    ExpandSet(
        path, names,
        [&](size_t k) {
          return std::vector<std::string>{"--factor", terms, "--factor-term", std::to_string(k)};
        },
        g);
  }
}

// One relight step per [relight] map: relit-NAME.FORMAT from final.ltm or cpca.ltm (a view with
// eye/target, a sequence, a reference error against rows.ltm as the table asks).
Status AddRelightNodes(const Recipe& r, const std::function<std::string(const std::string&)>& path, Graph* g) {
  const auto& rl = r.relight;
  std::string matrix = rl.matrix == "cpca" ? "cpca.ltm" : "final.ltm";
  for (const EnvMap& env : rl.envs) {
    LTB_ASSIGN_OR_RETURN(Node m, EnvNode(r, "relight", env, matrix));
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
    if (rl.eye) {  // a view of a factored bake (docs/GLOSSY.md)
      m.params["eye"] = {rl.eye->x, rl.eye->y, rl.eye->z};
      m.params["target"] = {rl.target.x, rl.target.y, rl.target.z};
      m.params["up"] = {rl.up.x, rl.up.y, rl.up.z};
      m.params["fov"] = rl.fov;
      m.params["size"] = {rl.width, rl.height};
      // relight --eye takes neither --weighting nor --json's matrix-path keys: rebuilt here.
      m.args = {"relight",    path(matrix),
                "--env",      env.path,
                "--terms",    std::to_string(rl.terms),
                "--eye",      Vec3Text(*rl.eye),
                "--target",   Vec3Text(rl.target),
                "--up",       Vec3Text(rl.up),
                "--fov",      Shortest(rl.fov),
                "--size",     std::to_string(rl.width) + "x" + std::to_string(rl.height),
                "--exposure", Shortest(rl.exposure),
                "--json"};
      if (rl.clamp) m.args.push_back("--clamp");
    }
    AddEnvLayout(env, &m);
    if (!rl.sequence.empty()) {
      m.params["sequence"] = rl.sequence;
      m.params["method"] = rl.method;
      m.args.insert(m.args.end(), {"--sequence", rl.sequence, "--method", rl.method});
    }
    if (rl.reference) {
      m.inputs.push_back("rows.ltm");
      m.args.insert(m.args.end(), {"--reference", path("rows.ltm")});
    }
    g->nodes.push_back(std::move(m));
  }
  return Status::Ok();
}

}  // namespace

int StageIndex(const std::string& s) {
  const auto& n = StageNames();
  return static_cast<int>(std::find(n.begin(), n.end(), s) - n.begin());
}

namespace {

// --from, --until and --force name stages of the table (or "all" for --force).
Status CheckStageFlags(const BakeOptions& o) {
  auto valid_stage = [](const std::string& s, const char* flag) -> Status {
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
  return Status::Ok();
}

}  // namespace

Result<Graph> BuildGraph(const Recipe& r, const BakeOptions& o, const std::string& workdir,
                         const std::string& scene_file) {
  Graph g;
  LTB_RETURN_IF_ERROR(CheckStageFlags(o));
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
  // Stages that run inside the stage they need (StageInfo::fused_args): needed -> fused.
  std::map<std::string, const StageInfo*> fused_into;
  std::set<std::string> fused;
  for (const StageInfo& info : StageTable()) {
    if (!info.fused_args || info.needs.size() != 1) continue;
    const std::string stage(info.name), host(info.needs[0]);
    const std::string host_output(FindStage(host)->output);
    const std::string kept = host_output.substr(0, host_output.rfind('.'));  // "raw" for raw.ltm
    if (needed.count(stage) && needed.count(host) && !r.Keeps(kept) && !g.targets.count(host) && o.from != stage) {
      fused_into[host] = &info;
      fused.insert(stage);
    }
  }

  auto path = [&](const std::string& file) { return (fs::path(workdir) / file).string(); };
  const StageContext ctx{path, scene_file};
  for (const StageInfo& info : StageTable()) {
    const std::string stage(info.name);
    if (!needed.count(stage)) continue;
    if (fused.count(stage)) continue;  // done by the step of the stage it runs in
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
    if (auto it = fused_into.find(stage); it != fused_into.end()) {  // e.g. sample + row-transform: no raw.ltm
      const StageInfo& inner = *it->second;
      const std::string inner_name(inner.name);
      n.name = stage + "+" + inner_name;
      n.stages = {stage, inner_name};
      n.output = inner.output;
      n.params = {{stage, n.params}, {inner_name, inner.command(r, ctx).params}};
      const std::vector<std::string> extra = inner.fused_args(r);
      n.args.insert(n.args.end(), extra.begin(), extra.end());
    }
    if (info.command) {
      g.nodes.push_back(std::move(n));
      continue;
    }
    if (stage == "material" || stage == "triple") {
      LTB_RETURN_IF_ERROR(AddTripleNodes(r, stage, path, &g));
      continue;
    }
    LTB_RETURN_IF_ERROR(AddRelightNodes(r, path, &g));
  }
  // Files to leave on disk: the targets' outputs and the kept intermediates.
  for (const Node& n : g.nodes) {
    bool target = false;
    for (const auto& s : n.stages) target = target || g.targets.count(s);
    if (n.stages.size() > 1)
      target = g.targets.count(n.stages.back()) > 0;  // a fused step makes its inner stage's output
    std::string stem = fs::path(n.output).stem().string();
    // The triple path's fields are what every later view reads: kept like final and cpca.
    if (target || n.image || r.Keeps(stem) || stem == "final" || stem == "cpca" || stem == "vis" ||
        stem.starts_with("material-")) {
      g.wanted.insert(n.output);
    }
  }
  ExpandSets(r, path, &g);
  return g;
}

std::vector<std::string> StepArgs(const Node& n, const std::string& output, const BakeOptions& o, bool overwrite,
                                  bool shard) {
  std::vector<std::string> c(n.args.begin(), n.args.end());
  c.insert(c.end(), {"-o", output});
  if (shard) {
    c.insert(c.end(), {"--mem-limit", o.mem_limit, "--progress", "never"});
    if (overwrite) c.push_back("--overwrite");
    if (const StageInfo* info = FindStage(n.stages.front())) {
      for (std::string_view a : info->shard_args) c.emplace_back(a);
    }
    return c;
  }
  if (!n.image) c.insert(c.end(), {"--mem-limit", o.mem_limit});
  c.insert(c.end(), {"--jobs", std::to_string(o.jobs), "--progress", o.progress ? "always" : "never"});
  if (overwrite && !n.image) c.push_back("--overwrite");
  return c;
}

}  // namespace ltb::pipeline
