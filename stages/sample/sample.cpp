#include "stages/sample/sample.h"

#include <time.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <memory>
#include <mutex>
#include <optional>
#include <sstream>
#include <vector>

#include "format/io/async_chunk_writer.h"
#include "format/io/container_writer.h"
#include "format/version.h"
#include "stages/common/base64.h"
#include "stages/common/basis.h"
#include "stages/common/channels.h"
#include "stages/common/parallel_for.h"
#include "stages/mesh/triangle_mesh.h"
#include "stages/row_transform/row_transform.h"
#include "stages/sample/converged.h"
#include "stages/sample/ray_scene.h"
#include "stages/sample/sample_internal.h"
#include "stages/sample/sampler.h"
#include "stages/sample/scene.h"
#include "stages/sample/scene_geometry.h"
#include "stages/sample/sparse_internal.h"
#include "stages/wavelet/haar_face.h"

namespace ltb::stages {

using namespace ltb::format;
using brdf::ParabolicTable;
using sample::BuildGeometry;
using sample::Counters;
using sample::Geometry;
using sample::PhongLobe;
using sample::RowPoint;
using sample::RowScratch;
using sample::Sampler;
using sample::SceneDesc;
using sample_internal::Prepared;

namespace sample_internal {

ArraySpec RowArray(const char* name, DType t, uint64_t rows, uint64_t cols, uint64_t block) {
  ArraySpec a;
  a.name = name;
  a.dtype = t;
  a.rows = rows;
  a.cols = cols;
  a.layout = Layout::kRows;
  a.block = block;
  return a;
}

Status CheckSparse(const SampleOptions& o, uint32_t r) {
  const SparseOptions& s = o.sparse;
  if (!s.enabled) return Status::Ok();
  auto num = [](double v) {
    std::ostringstream os;
    os << v;
    return os.str();
  };
  if (!(s.dense_fraction > 0 && s.dense_fraction <= 1)) {
    return InvalidArgument("--dense-fraction " + num(s.dense_fraction) + " is not in (0, 1]");
  }
  if (!(s.initial_fraction > 0 && s.initial_fraction <= 1)) {
    return InvalidArgument("the initial dense fraction " + num(s.initial_fraction) + " is not in (0, 1]");
  }
  if (s.radius && !(*s.radius > 0 && std::isfinite(*s.radius))) {
    return InvalidArgument("--radius " + num(*s.radius) + " must be a positive distance in scene units");
  }
  const uint64_t cols = 6ull * r * r;
  if (s.features && (*s.features == 0 || *s.features > cols)) {
    return InvalidArgument("--features " + std::to_string(*s.features) + " is not in 1..6R² = " + std::to_string(cols) +
                           " (R = " + std::to_string(r) + ")");
  }
  if (s.neighbours < 1 || s.neighbours > 64) {
    return InvalidArgument("--neighbours " + std::to_string(s.neighbours) + " is not in 1..64");
  }
  if (!(s.lambda >= 0 && s.lambda < 1)) return InvalidArgument("--l1-lambda " + num(s.lambda) + " is not in [0, 1)");
  if (!(s.max_residual > 0)) {
    return InvalidArgument("--max-residual " + num(s.max_residual) +
                           " must be positive (a large value never traces a row in full)");
  }
  if (o.visibility) return InvalidArgument("--sparse bakes T; it does not apply to --visibility");
  if (o.shard.sharded()) {
    return InvalidArgument("--sparse cannot be sharded yet (phase 1 is one sequence of rounds); run it unsharded");
  }
  return Status::Ok();
}

// --tolerance: a relative error in (0, 1), at least two samples a texel (the error is
// estimated from their spread), levels in 1..12; not yet with the modes that trace rows
// their own way.
Status CheckConverged(const SampleOptions& o, uint32_t spp) {
  if (!o.tolerance) return Status::Ok();
  const double t = *o.tolerance;
  if (!(t > 0 && t < 1)) {
    std::ostringstream os;
    os << t;
    return InvalidArgument("--tolerance " + os.str() + " is not a relative error in (0, 1) (e.g. 0.5% or 0.005)");
  }
  if (spp < 2) {
    return InvalidArgument("--tolerance estimates each texel's error from the spread of its samples: --spp " +
                           std::to_string(spp) + " must be at least 2");
  }
  if (o.max_levels < 1 || o.max_levels > 12) {
    return InvalidArgument("--max-levels " + std::to_string(o.max_levels) + " is not in 1..12");
  }
  if ((uint64_t{spp} << (o.max_levels - 1)) > (uint64_t{1} << 16)) {
    return InvalidArgument("--tolerance: --spp " + std::to_string(spp) + " at --max-levels " +
                           std::to_string(o.max_levels) + " would trace " +
                           std::to_string(uint64_t{spp} << (o.max_levels - 1)) +
                           " samples a texel at its top level; at most 65536 (lower either)");
  }
  if (o.sparse.enabled || o.visibility || o.rgb || o.factor > 0) {
    return InvalidArgument(
        "--tolerance (converged sampling) does not yet combine with --sparse, --visibility, --channels rgb or "
        "--factor (docs/SAMPLE.md \"Converged sampling\")");
  }
  return Status::Ok();
}

// Once the geometry is built. --channel: the scene as that channel sees it. A monochrome
// bake of a scene with colour:
// the reflectance table when the colour factors out of T (no bounces, and in image mode,
// where ks is rendered, one tint for albedo and ks and no vertex colours under a lobe);
// otherwise an error that says to bake per channel.
Status CheckColour(const SampleOptions& o, Prepared* p) {
  const SceneDesc& s = p->scene;
  // The original scene: the sampler reads each channel's values (a factored bake's
  // --channel c is channel c of the colour factored bake, from the same rays and factors).
  if (o.rgb || (o.factor > 0 && o.channel >= 0)) {
    if (o.visibility || o.sparse.enabled || (o.rgb && o.channel >= 0)) {
      return InvalidArgument("--channels rgb in one pass does not combine with --visibility, --sparse or --channel");
    }
    if (o.factor > 0 && o.channel >= 0 && !o.factor_term) {
      return InvalidArgument("--channel with --factor " + std::to_string(o.factor) +
                             " bakes one channel of one term: give --factor-term too (or --channels rgb for every "
                             "term and channel)");
    }
    p->rgb_factor = o.factor > 0;
    return Status::Ok();
  }
  if (o.channel >= 0) {
    if (o.visibility) return InvalidArgument("--visibility bakes geometry (no colour); leave out --channel");
    p->scene = ChannelScene(s, o.channel);
    return Status::Ok();
  }
  // Colour that reaches a row: a material some geometry uses that is not grey, or vertex colours.
  bool coloured = false;
  for (size_t g = 0; g < p->geo.geom_material.size(); ++g) {
    coloured = coloured || !s.materials[static_cast<size_t>(p->geo.geom_material[g])].Grey() ||
               s.objects[static_cast<size_t>(p->geo.geom_object[g])].colours == sample::Object::Colours::kFile;
  }
  if (o.visibility || !coloured) return Status::Ok();
  const std::string fix = "; bake one matrix per channel with --channels rgb (docs/COLOUR.md)";
  if (p->bounces > 0) {
    return InvalidArgument(o.scene + ": the scene has colour and --bounces " + std::to_string(p->bounces) +
                           " makes it bleed between surfaces, which one monochrome matrix cannot hold" + fix);
  }
  // A factored vertex bake keeps the diffuse part (term 0) and the lobe (terms 1..K−1) in
  // files of their own, each with its own reflectance table: the albedo's colour (and any
  // vertex colours) on term 0, the lobe's on the others, so any colours factor out (a red
  // plastic with a white highlight included). Image mode renders the two together.
  if (s.mode == SceneDesc::Mode::kImage) {
    // Every Embree geometry's material: an object's own, or those its OBJ's usemtl picks.
    for (size_t g = 0; g < p->geo.geom_material.size(); ++g) {
      const sample::Object& obj = s.objects[static_cast<size_t>(p->geo.geom_object[g])];
      const sample::Material& m = s.materials[static_cast<size_t>(p->geo.geom_material[g])];
      if (!m.separable) {
        return InvalidArgument(o.scene + ": material \"" + m.name + "\" has albedo " +
                               sample::FormatVec3(m.albedo_rgb) + " and ks " + sample::FormatVec3(m.ks_rgb) +
                               ", not one colour times two numbers, so its colour does not factor out of T" + fix);
      }
      if (obj.colours == sample::Object::Colours::kFile && m.ks > 0) {
        return InvalidArgument(o.scene + ":" + std::to_string(obj.line) + ": object \"" + obj.name +
                               "\" has vertex colours under the glossy material \"" + m.name +
                               "\" (ks > 0): they tint the albedo, not the lobe, so they do not factor out of T" + fix);
      }
    }
  }
  p->reflectance = true;
  return Status::Ok();
}

Result<std::unique_ptr<Prepared>> Prepare(const SampleOptions& o, const Progress& progress) {
  auto p = std::make_unique<Prepared>();
  LTB_ASSIGN_OR_RETURN(p->scene, sample::ParseScene(o.scene));
  p->r = o.cube_res.value_or(p->scene.cube_res);
  p->spp = o.spp.value_or(p->scene.spp);
  p->bounces = o.bounces.value_or(p->scene.bounces);
  p->seed = o.seed.value_or(p->scene.seed);
  if (!IsPowerOfTwo(p->r) || p->r > 1024) {
    return InvalidArgument("cube resolution " + std::to_string(p->r) +
                           " is not a power of two in 1..1024 (--cube-res)");
  }
  if (p->spp == 0) return InvalidArgument("--spp must be at least 1");
  LTB_RETURN_IF_ERROR(CheckSparse(o, p->r));
  LTB_RETURN_IF_ERROR(CheckConverged(o, p->spp));
  if (o.visibility) {
    if (p->scene.mode != SceneDesc::Mode::kVertex) {
      return InvalidArgument(o.scene +
                             ": --visibility bakes a field per vertex; the scene has a camera (image mode). Give it "
                             "an [output] table with mode = \"vertices\" (docs/SCENE.md)");
    }
    if (o.bounces.value_or(0) > 0) {
      return InvalidArgument("--visibility traces direct visibility only; --bounces " + std::to_string(*o.bounces) +
                             " does not apply (leave it out)");
    }
    if (o.row_filter) return InvalidArgument("--visibility cannot be fused with a row-transform");
    p->bounces = 0;  // the scene's [sampling] bounces do not apply to visibility
  }
  if (o.factor > 0) {
    const std::string f = "--factor " + std::to_string(o.factor);
    if (p->scene.mode != SceneDesc::Mode::kVertex) {
      return InvalidArgument(o.scene + ": " + f +
                             " factors the BRDF for vertex rows seen from any view; the scene "
                             "has a camera (image mode, one fixed view). Give it [output] mode = \"vertex\"");
    }
    if (o.factor > 64) return InvalidArgument(f + ": at most 64 terms");
    if (o.visibility || o.sparse.enabled) {
      return InvalidArgument(f + " does not combine with --visibility or --sparse (docs/GLOSSY.md)");
    }
  }
  LTB_ASSIGN_OR_RETURN(p->geo, BuildGeometry(p->scene, progress));
  LTB_RETURN_IF_ERROR(CheckColour(o, p.get()));
  p->rows = p->scene.mode == SceneDesc::Mode::kImage ? uint64_t{p->scene.camera.width} * p->scene.camera.height
                                                     : p->geo.vertex_rows.size();
  return p;
}

}  // namespace sample_internal

std::string FactorPath(const std::string& output, uint32_t k) { return SetMemberPath(output, "k" + std::to_string(k)); }

Result<BareTraceResult> TraceBare(const SampleOptions& o) {
  LTB_ASSIGN_OR_RETURN(std::unique_ptr<Prepared> p, sample_internal::Prepare(o, Progress{}));
  Sampler sampler(p->scene, p->geo, p->r, p->spp, p->bounces, p->seed);
  std::vector<uint64_t> blocks;
  const uint64_t block = 64;
  for (uint64_t r0 = 0; r0 < p->rows; r0 += block) blocks.push_back(r0);
  std::atomic<uint64_t> rays{0}, nanos{0}, cpu_nanos{0};
  auto thread_cpu_ns = [] {
    timespec t{};
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t);
    return static_cast<uint64_t>(t.tv_sec) * 1000000000ull + static_cast<uint64_t>(t.tv_nsec);
  };
  auto t0 = std::chrono::steady_clock::now();
  LTB_RETURN_IF_ERROR(ParallelFor(blocks, o.jobs, Progress{}, "rows", [&](uint64_t r0) -> Status {
    thread_local RowScratch sc;
    const uint64_t item_cpu0 = thread_cpu_ns();
    const auto item_wall0 = std::chrono::steady_clock::now();
    uint64_t item_embree_ns = 0;
    for (uint64_t row = r0; row < std::min(p->rows, r0 + block); ++row) {
      RowPoint rp = sampler.Primary(row);
      if (!rp.valid) continue;
      uint64_t below = 0, samples_below = 0;
      const PhongLobe brdf = sampler.MakeBrdf(rp);
      const uint64_t cols = 6ull * p->r * p->r, step = sampler.TexelsPerBatch();
      for (uint64_t c0 = 0; c0 < cols; c0 += step) {  // the same batches RunSample traces
        sampler.GenerateRays(row, rp, brdf, c0, std::min(cols, c0 + step), sc, &below, &samples_below);
        auto a = std::chrono::steady_clock::now();
        sampler.rays().Occluded(sc.batch, sc.n);
        item_embree_ns += static_cast<uint64_t>(
            std::chrono::duration_cast<std::chrono::nanoseconds>(std::chrono::steady_clock::now() - a).count());
        rays += sc.active;
      }
    }
    const double item_cpu = static_cast<double>(thread_cpu_ns() - item_cpu0);
    const double item_wall = static_cast<double>(
        std::chrono::duration_cast<std::chrono::nanoseconds>(std::chrono::steady_clock::now() - item_wall0).count());
    nanos += item_embree_ns;
    if (item_wall > 0) cpu_nanos += static_cast<uint64_t>(item_cpu * static_cast<double>(item_embree_ns) / item_wall);
    return Status::Ok();
  }));
  BareTraceResult out;
  out.rays = rays;
  out.trace_thread_seconds = static_cast<double>(nanos.load()) * 1e-9;
  out.trace_cpu_seconds = static_cast<double>(cpu_nanos.load()) * 1e-9;
  out.wall_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return out;
}

