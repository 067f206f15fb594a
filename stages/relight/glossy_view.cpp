#include "stages/relight/glossy_view.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <glm/geometric.hpp>
#include <glm/trigonometric.hpp>
#include <numbers>
#include <optional>

#include "format/io/container_reader.h"
#include "stages/brdf/brdf_factor.h"
#include "stages/common/base64.h"
#include "stages/common/channels.h"
#include "stages/common/parallel_for.h"
#include "stages/images/environment.h"
#include "stages/images/image_io.h"
#include "stages/relight/relight_matrix.h"
#include "stages/sample/camera.h"
#include "stages/sample/scene.h"
#include "stages/sample/scene_geometry.h"

namespace ltb::stages {
namespace {

using Clock = std::chrono::steady_clock;
double Ms(Clock::time_point a, Clock::time_point b) { return std::chrono::duration<double, std::milli>(b - a).count(); }

// Per material, its view factors g_0..g_{K−1} (empty: a diffuse material, g_0 = 1, the
// rest 0), from the first term's metadata; a plain vertex bake has one term and no tables.
struct ViewFactors {
  uint32_t terms = 0;
  bool factored = true;
  std::vector<std::vector<brdf::ParabolicTable>> g;
  std::string scene, geometry_hash;
};

// `tables`: decode the view tables too (the other terms' files are only checked against the first's).
Result<ViewFactors> ReadViewFactors(const std::string& path, bool tables) {
  LTB_ASSIGN_OR_RETURN(io::ContainerReader r, io::ContainerReader::Open(path));
  const nlohmann::json& j = r.metadata().json;
  ViewFactors v;
  try {
    if (!j.contains("factor")) {  // a plain vertex bake: diffuse, its radiance the same from any eye
      if (j.at("basis").at("rows").at("kind").get<std::string>() != "vertices") {
        return InvalidArgument(path +
                               ": its rows are pixels of a fixed camera, not vertices: leave out --eye (relight) "
                               "or the eye's parameters (view); for the triple-product path add --material "
                               "(docs/GLOSSY.md)");
      }
      v.terms = 1;
      v.factored = false;
      if (!j.contains("geometry")) {
        return InvalidArgument(path +
                               ": does not say where its mesh is (no \"geometry\" in its metadata): an image bake, or "
                               "a vertex bake older than this ltbake (bake it again to see it from an eye)");
      }
      v.scene = j.at("geometry").at("scene").get<std::string>();
      v.geometry_hash = j.at("geometry").at("geometry_hash").get<std::string>();
      return v;
    }
    const auto& f = j.at("factor");
    v.terms = f.at("terms").get<uint32_t>();
    const uint32_t res = f.at("view_res").get<uint32_t>();
    if (f.at("map").get<std::string>() != "parabolic" || f.at("frame").get<std::string>() != "duff2017") {
      return InvalidArgument(path + ": factors on a \"" + f.at("map").get<std::string>() + "\" map in a \"" +
                             f.at("frame").get<std::string>() + "\" frame, which this renderer does not read");
    }
    for (const auto& m : f.at("materials")) {
      std::vector<brdf::ParabolicTable> g;
      if (tables && m.at("glossy").get<bool>()) {
        for (const auto& text : m.at("g")) {
          LTB_ASSIGN_OR_RETURN(std::vector<float> t, FloatsFromBase64(text.get<std::string>()));
          if (res == 0 || res > 1024 || t.size() != uint64_t{res} * res) {
            return DataLoss(path + ": material \"" + m.at("name").get<std::string>() + "\" has a view table of " +
                            std::to_string(t.size()) + " values, not " + std::to_string(res) + "²");
          }
          g.push_back({res, std::move(t)});
        }
        if (g.size() != v.terms) {
          return DataLoss(path + ": material \"" + m.at("name").get<std::string>() + "\" has " +
                          std::to_string(g.size()) + " view tables for " + std::to_string(v.terms) + " terms");
        }
      }
      v.g.push_back(std::move(g));
    }
    v.scene = j.at("geometry").at("scene").get<std::string>();
    v.geometry_hash = j.at("geometry").at("geometry_hash").get<std::string>();
  } catch (const nlohmann::json::exception& e) {
    return InvalidArgument(path + ": not a term of a factored bake (sample --factor K): " + e.what());
  }
  return v;
}

// B per vertex (rows × 3) for one eye: Σ_k g_k(ω_o local)·P_k.
void VertexRadiance(const sample::Geometry& geo, const std::vector<std::vector<brdf::ParabolicTable>>& view_factors,
                    const std::vector<std::vector<float>>& p, uint32_t used, const glm::dvec3& eye, int jobs,
                    std::vector<float>* b) {
  const uint64_t rows = geo.vertex_rows.size();
  b->assign(rows * 3, 0.0f);
  std::vector<uint64_t> blocks;
  for (uint64_t r0 = 0; r0 < rows; r0 += 4096) blocks.push_back(r0);
  (void)ParallelFor(blocks, jobs, Progress{}, "vertices", [&](uint64_t r0) -> Status {
    for (uint64_t i = r0; i < std::min(rows, r0 + 4096); ++i) {
      const sample::RowPoint& rp = geo.vertex_rows[i];
      const auto& g = view_factors[static_cast<size_t>(rp.material)];
      float* out = b->data() + 3 * i;
      for (int c = 0; c < 3; ++c) out[c] = p[0][3 * i + c];  // g_0 = 1 (the diffuse term)
      if (g.empty()) continue;
      glm::dvec3 t, bt;
      brdf::TangentFrame(rp.n, &t, &bt);
      const glm::dvec3 wo = eye - rp.p;
      const brdf::ParabolicCoords pc(g.front().res, glm::dvec3(glm::dot(t, wo), glm::dot(bt, wo), glm::dot(rp.n, wo)));
      for (uint32_t k = 1; k < used; ++k) {
        const double gk = g[k].At(pc);
        for (int c = 0; c < 3; ++c) out[c] += static_cast<float>(gk * p[k][3 * i + c]);
      }
    }
    return Status::Ok();
  });
}

// The factored set's first term's factors, checked against the set: K members k0..k(K-1), all
// of one bake (same term count and geometry).
Result<ViewFactors> ReadFactorSet(const std::string& set, const std::vector<SetMember>& members) {
  if (members.empty() || members.front().name != "k0") {  // one vertex bake (a file, or a colour set)
    LTB_ASSIGN_OR_RETURN(ViewFactors vf, ReadViewFactors(members.empty() ? set : members.front().path, true));
    if (!vf.factored) return vf;
    return InvalidArgument(set +
                           ": a term of a factored bake; give the set's name (X.ltm for X.k0.ltm, X.k1.ltm, ...)");
  }
  // A colour factored bake's term is a colour set: its factors are in each channel's file.
  LTB_ASSIGN_OR_RETURN(ViewFactors vf, ReadViewFactors(SetLeaf(members.front().path), true));
  if (vf.terms != members.size()) {
    return InvalidArgument(members.front().path + ": says " + std::to_string(vf.terms) + " terms but the set has " +
                           std::to_string(members.size()));
  }
  for (size_t k = 1; k < members.size(); ++k) {  // every term from the same bake
    LTB_ASSIGN_OR_RETURN(ViewFactors other, ReadViewFactors(SetLeaf(members[k].path), false));
    if (other.terms != vf.terms || other.geometry_hash != vf.geometry_hash) {
      return InvalidArgument(members[k].path + ": is not a term of the same bake as " + members.front().path + " (" +
                             std::to_string(other.terms) + " vs " + std::to_string(vf.terms) +
                             " terms, or another geometry); rebake the set");
    }
  }
  return vf;
}

// B interpolated across each hit triangle of a row object; the rest is background.
void ShadeImage(const sample::Geometry& geo, const std::vector<sample::PixelHit>& hits, const std::vector<float>& b,
                std::vector<float>* image) {
  image->assign(hits.size() * 3, 0.0f);
  for (size_t px = 0; px < hits.size(); ++px) {
    const sample::PixelHit& h = hits[px];
    if (h.geom < 0 || static_cast<uint64_t>(h.geom) >= geo.row_meshes.size()) continue;
    const sample::Geometry::RowMesh& rm = geo.row_meshes[static_cast<size_t>(h.geom)];
    if (h.prim >= rm.triangles.size()) continue;  // not a row object
    const glm::uvec3& tri = rm.triangles[h.prim];
    const double w[3] = {1.0 - h.u - h.v, h.u, h.v};
    float* out = image->data() + px * 3;
    for (int v = 0; v < 3; ++v) {
      const float* bv = b.data() + 3 * (rm.first_row + tri[v]);
      for (int c = 0; c < 3; ++c) out[c] += static_cast<float>(w[v] * std::max(0.0f, bv[c]));
    }
  }
}

}  // namespace

Result<VertexRenderer> VertexRenderer::Open(const std::string& set, uint32_t use_terms, uint64_t mem_limit, int jobs,
                                            const Progress& progress) {
  LTB_ASSIGN_OR_RETURN(std::vector<SetMember> members, ChannelFiles(set));
  LTB_ASSIGN_OR_RETURN(ViewFactors vf, ReadFactorSet(set, members));
  const uint32_t used = use_terms == 0 ? vf.terms : std::min(use_terms, vf.terms);
  // The geometry the bake saw (its rows, normals and materials) for the primary rays.
  LTB_ASSIGN_OR_RETURN(sample::SceneDesc scene, sample::ParseScene(vf.scene));
  VertexRenderer v;
  LTB_ASSIGN_OR_RETURN(v.geo_, sample::BuildGeometry(scene, progress));
  const std::string first = vf.factored ? members.front().path : set;
  if (v.geo_.geometry_hash != vf.geometry_hash) {
    return FailedPrecondition(vf.scene + ": its geometry changed since " + first + " was baked (geometry hash " +
                              v.geo_.geometry_hash + ", baked " + vf.geometry_hash + "); bake again");
  }
  if (!vf.factored) vf.g.assign(scene.materials.size(), {});  // every material diffuse
  if (vf.g.size() != scene.materials.size()) {
    return FailedPrecondition(vf.scene + ": has " + std::to_string(scene.materials.size()) + " materials, the bake " +
                              std::to_string(vf.g.size()) + "; bake again");
  }
  v.g_ = std::move(vf.g);
  v.terms_in_bake_ = vf.terms;
  v.jobs_ = jobs;
  for (uint32_t k = 0; k < used; ++k) {
    const std::string& path = vf.factored ? members[k].path : set;
    LTB_ASSIGN_OR_RETURN(RelightMatrix m,
                         RelightMatrix::Open(path, mem_limit == 0 ? 0 : mem_limit / used, jobs, progress, nullptr));
    if (m.rows() != v.geo_.vertex_rows.size()) {
      return InvalidArgument(path + ": " + std::to_string(m.rows()) + " rows, but " + vf.scene + " has " +
                             std::to_string(v.geo_.vertex_rows.size()) + " vertex rows");
    }
    if (k > 0 && m.basis().cube_res() != v.m_.front().basis().cube_res()) {
      return InvalidArgument(path + ": a cubemap of " + std::to_string(m.basis().cube_res()) + "², " + first +
                             " one of " + std::to_string(v.m_.front().basis().cube_res()) + "²; bake the set again");
    }
    v.m_.push_back(std::move(m));
  }
  if (!v.geo_.vertex_rows.empty()) {
    v.low_ = v.high_ = v.geo_.vertex_rows.front().p;
    for (const sample::RowPoint& rp : v.geo_.vertex_rows) {
      v.low_ = glm::min(v.low_, rp.p);
      v.high_ = glm::max(v.high_, rp.p);
    }
  }
  return v;
}

Status VertexRenderer::Relight(const std::vector<float>& cube, uint64_t terms) {
  p_.resize(m_.size());
  for (size_t k = 0; k < m_.size(); ++k) {
    std::vector<float> lighting = cube;
    m_[k].basis().ToBasis(lighting.data());
    LightTerms t;
    LTB_RETURN_IF_ERROR(m_[k].basis().SelectTerms(lighting.data(), terms, Weighting::kArea, m_[k].column_norms(), &t));
    LTB_RETURN_IF_ERROR(m_[k].Relight(t, &p_[k]));
    if (k == 0) {
      double total = 0, kept = 0;
      for (float v : lighting) total += static_cast<double>(v) * v;
      for (float v : t.rgb) kept += static_cast<double>(v) * v;
      terms_available_ = lighting.size() / 3;
      energy_kept_ = total > 0 ? kept / total : 1.0;
      terms0_ = std::move(t);
    }
  }
  return Status::Ok();
}

Status VertexRenderer::Render(const glm::dvec3& eye, const sample::PinholeCamera& camera, int exponent,
                              const std::string& env, std::vector<float>* b, std::vector<float>* image) {
  if (p_.size() != m_.size()) return Internal("VertexRenderer::Render before Relight");
  VertexRadiance(geo_, g_, p_, terms_used(), eye, jobs_, b);
  ScaleByPowerOfTwo(b, exponent);
  LTB_RETURN_IF_ERROR(CheckRelitImageFinite(*b, 0, env));
  LTB_RETURN_IF_ERROR(sample::TracePixels(geo_, camera, jobs_, &hits_));
  ShadeImage(geo_, hits_, *b, image);
  return Status::Ok();
}

Result<GlossyViewResult> RunGlossyView(const GlossyViewOptions& o, const Progress& progress) {
  auto t0 = Clock::now();
  LTB_RETURN_IF_ERROR(sample::ValidateView(o.eye, o.target, o.up, o.fov_degrees)
                          .WithContext("the view (--eye, --target, --up, --fov)"));
  LTB_RETURN_IF_ERROR(sample::CheckViewMemory(o.width, o.height, o.mem_limit));
  LTB_ASSIGN_OR_RETURN(VertexRenderer v, VertexRenderer::Open(o.set, o.use_terms, o.mem_limit, o.jobs, progress));
  nlohmann::json report = {
      {"set", o.set}, {"env", o.env}, {"terms_in_bake", v.terms_in_bake()}, {"terms_used", v.terms_used()}};
  // P_k = T_k·L, once (the lighting does not change along an orbit).
  auto t1 = Clock::now();
  EnvLoadOptions eo;
  eo.layout = o.env_layout;
  eo.clamp = o.clamp_env;
  eo.max_bytes = o.mem_limit;
  eo.progress = progress;
  LTB_ASSIGN_OR_RETURN(Environment env, Environment::Open(o.env, v.basis().cube_res(), eo));
  if (env.clamped()) report["clamped_values"] = env.clamped();
  std::vector<float> cube;
  LTB_RETURN_IF_ERROR(env.Cubemap(o.rotate_deg * std::numbers::pi / 180.0, &cube));
  // A map near float32's largest value: P_k at 2^-k, B scaled back (and checked) by Render.
  const int exponent = LightingExponent(env.peak());
  ScaleByPowerOfTwo(&cube, -exponent);
  auto a = Clock::now();
  LTB_RETURN_IF_ERROR(v.Relight(cube, o.terms));
  report["load_ms"] = Ms(t0, t1);
  report["relight_ms"] = Ms(a, Clock::now());
  // What the lighting kept (term 0's selection; every term's is of the same map and basis).
  report["lighting_terms"] = {{"used", v.terms().column.size()},
                              {"available", v.terms_available()},
                              {"basis", v.basis().wavelet() ? "wavelet" : "pixels"},
                              {"energy_kept", v.energy_kept()}};
  // Views.
  const uint32_t frames = std::max<uint32_t>(1, o.orbit_frames);
  if (o.orbit_frames > 0 && !o.output.empty())
    LTB_RETURN_IF_ERROR(FramePath(o.output, 0, FramePattern::kOrbit).status());
  GlossyViewResult result;
  std::vector<float> b, image;
  std::vector<double> ms;
  for (uint32_t f = 0; f < frames; ++f) {
    if (progress.Cancelled()) return Cancelled("interrupted between frames; the frames written are kept");
    const glm::dvec3 eye = sample::OrbitEye(o.eye, o.target, o.orbit_deg, f);
    auto start = Clock::now();
    auto camera = sample::PinholeCamera::Create(eye, o.target, o.up, o.fov_degrees, o.width, o.height);
    if (!camera.ok()) {
      return camera.status().WithContext("the view (--eye, --target, --up, --fov), frame " + std::to_string(f));
    }
    LTB_RETURN_IF_ERROR(v.Render(eye, *camera, exponent, o.env, &b, &image).WithContext("frame " + std::to_string(f)));
    ms.push_back(Ms(start, Clock::now()));
    if (f == 0 && !o.vertex_output.empty()) {
      LTB_RETURN_IF_ERROR(WriteImage(o.vertex_output, b.data(), v.vertices(), 0, 0, {}));
    }
    if (!o.output.empty()) {
      std::string path = o.output;
      if (o.orbit_frames > 0) {
        LTB_ASSIGN_OR_RETURN(std::string frame_path, FramePath(o.output, f, FramePattern::kOrbit));
        path = frame_path;
      }
      LTB_RETURN_IF_ERROR(
          WriteImage(path, image.data(), uint64_t{o.width} * o.height, o.width, o.height, {.exposure = o.exposure}));
    }
    if (f == 0) result.image = image;
  }
  std::vector<double> sorted = ms;
  std::sort(sorted.begin(), sorted.end());
  const double median = sorted[sorted.size() / 2];
  report["frames"] = {{"count", frames}, {"median_ms", median}, {"fps", 1000.0 / median}, {"first_ms", ms.front()}};
  report["vertices"] = v.vertices();
  report["size"] = {o.width, o.height};
  result.report = std::move(report);
  return result;
}

}  // namespace ltb::stages
