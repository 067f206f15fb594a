#include "pipeline/stage_table.h"

#include <charconv>
#include <optional>

namespace ltb::pipeline {
namespace {

using nlohmann::json;

StageCommand Sample(const Recipe& r, const StageContext& ctx) {
  StageCommand c;
  c.args = {"sample", ctx.scene_file};
  auto opt = [&](const char* flag, const char* key, const std::optional<uint64_t>& v) {
    c.params[key] = v ? json(*v) : json(nullptr);
    if (v) {
      c.args.push_back(flag);
      c.args.push_back(std::to_string(*v));
    }
  };
  opt("--cube-res", "cube_res", r.sample.cube_res);
  opt("--spp", "spp", r.sample.spp);
  opt("--bounces", "bounces", r.sample.bounces);
  opt("--seed", "seed", r.sample.seed);
  const auto& sp = r.sample;
  if (sp.tolerance) {  // converged sampling; absent from params otherwise (older runs stay up to date)
    c.params["tolerance"] = *sp.tolerance;
    c.args.insert(c.args.end(), {"--tolerance", Shortest(*sp.tolerance)});
    if (sp.max_levels) {
      c.params["max_levels"] = *sp.max_levels;
      c.args.insert(c.args.end(), {"--max-levels", std::to_string(*sp.max_levels)});
    }
  }
  if (sp.sparse) {  // params["sparse"] marks the step unshardable (pipeline/bake.cpp)
    json p = json::object();
    c.args.insert(c.args.end(), {"--sparse", sp.sparse_force ? "force" : "auto"});
    p["mode"] = sp.sparse_force ? "force" : "auto";
    auto num = [&](const char* flag, const char* key, const std::optional<double>& v) {
      if (!v) return;
      p[key] = *v;
      c.args.insert(c.args.end(), {flag, Shortest(*v)});
    };
    auto whole = [&](const char* flag, const char* key, const std::optional<uint64_t>& v) {
      if (!v) return;
      p[key] = *v;
      c.args.insert(c.args.end(), {flag, std::to_string(*v)});
    };
    num("--dense-fraction", "dense_fraction", sp.dense_fraction);
    num("--radius", "radius", sp.radius);
    num("--l1-lambda", "l1_lambda", sp.l1_lambda);
    num("--max-residual", "max_residual", sp.max_residual);
    whole("--features", "features", sp.features);
    whole("--neighbours", "neighbours", sp.neighbours);
    c.params["sparse"] = p;
  }
  return c;
}

StageCommand RowTransform(const Recipe& r, const StageContext& ctx) {
  StageCommand c;
  c.inputs = {"raw.ltm"};
  c.params = {{"filter", r.row_transform.filter}, {"zstd", r.row_transform.zstd}};
  c.args = {"row-transform", ctx.path("raw.ltm"), "--filter", r.row_transform.filter};
  if (r.row_transform.zstd) c.args.push_back("--zstd");
  return c;
}

// Row-transform inside sample (`sample --row-transform FILTER`): rows.ltm without raw.ltm.
std::vector<std::string> RowTransformInSample(const Recipe& r) {
  std::vector<std::string> a = {"--row-transform", r.row_transform.filter};
  if (r.row_transform.zstd) a.push_back("--row-zstd");
  return a;
}

StageCommand Transpose(const Recipe& r, const StageContext& ctx) {
  StageCommand c;
  c.inputs = {"rows.ltm"};
  c.params = {{"zstd", r.transpose.zstd}};
  c.args = {"transpose", ctx.path("rows.ltm")};
  if (r.transpose.zstd) c.args.push_back("--zstd");
  return c;
}

StageCommand ColumnTransform(const Recipe& r, const StageContext& ctx) {
  const auto& col = r.column_transform;
  StageCommand c;
  c.inputs = {"cols.ltm"};
  c.params = {{"filter", col.filter}, {"depth", col.depth}, {"zstd", col.zstd}};
  c.args = {"column-transform", ctx.path("cols.ltm"), "--filter", col.filter, "--depth", col.depth};
  if (col.terms) {
    c.params["terms"] = *col.terms;
    c.args.insert(c.args.end(), {"--terms", std::to_string(*col.terms)});
  } else if (col.target_error) {
    c.params["target_error"] = *col.target_error;
    c.args.insert(c.args.end(), {"--target-error", Shortest(*col.target_error)});
  } else if (col.keep) {
    c.params["keep"] = *col.keep;
    c.args.insert(c.args.end(), {"--keep", Shortest(*col.keep)});
  } else {
    c.params["budget"] = col.budget.value_or("5%");
    c.args.insert(c.args.end(), {"--budget", col.budget.value_or("5%")});
  }
  if (!col.zstd) c.args.push_back("--no-zstd");
  return c;
}

StageCommand Quantize(const Recipe& r, const StageContext& ctx) {
  const auto& q = r.quantize;
  StageCommand c;
  c.inputs = {"cols4d.ltm"};
  if (q.bits) {
    c.params = {{"bits", *q.bits}, {"scaling", q.scaling}, {"dither", q.dither}, {"seed", q.seed}};
    c.args = {"quantize", ctx.path("cols4d.ltm"), "--bits", std::to_string(*q.bits), "--scaling", q.scaling,
              "--seed",   std::to_string(q.seed)};
    if (q.dither) c.args.push_back("--dither");
  } else {
    c.params = {{"error_ratio", q.error_ratio}};
    c.args = {"quantize", ctx.path("cols4d.ltm"), "--error-ratio", Shortest(q.error_ratio)};
  }
  return c;
}

StageCommand Cpca(const Recipe& r, const StageContext& ctx) {
  const auto& p = r.cpca;
  StageCommand c;
  c.inputs = {"rows.ltm"};
  c.params = {{"clusters", p.clusters}, {"basis", p.basis}, {"max_iterations", p.max_iterations}, {"seed", p.seed}};
  c.args = {"cpca",    ctx.path("rows.ltm"),    "--clusters",       std::to_string(p.clusters),
            "--basis", std::to_string(p.basis), "--max-iterations", std::to_string(p.max_iterations),
            "--seed",  std::to_string(p.seed)};
  return c;
}

StageCommand Visibility(const Recipe& r, const StageContext& ctx) {
  StageCommand c;
  c.args = {"sample", ctx.scene_file, "--visibility", "--cube-res", std::to_string(r.triple.cube_res)};
  c.params = {{"visibility", true}, {"cube_res", r.triple.cube_res}, {"spp", nullptr}};
  if (r.triple.spp) {
    c.params["spp"] = *r.triple.spp;
    c.args.insert(c.args.end(), {"--spp", std::to_string(*r.triple.spp)});
  }
  return c;
}

}  // namespace

const std::vector<StageInfo>& StageTable() {
  static const std::vector<StageInfo> table = {
      {"sample", "raw.ltm", {}, true, "ray-cast the transport matrix of the scene (Embree)", Sample, true, true},
      {"row-transform",
       "rows.ltm",
       {"sample"},
       true,
       "2D wavelets per cube face along each row",
       RowTransform,
       true,
       false,
       {},
       RowTransformInSample},
      // A transpose shard reads a slice of every row block; its checksum pass would read all
      // of them, in every shard. The commit of its input has just checked every checksum.
      {"transpose",
       "cols.ltm",
       {"row-transform"},
       true,
       "row blocks to column blocks, out of core",
       Transpose,
       true,
       false,
       {"--no-verify-input"}},
      {"column-transform",
       "cols4d.ltm",
       {"transpose"},
       true,
       "adaptive 4D: each column image at its best depth, its largest terms kept",
       ColumnTransform,
       true},
      {"quantize", "final.ltm", {"column-transform"}, true, "quantize the kept coefficients", Quantize, true},
      {"cpca", "cpca.ltm", {"row-transform"}, false, "clustered PCA of the row-transformed matrix", Cpca, true},
      {"relight", "", {}, false, "relight under each environment map, with its error", nullptr},
      {"visibility",
       "vis.ltm",
       {},
       true,
       "triple products: the visibility field per vertex (sample --visibility)",
       Visibility,
       false,
       true},
      {"material", "", {}, false, "triple products: a material field per [triple] materials entry", nullptr},
      {"triple", "", {"visibility", "material"}, false, "triple products: a view of the scene under each map", nullptr},
  };
  return table;
}

bool ReadsScene(const std::vector<std::string>& stages) {
  const StageInfo* s = stages.empty() ? nullptr : FindStage(stages.front());
  return s != nullptr && s->reads_scene;
}

const StageInfo* FindStage(std::string_view name) {
  for (const StageInfo& s : StageTable())
    if (s.name == name) return &s;
  return nullptr;
}

std::vector<std::string> StageNeeds(const Recipe& r, std::string_view name) {
  if (name == "relight") {
    std::vector<std::string> d = {r.relight.matrix == "cpca" ? "cpca" : "quantize"};
    if (r.relight.reference) d.push_back("row-transform");
    return d;
  }
  std::vector<std::string> out;
  if (const StageInfo* s = FindStage(name))
    for (std::string_view n : s->needs) out.emplace_back(n);
  return out;
}

const std::vector<std::string>& StageNames() {
  static const std::vector<std::string> names = [] {
    std::vector<std::string> n;
    for (const StageInfo& s : StageTable()) n.emplace_back(s.name);
    return n;
  }();
  return names;
}

std::string Shortest(double v) {
  char b[64];
  auto r = std::to_chars(b, b + sizeof b, v);
  return std::string(b, r.ptr);
}

}  // namespace ltb::pipeline