namespace sample_internal {

uint64_t BlockRows(const SampleOptions& o, uint64_t rows, uint64_t cols) {
  uint64_t block = o.chunk_rows;
  if (block == 0) {
    block = std::max<uint64_t>(1, (2u << 20) / (cols * 4));
    // At least 4 blocks per worker thread; for shards, 4 per shard instead: every shard
    // must pick the same blocking whatever --jobs its task runs with.
    const uint64_t parts = 4 * (o.shard.sharded() ? o.shard.count : static_cast<uint64_t>(std::max(1, o.jobs)));
    block = std::min(block, std::max<uint64_t>(1, (rows + parts - 1) / parts));
  }
  return std::min(block, rows);
}

nlohmann::json SampleMetadata(const SampleOptions& o, const Prepared& p, uint64_t block) {
  const SceneDesc& scene = p.scene;
  const uint32_t r = p.r;
  const uint64_t rows = p.rows, cols = 6ull * r * r;
  auto spec = [&](const char* name, DType t, uint64_t c) { return RowArray(name, t, rows, c, block).ToJson(); };
  nlohmann::json rows_basis =
      scene.mode == SceneDesc::Mode::kImage
          ? ImageRows(scene.camera.width, scene.camera.height)
          : nlohmann::json{{"kind", "vertices"}, {"count", rows}, {"objects", scene.vertex_objects}};
  nlohmann::json params = {{"cube_res", r},
                           {"spp", p.spp},
                           {"bounces", p.bounces},
                           {"seed", p.seed},
                           {"scene", std::filesystem::path(o.scene).filename().string()},
                           {"scene_hash", p.geo.scene_hash}};
  nlohmann::json cols_basis = PixelCubemapCols(r);
  std::string stage = "sample";
  nlohmann::json extra = nlohmann::json::object();
  if (o.visibility) {
    cols_basis = {{"kind", "cubemap"}, {"cube_res", r}, {"basis", "haar-squares"}, {"quantity", "visibility"}};
    params["visibility"] = true;
    // Where the renderer finds the geometry for its primary rays (relight --material).
    extra["visibility"] = {{"scene", std::filesystem::absolute(o.scene).lexically_normal().string()},
                           {"scene_hash", p.geo.scene_hash},
                           {"geometry_hash", p.geo.geometry_hash}};
  }
  if (scene.mode == SceneDesc::Mode::kVertex && !o.visibility) {
    // Where a renderer of the vertices from an eye finds their mesh (relight --eye, view).
    extra["geometry"] = {{"scene", std::filesystem::absolute(o.scene).lexically_normal().string()},
                         {"scene_hash", p.geo.scene_hash},
                         {"geometry_hash", p.geo.geometry_hash}};
  }
  if (o.row_filter) {
    cols_basis = WaveletCubemapCols(r, wavelet::FilterName(*o.row_filter));
    stage = "sample+row-transform";
    params["row_filter"] = wavelet::FilterName(*o.row_filter);
    params["row_zstd"] = o.row_zstd;
  }
  if (o.channel >= 0) {
    params["channel"] = ChannelName(o.channel);
    // Which channel of which set (docs/COLOUR.md); every later stage keeps it.
    extra["channel"] = {{"name", ChannelName(o.channel)}, {"index", o.channel}, {"names", {"r", "g", "b"}}};
  }
  if (p.reflectance) params["colour"] = "reflectance";
  nlohmann::json meta = {
      {"arrays",
       {spec("matrix", DType::kF32, cols), spec("mask", DType::kU8, 1), spec("position", DType::kF32, 3),
        spec("normal", DType::kF32, 3)}},
      {"basis", {{"rows", rows_basis}, {"cols", cols_basis}}},
      {"provenance", Provenance(stage, params, {})},
  };
  meta.update(extra);
  return meta;
}

// The reflectance a row's term `term` of a bake carries: the albedo's colour times the
// vertex colour (term 0: the diffuse part, or a bake without --factor), or the lobe's colour
// (terms 1..K−1 of a factored bake). A separable material has one colour for both.
glm::dvec3 RowTint(const sample::Material& m, const RowPoint& rp, bool lobe) {
  if (!lobe) return m.tint * rp.colour;
  if (m.separable) return m.tint;  // (ks_rgb = tint·ks: the same colour, the same bits as before)
  const double kmax = std::max({m.ks_rgb.x, m.ks_rgb.y, m.ks_rgb.z});
  return kmax > 0 ? m.ks_rgb / kmax : m.tint;
}

void AddReflectance(const Prepared& p, uint64_t block, nlohmann::json* meta) {
  if (p.reflectance) (*meta)["arrays"].push_back(RowArray("reflectance", DType::kF32, p.rows, 3, block).ToJson());
}

Status WriteReflectance(const Prepared& p, const Sampler& sampler, uint64_t block, io::ContainerWriter& out, bool lobe,
                        const Progress& progress) {
  if (!p.reflectance) return Status::Ok();
  const int a = out.metadata().FindArray("reflectance");
  if (a < 0) return Internal(out.path() + ": no reflectance array to write");
  std::vector<float> v;
  for (uint64_t chunk : out.Missing(static_cast<uint32_t>(a))) {
    if (progress.Cancelled()) return Cancelled("interrupted; committed chunks are kept, rerun to resume");
    const uint64_t r0 = chunk * block, n = std::min(block, p.rows - r0);
    v.assign(n * 3, 0.0f);
    for (uint64_t i = 0; i < n; ++i) {
      const RowPoint rp = sampler.Primary(r0 + i);
      if (!rp.valid) continue;
      const glm::dvec3 t = RowTint(p.scene.materials[static_cast<size_t>(rp.material)], rp, lobe);
      for (int c = 0; c < 3; ++c) v[3 * i + c] = static_cast<float>(t[c]);
    }
    LTB_RETURN_IF_ERROR(p.geo.rays->error());
    LTB_RETURN_IF_ERROR(out.Put(static_cast<uint32_t>(a), chunk,
                                ByteSpan(reinterpret_cast<const std::byte*>(v.data()), v.size() * sizeof(float))));
  }
  return Status::Ok();
}

}  // namespace sample_internal

namespace {

// Row blocks with any of the first `arrays` arrays missing in any output (a shard: among the
// blocks it owns; the arrays share the row blocking, so they share the shard's chunk range).
std::vector<uint64_t> MissingBlocks(std::vector<io::ContainerWriter>& outs, uint32_t arrays) {
  std::vector<uint64_t> todo;
  for (io::ContainerWriter& out : outs) {
    for (uint32_t a = 0; a < arrays; ++a) {
      std::vector<uint64_t> m = out.Missing(a);
      todo.insert(todo.end(), m.begin(), m.end());
    }
  }
  std::sort(todo.begin(), todo.end());
  todo.erase(std::unique(todo.begin(), todo.end()), todo.end());
  return todo;
}

// One row block's output: the matrix, 4096-byte aligned so O_DIRECT writes it without a
// staging copy, and the side tables.
struct BlockBuffers {
  struct Free {
    void operator()(float* p) const { std::free(p); }
  };
  std::unique_ptr<float, Free> mat;
  uint64_t mat_floats = 0;   // allocated
  std::vector<float> extra;  // a factored bake's terms 1..K−1, one block after the other
  std::vector<float> pos, nor;
  std::vector<uint8_t> mask;
  // A converged bake's side tables: highest level, rays and estimated relative error per row.
  std::vector<uint8_t> level;
  std::vector<uint64_t> rays;
  std::vector<float> error;
};

// Block buffers come back here once their chunks are written, so the next block reuses
// memory that is already mapped instead of faulting in fresh pages. Holds at most as many
// buffers as were in use at once (tracing threads + write queue).
class BufferPool {
 public:
  // A buffer for `rows` rows of `cols` values, returned to the pool when the last
  // shared_ptr to it goes. nullptr when memory runs out.
  std::shared_ptr<BlockBuffers> Get(uint64_t rows, uint64_t cols, uint64_t extra_terms) {
    std::unique_ptr<BlockBuffers> b;
    {
      std::lock_guard<std::mutex> lock(mu_);
      if (!free_.empty()) {
        b = std::move(free_.back());
        free_.pop_back();
      }
    }
    if (!b) b = std::make_unique<BlockBuffers>();
    const uint64_t floats = rows * cols;
    if (b->mat_floats < floats) {
      const uint64_t bytes = (floats * sizeof(float) + kDirectAlign - 1) / kDirectAlign * kDirectAlign;
      b->mat.reset(static_cast<float*>(std::aligned_alloc(kDirectAlign, bytes)));
      if (!b->mat) return nullptr;
      b->mat_floats = floats;
    }
    b->extra.assign(extra_terms * rows * cols, 0.0f);
    b->pos.assign(rows * 3, 0.0f);
    b->nor.assign(rows * 3, 0.0f);
    b->mask.assign(rows, 0);
    b->level.assign(rows, 0);
    b->rays.assign(rows, 0);
    b->error.assign(rows, 0.0f);
    return std::shared_ptr<BlockBuffers>(b.release(), [this](BlockBuffers* p) {
      std::lock_guard<std::mutex> lock(mu_);
      free_.emplace_back(p);
    });
  }

 private:
  static constexpr uint64_t kDirectAlign = 4096;
  std::mutex mu_;
  std::vector<std::unique_ptr<BlockBuffers>> free_;
};

// A factored bake's factors (docs/GLOSSY.md): per material of a vertex row, its BRDF's
// factorisation (glossy materials only) and the incident tables f_1..f_{K−1} the sampler
// reads (empty for a diffuse material: its terms 1..K−1 are 0).
struct FactorPlan {
  uint32_t terms = 0;
  std::vector<brdf::BrdfFactors> factors;
  std::vector<std::vector<const brdf::ParabolicTable*>> tables;
  std::vector<std::pair<std::string, std::vector<double>>> errors;
};

Result<FactorPlan> PlanFactors(const SampleOptions& o, const Prepared& p, uint32_t terms) {
  FactorPlan plan;
  plan.terms = terms;
  const auto& mats = p.scene.materials;
  std::vector<bool> used(mats.size(), false);
  for (const RowPoint& rp : p.geo.vertex_rows) used[static_cast<size_t>(rp.material)] = true;
  plan.factors.resize(mats.size());
  for (size_t m = 0; m < mats.size(); ++m) {
    if (!used[m] || !(mats[m].ks > 0) || terms < 2) continue;
    if (mats[m].brdf != "phong") {
      return InvalidArgument(p.scene.path + ": material \"" + mats[m].name + "\" has brdf \"" + mats[m].brdf +
                             "\"; sample --factor factors the Phong lobe only (the triple-product path renders the "
                             "others: docs/TRIPLE.md)");
    }
    LTB_ASSIGN_OR_RETURN(plan.factors[m], brdf::FactorPhong(mats[m].albedo, mats[m].ks, mats[m].exponent, terms,
                                                            o.factor_incident_res, o.factor_view_res));
    plan.errors.emplace_back(mats[m].name, plan.factors[m].error);
  }
  plan.tables.resize(mats.size());
  for (size_t m = 0; m < mats.size(); ++m) {
    for (size_t k = 1; k < plan.factors[m].f.size(); ++k) plan.tables[m].push_back(&plan.factors[m].f[k]);
  }
  return plan;
}

// Output k of a factored bake: which term it is ("channel" k<k> of the set, docs/COLOUR.md
// "A set through the stages"), every material's view factors g_0..g_{K−1} (float32 tables
// over the parabolic view map, base64) and errors, and where the renderer finds the
// geometry (relight --eye).
void AddFactorMetadata(const SampleOptions& o, const Prepared& p, const FactorPlan& plan, uint32_t k,
                       nlohmann::json* meta) {
  nlohmann::json names = nlohmann::json::array();
  for (uint32_t i = 0; i < plan.terms; ++i) names.push_back("k" + std::to_string(i));
  const nlohmann::json term = {{"name", "k" + std::to_string(k)}, {"index", k}, {"names", names}, {"factor", k}};
  // A colour factored bake's file is colour channel c of the set X.k<k>.ltm, itself term k
  // of the set X.ltm ("term"); a monochrome one's is term k of X.ltm ("channel").
  (*meta)[p.rgb_factor ? "term" : "channel"] = term;
  nlohmann::json materials = nlohmann::json::array();
  uint32_t view_res = 0;
  for (size_t m = 0; m < p.scene.materials.size(); ++m) {
    const sample::Material& mat = p.scene.materials[m];
    const brdf::BrdfFactors& f = plan.factors[m];
    nlohmann::json j = {{"name", mat.name},
                        {"albedo", mat.albedo},
                        {"ks", mat.ks},
                        {"exponent", mat.exponent},
                        {"glossy", !f.g.empty()}};
    if (!f.g.empty()) {
      view_res = f.g.front().res;
      nlohmann::json g = nlohmann::json::array();
      for (const brdf::ParabolicTable& t : f.g) g.push_back(FloatsToBase64(t.value));
      j["g"] = g;
      j["error"] = f.error;
    }
    materials.push_back(j);
  }
  (*meta)["factor"] = {{"terms", plan.terms}, {"view_res", view_res}, {"incident_res", o.factor_incident_res},
                       {"map", "parabolic"},  {"frame", "duff2017"},  {"materials", materials}};
  (*meta)["geometry"] = {{"scene", std::filesystem::absolute(o.scene).lexically_normal().string()},
                         {"scene_hash", p.geo.scene_hash},
                         {"geometry_hash", p.geo.geometry_hash}};
  (*meta)["provenance"]["parameters"]["factor"] = plan.terms;
  (*meta)["provenance"]["parameters"]["factor_grid"] = {o.factor_incident_res, o.factor_view_res};
}

// Converged sampling: the samplers of levels 1..max_levels−1, level k with spp·2^k rays a
// texel and its own seed (level 0 is the bake's own sampler); none without --tolerance.
std::vector<std::unique_ptr<Sampler>> LevelSamplers(const SampleOptions& o, const Prepared& p) {
  std::vector<std::unique_ptr<Sampler>> out;
  for (uint32_t k = 1; o.tolerance && k < o.max_levels; ++k) {
    out.push_back(std::make_unique<Sampler>(p.scene, p.geo, p.r, p.spp << k, p.bounces, sample::LevelSeed(p.seed, k)));
  }
  return out;
}

// The arrays BlockSampler writes per block: the four every sample output has and the side
// tables AddRowStatsMetadata adds.
constexpr uint32_t BlockArrays(bool converged) { return converged ? 7 : 5; }

// The side tables after the four every sample output has: the rays traced per row
// (sample_rays), and a converged bake's highest level and estimated error per row around it;
// with a converged bake's parameters.
void AddRowStatsMetadata(const SampleOptions& o, const Prepared& p, uint64_t block, nlohmann::json* meta) {
  const ArraySpec rays = sample_internal::RowArray("sample_rays", DType::kU64, p.rows, 1, block);
  if (!o.tolerance) {
    (*meta)["arrays"].push_back(rays.ToJson());
    return;
  }
  for (const ArraySpec& a : {sample_internal::RowArray("sample_level", DType::kU8, p.rows, 1, block), rays,
                             sample_internal::RowArray("sample_error", DType::kF32, p.rows, 1, block)}) {
    (*meta)["arrays"].push_back(a.ToJson());
  }
  (*meta)["provenance"]["parameters"]["tolerance"] = *o.tolerance;
  (*meta)["provenance"]["parameters"]["max_levels"] = o.max_levels;
}

// One output of a bake: term `term` (0 unless factored) of colour channel `channel` (−1:
// monochrome), from the block buffer's plane `plane` (0 the matrix buffer, p ≥ 1 extra
// plane p − 1). A colour factored bake's planes are 3·term + channel.
struct OutSlot {
  uint32_t term = 0;
  int channel = -1;
  uint32_t plane = 0;
};

// The block buffer's planes: a factored bake's terms (times 3 in colour), a colour set's
// channels, or the one matrix.
uint64_t Planes(const SampleOptions& o, const Prepared& p, const FactorPlan* plan) {
  if (plan) return uint64_t{plan->terms} * (p.rgb_factor ? 3 : 1);
  return o.rgb ? 3 : 1;
}

// Samples row blocks, one chunk of each array per block, from any number of threads, and
// hands the chunks to the writer thread; counts what it did. Progress in rays; the total
// is extrapolated from the rays per row that sees geometry so far, times the rows to do that
// see it (valid_todo, counted before: a row that sees only sky costs no rays, and an image's
// top rows often do, which made a count by rows promise a quarter of the time it took).
struct BlockSampler {
  const SampleOptions& o;
  const Prepared& p;
  const Sampler& sampler;
  // One output, or a set's members (slots[i] into outs[i]).
  std::vector<io::ContainerWriter>& outs;
  const std::vector<OutSlot>& slots;
  std::vector<std::unique_ptr<io::AsyncChunkWriter>>& writers;
  const FactorPlan* plan;
  BufferPool& pool;
  const Progress& progress;
  uint64_t block, rows_todo;
  // Converged sampling (--tolerance): one sampler per level (empty: one Transport per row),
  // the pilot's λ and RMS row norm N (stages/sample/converged.h).
  std::vector<const sample::Sampler*> levels;
  sample::Pilot pilot;
  Counters cnt;
  uint64_t valid_todo = 0;  // rows of the blocks to do that see geometry
  std::atomic<uint64_t> valid{0}, written{0}, rows_done{0};
  std::mutex converged_mu;
  std::vector<uint64_t> level_histogram;  // under converged_mu
  double max_rel_error = 0;               // under converged_mu

  Status Run(uint64_t chunk) {
    const uint64_t rows = p.rows, cols = 6ull * p.r * p.r;
    uint64_t r0 = chunk * block, n = std::min(block, rows - r0);
    thread_local RowScratch sc;
    const uint64_t extra_terms = Planes(o, p, plan) - 1;
    std::shared_ptr<BlockBuffers> buf = pool.Get(n, cols, extra_terms);
    if (!buf) {
      return Internal("out of memory for a block of " + std::to_string(n) + " rows x " + std::to_string(cols) +
                      " values");
    }
    float* mat = buf->mat.get();
    float* pos = buf->pos.data();
    float* nor = buf->nor.data();
    for (uint64_t i = 0; i < n; ++i) {
      if (progress.Cancelled()) return Cancelled("interrupted; committed chunks are kept, rerun to resume");
      uint64_t done_rows = rows_done.fetch_add(1) + 1;
      RowPoint rp = sampler.Primary(r0 + i);
      if (!rp.valid) {  // sees no geometry: an all-zero row, mask 0
        std::fill_n(mat + i * cols, cols, 0.0f);
        continue;
      }
      buf->mask[i] = 1;
      valid++;
      for (int k = 0; k < 3; ++k) {
        pos[3 * i + k] = static_cast<float>(rp.p[k]);
        nor[3 * i + k] = static_cast<float>(rp.n[k]);
      }
      const std::vector<const ParabolicTable*>* f = plan ? &plan->tables[static_cast<size_t>(rp.material)] : nullptr;
      Counters row_cnt;  // this row's, for its sample_rays entry (then added to the bake's)
      // Row i of every plane of the block (OutSlot): the matrix buffer, then the extra planes.
      thread_local std::vector<float*> planes;
      planes.assign(1, mat + i * cols);
      for (uint64_t k = 0; k < extra_terms; ++k) planes.push_back(buf->extra.data() + (k * n + i) * cols);
      const bool glossy_factored = f != nullptr && !f->empty();
      if (glossy_factored) {  // a glossy material of a factored bake: every term (and channel) from one set of rays
        sampler.TransportFactored(r0 + i, rp, *f, planes.data(), sc, row_cnt, p.rgb_factor);
      } else if (o.rgb || p.rgb_factor) {  // the three channels from one set of rays (a factored bake's term 0)
        sampler.TransportChannels(r0 + i, rp, planes.data(), sc, row_cnt);
      } else if (!levels.empty()) {  // converged sampling: each texel to the level its error needs
        thread_local sample::ConvergedScratch cs;
        const sample::ConvergedRow cr = sample::TraceConverged(levels, r0 + i, rp, pilot, mat + i * cols, sc, cs);
        buf->level[i] = static_cast<uint8_t>(cr.level);
        buf->error[i] = static_cast<float>(cr.rel_error);
        row_cnt.rays += cr.rays;
      } else {  // terms 1..K−1 of a diffuse material are 0 (the buffers start at 0)
        sampler.Transport(r0 + i, rp, mat + i * cols, sc, row_cnt);
      }
      buf->rays[i] = row_cnt.rays.load();
      cnt.rays += row_cnt.rays.load();
      cnt.below += row_cnt.below.load();
      cnt.samples_below += row_cnt.samples_below.load();
      const uint64_t rays = cnt.rays.load(), valid_done = valid.load();
      const uint64_t estimate =
          std::max(rays, static_cast<uint64_t>(static_cast<double>(rays) /
                                               static_cast<double>(std::max<uint64_t>(valid_done, 1)) *
                                               static_cast<double>(valid_todo)));
      progress.Report(rays, done_rows >= rows_todo ? rays : estimate, "rays");
    }
    LTB_RETURN_IF_ERROR(p.geo.rays->error());
    EncodeOptions matrix_encoding;
    if (o.row_filter) {  // fused row-transform: exactly what RunRowTransform does to this block
      thread_local std::vector<float> scratch;
      scratch.resize(RowBlockScratchSize(p.r));
      uint64_t zero_rows = 0;
      TransformRowBlock(*o.row_filter, p.r, mat, n, scratch.data(), &zero_rows);
      for (uint64_t k = 0; k < extra_terms; ++k) {
        TransformRowBlock(*o.row_filter, p.r, buf->extra.data() + k * n * cols, n, scratch.data(), &zero_rows);
      }
      matrix_encoding.zstd = o.row_zstd;
    }
    if (o.visibility) {  // each row's V, Haar-transformed per face; stored sparse
      wavelet::HaarRowsInPlace(mat, n, p.r);
      matrix_encoding.sparse = true;
      matrix_encoding.zstd = true;
    }
    auto bytes = [](const auto* v, uint64_t count) {
      return ByteSpan(reinterpret_cast<const std::byte*>(v), count * sizeof(v[0]));
    };
    if (!levels.empty()) {
      std::lock_guard<std::mutex> lock(converged_mu);
      for (uint64_t i = 0; i < n; ++i) {
        if (buf->mask[i] == 0) continue;  // no geometry
        level_histogram.resize(std::max<size_t>(level_histogram.size(), buf->level[i] + 1u), 0);
        level_histogram[buf->level[i]]++;
        max_rel_error = std::max(max_rel_error, static_cast<double>(buf->error[i]));
      }
    }
    // In AddRowStatsMetadata's order: the four every output has, then sample_rays, or a
    // converged bake's sample_level, sample_rays, sample_error.
    const uint32_t arrays = BlockArrays(!levels.empty());
    for (size_t k = 0; k < outs.size(); ++k) {
      const uint32_t plane = slots[k].plane;
      const float* m = plane == 0 ? mat : buf->extra.data() + (plane - 1) * n * cols;
      const ByteSpan converged[7] = {
          bytes(m, n * cols),          bytes(buf->mask.data(), n), bytes(pos, n * 3),          bytes(nor, n * 3),
          bytes(buf->level.data(), n), bytes(buf->rays.data(), n), bytes(buf->error.data(), n)};
      const ByteSpan full[5] = {converged[0], converged[1], converged[2], converged[3], converged[5]};
      const ByteSpan* parts = levels.empty() ? full : converged;
      for (uint32_t a = 0; a < arrays; ++a) {
        if (outs[k].Has(a, chunk)) continue;
        // The writer thread encodes and writes; buf goes back to the pool after the last part.
        LTB_RETURN_IF_ERROR(writers[k]->Submit(a, chunk, parts[a], buf, a == 0 ? matrix_encoding : EncodeOptions{}));
        written++;
      }
    }
    return Status::Ok();
  }
};

// Converged sampling's pilot (stages/sample/converged.h): λ and the RMS row norm for the
// tracing threads; its rays count as the bake's.
void RunPilot(const SampleOptions& o, const Sampler& sampler, uint64_t rows, BlockSampler* bs, SampleResult* result) {
  bs->pilot = sample::PilotRows(sampler, rows, o.max_levels, *o.tolerance);
  bs->cnt.rays += bs->pilot.rays;
  result->pilot_rows = bs->pilot.rows;
  result->pilot_rms_norm = std::sqrt(bs->pilot.mean_norm2);
  result->tolerance_reachable = bs->pilot.reachable;
  result->least_error = bs->pilot.least_error;
}

// Per row block of `blocks` (the others 0), its rows that see geometry (one primary ray
// each): what the progress's estimate of the rays still to trace scales by, and what a
// sharded bake balances its shards by.
Result<std::vector<uint64_t>> GeometryRowsPerBlock(const Sampler& sampler, const std::vector<uint64_t>& blocks,
                                                   uint64_t block, uint64_t rows, int jobs, const Progress& progress) {
  std::vector<uint64_t> n((rows + block - 1) / block, 0);
  LTB_RETURN_IF_ERROR(ParallelFor(blocks, jobs, Progress{.update = nullptr, .cancelled = progress.cancelled}, "chunks",
                                  [&](uint64_t chunk) -> Status {
                                    uint64_t valid = 0;
                                    for (uint64_t r = chunk * block; r < std::min(rows, (chunk + 1) * block); ++r)
                                      valid += sampler.Primary(r).valid;
                                    n[chunk] = valid;  // each chunk once: no race
                                    return Status::Ok();
                                  }));
  return n;
}

// A sharded bake's row blocks split so that each shard gets about the same rows that see
// geometry (a row that sees only sky costs no rays: contiguous equal block counts gave the
// shard with the image's top 2.9 s and the other 8.6 s, bench/results/cluster_model_check.md).
// Every shard computes the same bounds from every block's geometry rows (one primary ray a
// row, deterministic), weighting each block by them plus one, so an empty image still splits
// by blocks.
std::vector<uint64_t> BalancedShardBounds(const std::vector<uint64_t>& geometry_rows, uint64_t count) {
  const uint64_t blocks = geometry_rows.size();
  std::vector<uint64_t> bounds(count + 1, blocks);
  bounds[0] = 0;
  uint64_t total = 0;
  for (uint64_t g : geometry_rows) total += g + 1;
  unsigned __int128 cum = 0;
  uint64_t b = 0;
  for (uint64_t k = 1; k < count; ++k) {  // the first block at which k/count of the weight is done
    while (b < blocks && cum * count < static_cast<unsigned __int128>(k) * total) cum += geometry_rows[b++] + 1;
    bounds[k] = b;
  }
  return bounds;
}

// The bake's outputs: every term (and channel) of the set, or with --factor-term t only term t
// (recipes), with --channel c only channel c.
Result<std::vector<OutSlot>> OutputSlots(const SampleOptions& o, const Prepared& p, const FactorPlan* plan) {
  if (o.factor_term && (!plan || *o.factor_term >= plan->terms)) {
    return InvalidArgument("--factor-term " + std::to_string(*o.factor_term) + " needs --factor K with K > it");
  }
  std::vector<OutSlot> slots;
  const uint32_t terms = plan ? plan->terms : 1;
  for (uint32_t k = o.factor_term.value_or(0); k < (o.factor_term ? *o.factor_term + 1 : terms); ++k) {
    if (!o.rgb && !p.rgb_factor) {
      slots.push_back({k, o.channel, k});
      continue;
    }
    for (int c = 0; c < 3; ++c) {
      if (o.channel < 0 || o.channel == c) slots.push_back({k, c, static_cast<uint32_t>(3 * k + c)});
    }
  }
  return slots;
}

// The full bake's outputs (one, a channel set's or a factored bake's terms), opened or resumed;
// chose_full: --sparse auto's decision for the full bake, recorded in the provenance.
Result<std::vector<io::ContainerWriter>> OpenOutputs(const SampleOptions& o, const Prepared& prep,
                                                     const FactorPlan* plan, const std::vector<OutSlot>& slots,
                                                     uint64_t block, const std::optional<SparseAuto>& chose_full,
                                                     const io::ShardSpec& shard) {
  io::WriterOptions wo;
  wo.overwrite_mismatch = o.overwrite;
  wo.direct_io = o.direct_io;
  std::vector<io::ContainerWriter> outs;
  for (const OutSlot& slot : slots) {
    SampleOptions ok = o;  // --channels rgb: output c is exactly what --channel c writes
    ok.channel = slot.channel;
    nlohmann::json meta = sample_internal::SampleMetadata(ok, prep, block);
    AddRowStatsMetadata(o, prep, block, &meta);
    sample_internal::AddReflectance(prep, block, &meta);
    if (plan) AddFactorMetadata(o, prep, *plan, slot.term, &meta);
    if (chose_full) {
      meta["provenance"]["parameters"]["sparse_auto"] = sample_internal::sparse_bake::SparseAutoJson(*chose_full);
    }
    std::string path = o.output;  // --factor-term and --channel name one member: OUT as given
    if (plan && !o.factor_term) path = FactorPath(path, slot.term);
    if (o.rgb) path = ChannelPath(path, slot.channel);
    LTB_ASSIGN_OR_RETURN(io::ContainerWriter out, io::OpenStageOutput(path, meta, wo, shard));
    outs.push_back(std::move(out));
  }
  return outs;
}

}  // namespace

Result<SampleResult> RunSample(const SampleOptions& o, const Progress& progress) {
  auto t0 = std::chrono::steady_clock::now();
  LTB_ASSIGN_OR_RETURN(std::unique_ptr<Prepared> prep, sample_internal::Prepare(o, progress));
  std::optional<SparseAuto> chose_full;  // --sparse auto picked the full bake
  if (o.sparse.enabled) {
    SparseAuto full;
    LTB_ASSIGN_OR_RETURN(std::optional<SampleResult> sr, sample_internal::RunSparseSample(o, *prep, progress, &full));
    if (sr) {
      sr->seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
      return *sr;
    }
    chose_full = full;
  }
  const Geometry& geo = prep->geo;
  const uint32_t r = prep->r;
  const uint64_t rows = prep->rows;
  const uint64_t block = sample_internal::BlockRows(o, rows, 6ull * r * r);
  // A factored bake (--factor K): K outputs OUT.k0.ltm ... from one pass (docs/GLOSSY.md).
  std::optional<FactorPlan> plan;
  if (o.factor > 0) {
    LTB_ASSIGN_OR_RETURN(FactorPlan p, PlanFactors(o, *prep, o.factor));
    plan = std::move(p);
  }
  LTB_ASSIGN_OR_RETURN(const std::vector<OutSlot> slots, OutputSlots(o, *prep, plan ? &*plan : nullptr));
  const uint32_t outputs = static_cast<uint32_t>(slots.size());
  Sampler sampler(prep->scene, geo, r, prep->spp, prep->bounces, prep->seed);
  sampler.SetVisibility(o.visibility);
  io::ShardSpec shard = o.shard;
  std::vector<uint64_t> geometry_rows;  // per block; a sharded bake counts every block's once
  if (shard.sharded()) {
    std::vector<uint64_t> all((rows + block - 1) / block);
    for (uint64_t b = 0; b < all.size(); ++b) all[b] = b;
    LTB_ASSIGN_OR_RETURN(geometry_rows, GeometryRowsPerBlock(sampler, all, block, rows, o.jobs, progress));
    shard.bounds = BalancedShardBounds(geometry_rows, shard.count);
  }
  LTB_ASSIGN_OR_RETURN(std::vector<io::ContainerWriter> outs,
                       OpenOutputs(o, *prep, plan ? &*plan : nullptr, slots, block, chose_full, shard));

  SampleResult result;
  result.rows = rows;
  result.cube_res = r;
  result.spp = prep->spp;
  result.bounces = prep->bounces;
  result.degenerate_triangles = geo.degenerate;
  if (plan) result.factor_errors = plan->errors;
  result.sparse_auto = chose_full;
  const uint64_t nchunks = (rows + block - 1) / block;
  const uint32_t block_arrays = BlockArrays(o.tolerance.has_value());
  result.chunks_total = nchunks * block_arrays * outputs;
  for (const io::ContainerWriter& out : outs) result.chunks_already_committed += out.resume_info().committed_chunks;

  const std::vector<uint64_t> todo = MissingBlocks(outs, block_arrays);
  std::vector<std::unique_ptr<Sampler>> level_samplers = LevelSamplers(o, *prep);
  std::vector<const Sampler*> levels;
  if (o.tolerance) levels.push_back(&sampler);
  for (const auto& ls : level_samplers) levels.push_back(ls.get());
  // The tracing threads hand their chunks to one writer thread per output through a
  // bounded queue (a quarter of --mem-limit, at most kMaxWriteQueueBytes, shared by the
  // outputs); the pool outlives the writers, which return the buffers to it.
  BufferPool pool;
  const uint64_t queue_bytes =
      (o.mem_limit > 0 ? std::min(o.mem_limit / 4, kMaxWriteQueueBytes) : kMaxWriteQueueBytes) / outputs;
  std::vector<std::unique_ptr<io::AsyncChunkWriter>> writers;
  for (io::ContainerWriter& out : outs) writers.push_back(std::make_unique<io::AsyncChunkWriter>(out, queue_bytes));
  BlockSampler bs{o,
                  *prep,
                  sampler,
                  outs,
                  slots,
                  writers,
                  plan ? &*plan : nullptr,
                  pool,
                  progress,
                  block,
                  std::min(rows, todo.size() * block),
                  levels};
  if (geometry_rows.empty()) {
    LTB_ASSIGN_OR_RETURN(geometry_rows, GeometryRowsPerBlock(sampler, todo, block, rows, o.jobs, progress));
  }
  for (uint64_t b : todo) bs.valid_todo += geometry_rows[b];
  if (o.tolerance) RunPilot(o, sampler, rows, &bs, &result);
  Status s = ParallelFor(todo, o.jobs, Progress{.update = nullptr, .cancelled = progress.cancelled}, "chunks",
                         [&](uint64_t chunk) -> Status { return bs.Run(chunk); });
  // Also after a failure or an interrupt: the chunks already queued are written and commit.
  for (auto& w : writers) {
    Status closed = w->Close();
    if (s.ok()) s = closed;
    result.write_queue_bytes += w->capacity_bytes();
    result.write_queue_waits += w->submit_waits();
  }
  for (io::ContainerWriter& out : outs) {
    const io::DirectIoStats ds = out.direct_io_stats();
    result.bytes_direct += ds.direct_bytes;
    if (result.direct_fallback.empty()) result.direct_fallback = ds.fallback_reason;
  }
  result.chunks_written = bs.written;
  result.rays = bs.cnt.rays;
  result.texels_below_horizon = bs.cnt.below;
  result.samples_below_horizon = bs.cnt.samples_below;
  result.valid_rows = bs.valid;
  result.level_histogram = bs.level_histogram;
  result.max_rel_error = bs.max_rel_error;
  LTB_RETURN_IF_ERROR(s);
  for (size_t i = 0; i < outs.size(); ++i) {
    const bool lobe = plan && slots[i].term > 0;  // a glossy term of a factored bake
    LTB_RETURN_IF_ERROR(sample_internal::WriteReflectance(*prep, sampler, block, outs[i], lobe, progress));
    LTB_RETURN_IF_ERROR(outs[i].Finish());
  }
  result.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return result;
}

}  // namespace ltb::stages
