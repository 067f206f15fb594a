#include "stages/triple/render.h"

#include <algorithm>
#include <atomic>
#include <bit>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <glm/geometric.hpp>
#include <glm/trigonometric.hpp>
#include <memory>
#include <numbers>
#include <numeric>

#include "format/bits.h"
#include "format/io/container_reader.h"
#include "stages/common/cubemap.h"
#include "stages/common/parallel_for.h"
#include "stages/images/environment.h"
#include "stages/images/image_io.h"
#include "stages/sample/ray_scene.h"
#include "stages/sample/scene.h"
#include "stages/sample/scene_geometry.h"
#include "stages/triple/haar_triple.h"
#include "stages/triple/material.h"
#include "stages/triple/material_field.h"
#include "stages/triple/shared_products.h"

namespace ltb::triple {

Result<TripleMethod> ParseTripleMethod(const std::string& name) {
  if (name == "linear") return TripleMethod::kLinear;
  if (name == "sublinear") return TripleMethod::kSublinear;
  if (name == "pixel") return TripleMethod::kPixel;
  if (name == "shared") return TripleMethod::kShared;
  return InvalidArgument("--method " + name + ": expected shared, sublinear, linear or pixel");
}

const char* TripleMethodName(TripleMethod m) {
  switch (m) {
    case TripleMethod::kLinear:
      return "linear";
    case TripleMethod::kSublinear:
      return "sublinear";
    case TripleMethod::kPixel:
      return "pixel";
    case TripleMethod::kShared:
      return "shared";
  }
  return "?";
}

namespace {

using Clock = std::chrono::steady_clock;
double Ms(Clock::time_point a, Clock::time_point b) { return std::chrono::duration<double, std::milli>(b - a).count(); }

// The glossy lobe of a scene material (its brdf, exponent, roughness, f0), ks = 1.
Brdf GlossyLobe(const sample::Material& m) {
  Brdf b;
  b.kind = m.brdf == "blinn"           ? Brdf::Kind::kBlinn
           : m.brdf == "ward"          ? Brdf::Kind::kWard
           : m.brdf == "cook-torrance" ? Brdf::Kind::kCookTorrance
                                       : Brdf::Kind::kPhong;
  b.albedo = m.ks;
  if (b.kind == Brdf::Kind::kPhong || b.kind == Brdf::Kind::kBlinn) b.exponent = m.exponent;
  if (b.kind == Brdf::Kind::kWard || b.kind == Brdf::Kind::kCookTorrance) b.roughness = m.roughness;
  if (b.kind == Brdf::Kind::kCookTorrance) b.f0 = m.f0;
  return b;
}

// The lighting of one frame in Haar (per channel, 6R² coefficients, face by face), its
// parent sums, and its N-term approximation: the wavelets kept, ascending.
struct Lighting {
  std::vector<double> c[3];     // exact
  std::vector<double> kept[3];  // the approximation (scaling coefficients always kept)
  std::vector<double> psum[3];  // of the exact coefficients, per face: 6 × squares
  std::vector<double> kept_psum[3];
  std::vector<uint32_t> terms;  // wavelet indices of the approximation, ascending
};

// The linear and shared methods also read the approximation's dense coefficients, the
// linear one their parent sums.
void MakeLighting(const std::vector<float>& cube, uint64_t res, uint64_t n_terms, TripleMethod method, Lighting* l) {
  const bool dense = method == TripleMethod::kLinear || method == TripleMethod::kShared;
  const uint64_t face = res * res, cols = 6 * face, squares = (face - 1) / 3;
  const int levels = std::countr_zero(res);
  std::vector<double> pixels(face), ps;
  for (int ch = 0; ch < 3; ++ch) {
    l->c[ch].assign(cols, 0.0);
    l->psum[ch].assign(6 * squares, 0.0);
    for (uint64_t f = 0; f < 6; ++f) {
      for (uint64_t p = 0; p < face; ++p) pixels[p] = cube[(f * face + p) * 3 + ch];
      const HaarFace h = HaarFace::Forward(pixels, res);
      std::copy(h.c.begin(), h.c.end(), l->c[ch].begin() + static_cast<std::ptrdiff_t>(f * face));
      ParentSums(h.c.data(), levels, &ps);
      std::copy(ps.begin(), ps.end(), l->psum[ch].begin() + static_cast<std::ptrdiff_t>(f * squares));
    }
  }
  // Rank wavelets by the magnitude of their luminance.
  std::vector<uint32_t> idx;
  std::vector<double> mag(cols, 0.0);
  for (uint64_t k = 0; k < cols; ++k) {
    mag[k] = std::fabs(0.2126 * l->c[0][k] + 0.7152 * l->c[1][k] + 0.0722 * l->c[2][k]) * L1Norm(k % face);
    if (k % face != 0 && (l->c[0][k] != 0 || l->c[1][k] != 0 || l->c[2][k] != 0))
      idx.push_back(static_cast<uint32_t>(k));
  }
  const uint64_t n = std::min<uint64_t>(n_terms, idx.size());
  std::partial_sort(idx.begin(), idx.begin() + static_cast<std::ptrdiff_t>(n), idx.end(),
                    [&](uint32_t a, uint32_t b) { return mag[a] != mag[b] ? mag[a] > mag[b] : a < b; });
  idx.resize(n);
  std::sort(idx.begin(), idx.end());
  l->terms = idx;
  for (int ch = 0; ch < 3 && dense; ++ch) {
    l->kept[ch].assign(cols, 0.0);
    for (uint64_t f = 0; f < 6; ++f) l->kept[ch][f * face] = l->c[ch][f * face];
    for (uint32_t k : idx) l->kept[ch][k] = l->c[ch][k];
    if (method != TripleMethod::kLinear) continue;
    l->kept_psum[ch].assign(6 * squares, 0.0);
    for (uint64_t f = 0; f < 6; ++f) {
      ParentSums(l->kept[ch].data() + f * face, levels, &ps);
      std::copy(ps.begin(), ps.end(), l->kept_psum[ch].begin() + static_cast<std::ptrdiff_t>(f * squares));
    }
  }
}

// The basis function of each coefficient of a face, tabulated.
struct FaceTable {
  uint64_t res = 0, face = 0, squares = 0;
  int levels = 0;
  std::vector<HaarBasis> basis;  // per coefficient index within a face
};

// Scratch of one thread: dense V and ρ with the coefficients touched, stamps for squares.
struct Scratch {
  std::vector<double> v, rho, pv, pr;  // 6R² dense; parent sums of one face (linear)
  // V for the sublinear method: a value and the stamp of the vertex that wrote it, so that
  // nothing needs clearing between vertices (an entry with an old stamp is a zero).
  struct Stamped {
    float value;
    uint32_t stamp;
  };
  std::vector<Stamped> vs;
  std::vector<uint32_t> rho_terms;
  std::vector<uint32_t> coef_stamp, square_stamp;
  // Lazy parent sums of V and ρ per square (psum_lazy, §5.3): valid where the stamp is current.
  std::vector<double> psum_v, psum_r;
  std::vector<uint32_t> psum_v_stamp, psum_r_stamp;
  uint32_t stamp = 0;
  std::vector<RhoPart> parts;
  void Size(uint64_t cols, uint64_t squares) {
    if (v.size() == cols) return;
    v.assign(cols, 0.0);
    vs.assign(cols, Stamped{0, 0});
    rho.assign(cols, 0.0);
    coef_stamp.assign(cols, 0);
    square_stamp.assign(6 * squares, 0);
    psum_v.assign(6 * squares, 0.0);
    psum_r.assign(6 * squares, 0.0);
    psum_v_stamp.assign(6 * squares, 0);
    psum_r_stamp.assign(6 * squares, 0);
    stamp = 0;
  }
  uint32_t NextStamp() {
    if (++stamp == 0) {  // wrapped: clear so no old mark matches
      for (auto* v : {&coef_stamp, &square_stamp, &psum_v_stamp, &psum_r_stamp}) std::fill(v->begin(), v->end(), 0);
      for (Stamped& e : vs) e = Stamped{0, 0};
      stamp = 1;
    }
    return stamp;
  }
};

// The parent sum of square (level, i, j) of face f of `coef` (6 faces of R² coefficients),
// memoised per square in `memo` where `memo_stamp` is `stamp`: a square's is its parent's
// plus 2^(level−1) × the parent's wavelets signed for its quadrant (ParentSums, on demand).
template <typename Coef>
double LazyParentSum(const Coef& coef, uint64_t face, uint64_t squares, uint64_t f, int level, uint64_t i, uint64_t j,
                     std::vector<double>& memo, std::vector<uint32_t>& memo_stamp, uint32_t stamp) {
  const uint64_t slot = f * squares + SquareIndex(level, i, j);
  if (memo_stamp[slot] == stamp) return memo[slot];
  double p = coef(f * face);
  if (level > 0) {
    const uint64_t w = f * face + 1 + 3 * SquareIndex(level - 1, i / 2, j / 2);
    const double sy = (j & 1) ? 1.0 : -1.0, sx = (i & 1) ? 1.0 : -1.0;
    p = LazyParentSum(coef, face, squares, f, level - 1, i / 2, j / 2, memo, memo_stamp, stamp) +
        static_cast<double>(uint64_t{1} << (level - 1)) * (sy * coef(w) + sx * coef(w + 1) + sx * sy * coef(w + 2));
  }
  memo[slot] = p;
  memo_stamp[slot] = stamp;
  return p;
}

// Case 2 of one square: three different types, weight 2^level.
inline double Case2(const double* r, const double* a, const double* b) {
  return r[0] * a[1] * b[2] + r[0] * a[2] * b[1] + r[1] * a[2] * b[0] + r[1] * a[0] * b[2] + r[2] * a[0] * b[1] +
         r[2] * a[1] * b[0];
}

struct Renderer {
  const RenderOptions& o;
  uint64_t res = 0;
  FaceTable ft;
  SparseRows vis;
  std::vector<MaterialField> fields;
  sample::SceneDesc scene;
  sample::Geometry geo;
  // Per scene material: its Lambert and glossy fields (nullptr when the part is zero).
  std::vector<const MaterialField*> lambert_of, glossy_of;
  std::unique_ptr<TexelTable> texel_table;  // centres and solid angles × R² (pixel method)
  std::unique_ptr<stages::Environment> env;
  Lighting light;
  std::vector<float> light_cube;   // 6R² × 3, the frame's radiance (pixel method)
  std::vector<float> light_lanes;  // the approximated lighting's texels × 2^-light_exponent, kLanes each
  int light_exponent = 0;          // (the shared method)

  // ρ̃ of vertex `row` seen from `eye`: the sampled rows of the fields, weighted.
  void RhoParts(uint64_t row, const glm::dvec3& eye, std::vector<RhoPart>* parts) const {
    parts->clear();
    const sample::RowPoint& rp = geo.vertex_rows[row];
    const sample::Material& m = scene.materials[rp.material];
    if (lambert_of[rp.material]) Interpolate(*lambert_of[rp.material], rp.n, rp.n, m.albedo, parts);
    if (glossy_of[rp.material]) Interpolate(*glossy_of[rp.material], rp.n, Reflection(rp, eye), m.ks, parts);
  }
  static glm::dvec3 Reflection(const sample::RowPoint& rp, const glm::dvec3& eye) {
    const glm::dvec3 wo = glm::normalize(eye - rp.p);
    return glm::normalize(2 * glm::dot(rp.n, wo) * rp.n - wo);
  }

  void ScatterV(uint64_t row, Scratch& s) const {
    for (uint64_t e = vis.offset[row]; e < vis.offset[row + 1]; ++e) s.v[vis.col[e]] = vis.val[e];
  }
  void ClearV(uint64_t row, Scratch& s) const {
    for (uint64_t e = vis.offset[row]; e < vis.offset[row + 1]; ++e) s.v[vis.col[e]] = 0;
  }
  void ScatterStampedV(uint64_t row, Scratch& s, uint32_t stamp) const {
    Scratch::Stamped* vs = s.vs.data();
    for (uint64_t e = vis.offset[row]; e < vis.offset[row + 1]; ++e) vs[vis.col[e]] = {vis.val[e], stamp};
  }
  // ρ's approximation into s.rho, the touched coefficients listed in s.rho_terms.
  void ScatterRho(const std::vector<RhoPart>& parts, Scratch& s, uint32_t stamp) const {
    s.rho_terms.clear();
    for (const RhoPart& p : parts) {
      const SparseRows& r = p.field->rows;
      const uint64_t b = r.offset[p.row], e = r.offset[p.row + 1];
      const uint64_t keep = o.brdf_terms == RenderOptions::kAll
                                ? e - b
                                : std::min<uint64_t>(e - b, p.field->scaling[p.row] + o.brdf_terms);
      for (uint64_t k = b; k < b + keep; ++k) {
        const uint32_t c = r.col[k];
        if (s.coef_stamp[c] != stamp) {
          s.coef_stamp[c] = stamp;
          s.rho_terms.push_back(c);
        }
        s.rho[c] += p.weight * r.val[k];
      }
    }
  }
  void ClearRho(Scratch& s) const {
    for (uint32_t c : s.rho_terms) s.rho[c] = 0;
  }

  // Sublinear evaluation (§5.3) of one vertex: V scattered with ScatterStampedV, ρ with
  // ScatterRho, both under `stamp`.
  void Sublinear(Scratch& s, uint32_t stamp, double out[3]) const {
    const uint64_t face = ft.face;
    const Scratch::Stamped* vs = s.vs.data();
    auto v = [vs, stamp](uint64_t k) { return vs[k].stamp == stamp ? static_cast<double>(vs[k].value) : 0.0; };
    auto rho = [&s](uint64_t k) { return s.rho[k]; };
    double b[3] = {0, 0, 0};
    for (uint64_t f = 0; f < 6; ++f) {  // case 1
      const uint64_t k = f * face;
      const double rv = s.rho[k] * v(k);
      for (int ch = 0; ch < 3; ++ch) b[ch] += rv * light.c[ch][k];
    }
    for (uint32_t k : s.rho_terms) {  // case 2 over ρ's squares, case 3 over ρ's wavelets
      const uint64_t f = k / face, local = k % face;
      if (local == 0) continue;
      const HaarBasis& hb = ft.basis[local];
      const uint64_t sq = (local - 1) / 3, base = f * face + 1 + 3 * sq;
      const double pv = LazyParentSum(v, face, ft.squares, f, hb.level, hb.i, hb.j, s.psum_v, s.psum_v_stamp, stamp);
      const double vk = v(k), rk = s.rho[k];
      for (int ch = 0; ch < 3; ++ch) {
        b[ch] += rk * (light.c[ch][k] * pv + vk * light.psum[ch][f * ft.squares + sq]);
      }
      if (s.square_stamp[f * ft.squares + sq] != stamp) {
        s.square_stamp[f * ft.squares + sq] = stamp;
        const double vb[3] = {v(base), v(base + 1), v(base + 2)};
        const double scale = static_cast<double>(uint64_t{1} << hb.level);
        for (int ch = 0; ch < 3; ++ch) b[ch] += scale * Case2(&s.rho[base], &light.c[ch][base], vb);
      }
    }
    for (uint32_t k : light.terms) {  // case 3 over L's kept wavelets, with ρ's parent sums
      const double vk = v(k);
      if (vk == 0) continue;
      const uint64_t f = k / face, local = k % face;
      const HaarBasis& hb = ft.basis[local];
      const double pr = LazyParentSum(rho, face, ft.squares, f, hb.level, hb.i, hb.j, s.psum_r, s.psum_r_stamp, stamp);
      if (pr == 0) continue;
      for (int ch = 0; ch < 3; ++ch) b[ch] += vk * light.c[ch][k] * pr;
    }
    for (int ch = 0; ch < 3; ++ch) out[ch] = b[ch];
  }

  // Linear evaluation (§5.2): every coefficient of the approximated L and ρ, and of V.
  void Linear(Scratch& s, double out[3]) const {
    const uint64_t face = ft.face;
    out[0] = out[1] = out[2] = 0;
    for (uint64_t f = 0; f < 6; ++f) {
      const double* v = s.v.data() + f * face;
      const double* r = s.rho.data() + f * face;
      ParentSums(v, ft.levels, &s.pv);
      ParentSums(r, ft.levels, &s.pr);
      for (int ch = 0; ch < 3; ++ch) {
        out[ch] +=
            LinearTripleProductDense(light.kept[ch].data() + f * face, light.kept_psum[ch].data() + f * ft.squares, v,
                                     s.pv.data(), r, s.pr.data(), ft.levels);
      }
    }
  }

  // The pixel-basis reference: Σ_p L_p V_p ρ̃(ω_p) Ω_p over the texels (the N brightest with
  // terms), ρ̃ evaluated exactly from the scene's material, V decoded from its Haar row.
  void Pixel(uint64_t row, const glm::dvec3& eye, const std::vector<uint32_t>& texels, Scratch& s,
             double out[3]) const {
    const sample::RowPoint& rp = geo.vertex_rows[row];
    const sample::Material& m = scene.materials[rp.material];
    Brdf lambert;
    lambert.albedo = m.albedo;
    const Brdf glossy = GlossyLobe(m);
    const glm::dvec3 refl = m.ks > 0 ? Reflection(rp, eye) : glm::dvec3(0, 0, 1);
    const uint64_t face = ft.face;
    double b[3] = {0, 0, 0};
    auto add = [&](uint64_t p, double vp) {
      if (vp == 0) return;
      const glm::dvec3& dir = texel_table->centre[p];
      double rho = m.albedo > 0 ? BrdfValue(lambert, rp.n, rp.n, dir) : 0.0;
      if (m.ks > 0) rho += BrdfValue(glossy, rp.n, refl, dir);
      const double w = vp * rho * texel_table->weight[p] / static_cast<double>(face);
      for (int ch = 0; ch < 3; ++ch) b[ch] += w * light_cube[3 * p + ch];
    };
    if (texels.empty()) {  // every texel: decode V per face
      for (uint64_t f = 0; f < 6; ++f) {
        HaarFace h;
        h.res = ft.res;
        h.c.assign(s.v.begin() + static_cast<std::ptrdiff_t>(f * face),
                   s.v.begin() + static_cast<std::ptrdiff_t>((f + 1) * face));
        const std::vector<double> px = h.Inverse();
        for (uint64_t p = 0; p < face; ++p) add(f * face + p, px[p]);
      }
    } else {  // the kept texels: V at each by walking its ancestors
      for (uint32_t p : texels) {
        const uint64_t f = p / face, local = p % face;
        add(p, ParentSumAt(s.v.data() + f * face, ft.levels, local % ft.res, local / ft.res));
      }
    }
    for (int ch = 0; ch < 3; ++ch) out[ch] = b[ch];
  }
};

// The N brightest texels of the frame's lighting (by luminance × solid angle, or anything
// proportional to it); empty: all.
std::vector<uint32_t> BrightestTexels(const std::vector<float>& cube, const std::vector<double>& solid_angle,
                                      uint64_t n) {
  const uint64_t cols = solid_angle.size();
  if (n >= cols) return {};
  std::vector<uint32_t> idx(cols);
  std::iota(idx.begin(), idx.end(), 0u);
  std::vector<double> mag(cols);
  for (uint64_t p = 0; p < cols; ++p) {
    mag[p] = std::fabs(0.2126 * cube[3 * p] + 0.7152 * cube[3 * p + 1] + 0.0722 * cube[3 * p + 2]) * solid_angle[p];
  }
  std::partial_sort(idx.begin(), idx.begin() + static_cast<std::ptrdiff_t>(n), idx.end(),
                    [&](uint32_t a, uint32_t b) { return mag[a] != mag[b] ? mag[a] > mag[b] : a < b; });
  idx.resize(n);
  std::sort(idx.begin(), idx.end());
  return idx;
}

Status ResolveMaterials(Renderer& rd) {
  const MaterialField* lambert = nullptr;
  for (const MaterialField& f : rd.fields) {
    if (f.brdf.kind == Brdf::Kind::kLambert) {
      if (lambert) return InvalidArgument("two Lambert material fields: " + lambert->path + " and " + f.path);
      lambert = &f;
    }
  }
  for (const sample::Material& m : rd.scene.materials) {
    rd.lambert_of.push_back(nullptr);
    rd.glossy_of.push_back(nullptr);
    if (rd.o.method == TripleMethod::kPixel) continue;  // evaluated exactly, no field
    if (m.albedo > 0) {
      if (!lambert) {
        return InvalidArgument("material \"" + m.name + "\" has albedo " + std::to_string(m.albedo) +
                               " but no Lambert material field was given: make one with `ltbake material --brdf "
                               "lambert -o lambert.ltm --cube-res " +
                               std::to_string(rd.res) + "` and pass --material lambert.ltm");
      }
      rd.lambert_of.back() = lambert;
    }
    if (m.ks > 0) {
      const Brdf lobe = GlossyLobe(m);
      for (const MaterialField& f : rd.fields) {
        if (f.brdf.SameLobe(lobe)) rd.glossy_of.back() = &f;
      }
      if (!rd.glossy_of.back()) {
        const std::string spec = BrdfSpec(lobe);
        return InvalidArgument("material \"" + m.name + "\" has ks " + std::to_string(m.ks) + " and the lobe " + spec +
                               " but no material field of that lobe was given: make one with `ltbake material --brdf " +
                               spec + " -o glossy.ltm --cube-res " + std::to_string(rd.res) +
                               "` and pass --material glossy.ltm");
      }
    }
  }
  return Status::Ok();
}

Status LoadInputs(const RenderOptions& o, const Progress& progress, Renderer& rd, nlohmann::json* report) {
  LTB_ASSIGN_OR_RETURN(io::ContainerReader in, io::ContainerReader::Open(o.visibility));
  const nlohmann::json& j = in.metadata().json;
  std::string scene_path = o.scene, want_hash;
  try {
    const nlohmann::json cols = j.contains("basis") && j["basis"].is_object() && j["basis"].contains("cols")
                                    ? j["basis"]["cols"]
                                    : nlohmann::json();
    if (!cols.is_object() || cols.value("basis", "") != "haar-squares" || cols.value("quantity", "") != "visibility" ||
        !j.contains("visibility")) {
      return InvalidArgument(o.visibility +
                             ": is not a visibility field; make one with `ltbake sample SCENE --visibility -o "
                             "vis.ltm` (a vertex-mode scene)");
    }
    rd.res = cols.value("cube_res", uint64_t{0});
    if (scene_path.empty()) scene_path = j["visibility"].at("scene").get<std::string>();
    want_hash = j["visibility"].at("geometry_hash").get<std::string>();
  } catch (const nlohmann::json::exception& e) {
    return InvalidArgument(o.visibility + ": malformed visibility metadata: " + e.what());
  }
  if (!in.complete()) {
    return FailedPrecondition(o.visibility + ": not complete; rerun `ltbake sample --visibility` to finish it");
  }
  if (!IsPowerOfTwo(rd.res) || rd.res > 512 || in.metadata().matrix().cols != 6 * rd.res * rd.res) {
    return InvalidArgument(o.visibility + ": columns are not 6R² for a power-of-two R up to 512");
  }
  LTB_RETURN_IF_ERROR(ReadSparseRows(in, &rd.vis));
  LTB_ASSIGN_OR_RETURN(rd.scene, sample::ParseScene(scene_path));
  LTB_ASSIGN_OR_RETURN(rd.geo, sample::BuildGeometry(rd.scene, progress));
  if (rd.geo.geometry_hash != want_hash) {
    return FailedPrecondition(scene_path +
                              ": the scene's geometry (an object, a transform or a mesh file) changed since " +
                              o.visibility + " was baked (geometry hash " + rd.geo.geometry_hash + ", baked from " +
                              want_hash + "); bake the visibility field again. Materials may change freely");
  }
  if (rd.geo.vertex_rows.size() != rd.vis.rows) {
    return FailedPrecondition(scene_path + " has " + std::to_string(rd.geo.vertex_rows.size()) + " vertex rows but " +
                              o.visibility + " " + std::to_string(rd.vis.rows));
  }
  for (const std::string& path : o.materials) {
    LTB_ASSIGN_OR_RETURN(MaterialField f, LoadMaterialField(path, rd.res));
    rd.fields.push_back(std::move(f));
  }
  LTB_RETURN_IF_ERROR(ResolveMaterials(rd));
  (*report)["scene"] = scene_path;
  (*report)["cube_res"] = rd.res;
  (*report)["vertices"] = rd.vis.rows;
  (*report)["visibility_terms"] = rd.vis.col.size();
  (*report)["visibility_bytes"] = in.file_size();
  nlohmann::json mats = nlohmann::json::array();
  for (const MaterialField& f : rd.fields) {
    mats.push_back(
        {{"file", f.path}, {"brdf", BrdfSpec(f.brdf)}, {"samples_res", f.sres}, {"terms", f.rows.col.size()}});
  }
  (*report)["materials"] = mats;
  return Status::Ok();
}

// B at one vertex seen from `eye`, by the chosen method, into b; returns the BRDF terms used
// (0 for the pixel method).
uint64_t ShadeVertex(Renderer& rd, TripleMethod method, uint64_t row, const glm::dvec3& eye,
                     const std::vector<uint32_t>& texels, Scratch& s, double b[3]) {
  if (method == TripleMethod::kPixel) {
    rd.ScatterV(row, s);
    rd.Pixel(row, eye, texels, s, b);
    rd.ClearV(row, s);
    return 0;
  }
  const uint32_t stamp = s.NextStamp();
  rd.RhoParts(row, eye, &s.parts);
  rd.ScatterRho(s.parts, s, stamp);
  const uint64_t terms = s.rho_terms.size();
  if (method == TripleMethod::kLinear) {
    rd.ScatterV(row, s);
    rd.Linear(s, b);
    rd.ClearV(row, s);
  } else {
    rd.ScatterStampedV(row, s, stamp);
    rd.Sublinear(s, stamp, b);
  }
  rd.ClearRho(s);
  return terms;
}

// The shared method (stages/triple/shared_products.h): B of every needed vertex from `eye`
// into values; the rows lit into stats.
Status ShadeShared(const Renderer& rd, const std::vector<uint8_t>& needed, const glm::dvec3& eye,
                   const Progress& progress, std::vector<float>* values, SharedStats* stats) {
  std::vector<uint64_t> rows;
  VertexRho rho;
  std::vector<RhoPart> parts;
  for (uint64_t row = 0; row < needed.size(); ++row) {
    if (!needed[row]) continue;
    rd.RhoParts(row, eye, &parts);
    rows.push_back(row);
    rho.parts.insert(rho.parts.end(), parts.begin(), parts.end());
    rho.offset.push_back(rho.parts.size());
  }
  std::vector<double> b;
  LTB_RETURN_IF_ERROR(SharedTripleProducts(rd.vis, rd.res, rd.light_lanes, rows, rho, rd.fields,
                                           rd.o.brdf_terms == RenderOptions::kAll ? UINT64_MAX : rd.o.brdf_terms,
                                           rd.o.jobs, progress, &b, stats));
  for (uint64_t i = 0; i < rows.size(); ++i)
    for (int ch = 0; ch < 3; ++ch)
      (*values)[rows[i] * 3 + ch] = static_cast<float>(std::ldexp(b[i * 3 + ch], rd.light_exponent));
  return Status::Ok();
}

// The vertices of every triangle a pixel sees (needed = 1), counting the pixels that hit
// something and those that hit a mesh without vertex shading.
void MarkSeenVertices(const sample::Geometry& geo, const std::vector<sample::PixelHit>& hits,
                      std::vector<uint8_t>* needed, uint64_t* hit_pixels, uint64_t* unshaded) {
  for (const sample::PixelHit& h : hits) {
    if (h.geom < 0) continue;
    ++*hit_pixels;
    const sample::Geometry::RowMesh& m = geo.row_meshes[static_cast<size_t>(h.geom)];
    if (m.triangles.empty()) {
      ++*unshaded;
      continue;
    }
    const glm::uvec3& t = m.triangles[h.prim];
    for (int c = 0; c < 3; ++c) (*needed)[m.first_row + t[c]] = 1;
  }
}

// Each pixel: its triangle's vertex values interpolated barycentrically, clamped at 0.
void InterpolateImage(const sample::Geometry& geo, const std::vector<sample::PixelHit>& hits,
                      const std::vector<float>& values, std::vector<float>* image) {
  for (uint64_t p = 0; p < hits.size(); ++p) {
    const sample::PixelHit& h = hits[p];
    float rgb[3] = {0, 0, 0};
    if (h.geom >= 0) {
      const sample::Geometry::RowMesh& m = geo.row_meshes[static_cast<size_t>(h.geom)];
      if (!m.triangles.empty()) {
        const glm::uvec3& t = m.triangles[h.prim];
        const float w[3] = {1 - h.u - h.v, h.u, h.v};
        for (int q = 0; q < 3; ++q)
          for (int ch = 0; ch < 3; ++ch) rgb[ch] += w[q] * values[(m.first_row + t[q]) * 3 + ch];
      }
    }
    for (int ch = 0; ch < 3; ++ch) (*image)[p * 3 + ch] = std::max(0.0f, rgb[ch]);
  }
}

// The size, view, memory, terms and --output pattern, before anything is read.
Status CheckRenderOptions(const RenderOptions& o) {
  if (o.width == 0 || o.height == 0 || uint64_t{o.width} * o.height > (1u << 26)) {
    return InvalidArgument("--size " + std::to_string(o.width) + "x" + std::to_string(o.height) +
                           " is empty or above 2^26 pixels");
  }
  LTB_RETURN_IF_ERROR(sample::ValidateView(o.eye, o.target, o.up, o.fov_degrees)
                          .WithContext("the view (--eye, --target, --up, --fov)"));
  LTB_RETURN_IF_ERROR(sample::CheckViewMemory(o.width, o.height, o.mem_limit));
  if (o.light_terms == 0) return InvalidArgument("--terms must be at least 1 (or all)");
  if (o.light_turn_deg != 0 && o.orbit_frames == 0) {
    return InvalidArgument("--light-turn " + std::to_string(o.light_turn_deg) +
                           " turns the map from frame to frame: give the frames with --orbit DEG:FRAMES (0:FRAMES "
                           "for an eye that stays)");
  }
  if (!std::isfinite(o.light_turn_deg) || std::fabs(o.light_turn_deg) > 360) {
    return InvalidArgument("--light-turn must be a number of degrees in [-360, 360]");
  }
  if (o.orbit_frames > 0 && !o.output.empty())
    LTB_RETURN_IF_ERROR(stages::FramePath(o.output, 0, stages::FramePattern::kOrbit).status());
  return Status::Ok();
}

// Frame k's image: --output itself, or its %04d frame with --orbit-frames.
Status WriteFrame(const RenderOptions& o, uint32_t k, const std::vector<float>& image) {
  std::string path = o.output;
  if (o.orbit_frames > 0) {
    LTB_ASSIGN_OR_RETURN(path, stages::FramePath(o.output, k, stages::FramePattern::kOrbit));
  }
  return stages::WriteImage(path, image.data(), image.size() / 3, o.width, o.height, {.exposure = o.exposure});
}

// The face table, the pixel method's texel table and the frame's lighting cube.
Status LoadEnvironment(const RenderOptions& o, const Progress& progress, Renderer& rd) {
  rd.ft.res = rd.res;
  rd.ft.face = rd.res * rd.res;
  rd.ft.squares = (rd.ft.face - 1) / 3;
  rd.ft.levels = std::countr_zero(rd.res);
  for (uint64_t k = 0; k < rd.ft.face; ++k) rd.ft.basis.push_back(BasisOf(k));
  if (o.method == TripleMethod::kPixel) rd.texel_table = std::make_unique<TexelTable>(rd.res);
  stages::EnvLoadOptions eo;
  eo.layout = o.env_layout;
  eo.clamp = o.clamp_env;
  eo.max_bytes = o.mem_limit;
  eo.progress = progress;
  eo.jobs = o.jobs;
  LTB_ASSIGN_OR_RETURN(stages::Environment env, stages::Environment::Open(o.env, rd.res, eo));
  if (o.light_turn_deg != 0 && !env.rotates()) {
    return InvalidArgument(o.env + ": a cubemap .npy cannot turn (--light-turn); pass the map as .exr or .hdr");
  }
  rd.env = std::make_unique<stages::Environment>(std::move(env));
  return Status::Ok();
}

// The lighting of a frame: the map turned by `deg` about +Z, in Haar with its kept terms (and
// the shared method's lanes); the pixel method's brightest texels into *texels.
Status LightFrame(const RenderOptions& o, double deg, Renderer& rd, std::vector<uint32_t>* texels) {
  LTB_RETURN_IF_ERROR(rd.env->Cubemap(deg * std::numbers::pi / 180, &rd.light_cube));
  MakeLighting(rd.light_cube, rd.res, o.method == TripleMethod::kPixel ? RenderOptions::kAll : o.light_terms, o.method,
               &rd.light);
  if (o.method == TripleMethod::kShared) rd.light_lanes = LightingLanes(rd.light.kept, rd.res, &rd.light_exponent);
  *texels = o.method == TripleMethod::kPixel && o.light_terms != RenderOptions::kAll
                ? BrightestTexels(rd.light_cube, rd.texel_table->weight, o.light_terms)
                : std::vector<uint32_t>{};
  return Status::Ok();
}

}  // namespace

Result<RenderResult> RunTripleRender(const RenderOptions& o, const Progress& progress) {
  LTB_RETURN_IF_ERROR(CheckRenderOptions(o));
  const uint32_t frames = std::max<uint32_t>(1, o.orbit_frames);
  nlohmann::json report = {
      {"method", TripleMethodName(o.method)},
      {"visibility", o.visibility},
      {"env", o.env},
      {"light_terms", o.light_terms == RenderOptions::kAll ? nlohmann::json("all") : nlohmann::json(o.light_terms)},
      {"brdf_terms", o.brdf_terms == RenderOptions::kAll ? nlohmann::json("all") : nlohmann::json(o.brdf_terms)}};
  auto t0 = Clock::now();
  Renderer rd{o};
  LTB_RETURN_IF_ERROR(LoadInputs(o, progress, rd, &report));
  LTB_RETURN_IF_ERROR(LoadEnvironment(o, progress, rd));
  const uint64_t cols = 6 * rd.ft.face;
  auto t1 = Clock::now();
  report["load_ms"] = Ms(t0, t1);
  std::vector<uint32_t> texels;
  LTB_RETURN_IF_ERROR(LightFrame(o, o.rotate_deg, rd, &texels));
  report["light_terms_used"] =
      o.method == TripleMethod::kPixel ? (texels.empty() ? cols : texels.size()) : rd.light.terms.size();
  report["lighting_ms"] = Ms(t1, Clock::now());

  const uint64_t rows = rd.vis.rows;
  std::vector<float> values(rows * 3, 0.0f);
  std::vector<uint8_t> needed(rows, 0);
  std::atomic<uint64_t> brdf_terms_sum{0};
  // B of the needed vertices from `eye` into values.
  SharedStats shared_stats;
  auto evaluate = [&](const glm::dvec3& eye) -> Status {
    if (o.method == TripleMethod::kShared) return ShadeShared(rd, needed, eye, progress, &values, &shared_stats);
    std::vector<uint64_t> blocks;
    for (uint64_t r0 = 0; r0 < rows; r0 += 256) blocks.push_back(r0);
    return stages::ParallelFor(blocks, o.jobs, Progress{.update = nullptr, .cancelled = progress.cancelled}, "vertices",
                               [&](uint64_t r0) -> Status {
                                 thread_local std::unique_ptr<Scratch> tls;
                                 if (!tls) tls = std::make_unique<Scratch>();
                                 Scratch& s = *tls;
                                 s.Size(cols, rd.ft.squares);
                                 uint64_t terms = 0;
                                 for (uint64_t row = r0; row < std::min(rows, r0 + 256); ++row) {
                                   if (!needed[row]) continue;
                                   double b[3];
                                   terms += ShadeVertex(rd, o.method, row, eye, texels, s, b);
                                   for (int ch = 0; ch < 3; ++ch) values[row * 3 + ch] = static_cast<float>(b[ch]);
                                 }
                                 brdf_terms_sum += terms;
                                 return Status::Ok();
                               });
  };

  RenderResult result;
  nlohmann::json frame_reports = nlohmann::json::array();
  if (!o.vertex_output.empty()) {  // every vertex, from the first frame's eye
    std::fill(needed.begin(), needed.end(), 1);
    auto a = Clock::now();
    LTB_RETURN_IF_ERROR(evaluate(o.eye));
    // The lighting and B are in double; B beyond float32 is an error, never written.
    LTB_RETURN_IF_ERROR(stages::CheckRelitImageFinite(values, 0, o.env));
    report["vertex_output_ms"] = Ms(a, Clock::now());
    LTB_RETURN_IF_ERROR(stages::WriteImage(o.vertex_output, values.data(), rows, rows, 1));
    result.vertex_values = values;
  }
  const uint64_t pixels = uint64_t{o.width} * o.height;
  std::vector<sample::PixelHit> hits;
  std::vector<float> image(pixels * 3);
  // Frames are rendered unless only the vertex values were asked for.
  const uint32_t rendered = o.output.empty() && !o.vertex_output.empty() ? 0 : frames;
  for (uint32_t k = 0; k < rendered; ++k) {
    if (progress.Cancelled()) return Cancelled("interrupted between frames; the frames written are kept");
    const glm::dvec3 eye = sample::OrbitEye(o.eye, o.target, o.orbit_deg, k);
    auto a = Clock::now();
    const double light_deg = o.rotate_deg + k * o.light_turn_deg;
    if (k > 0 && o.light_turn_deg != 0) LTB_RETURN_IF_ERROR(LightFrame(o, light_deg, rd, &texels));
    auto a2 = Clock::now();
    auto camera = sample::PinholeCamera::Create(eye, o.target, o.up, o.fov_degrees, o.width, o.height);
    if (!camera.ok()) {
      return camera.status().WithContext("the view (--eye, --target, --up, --fov), frame " + std::to_string(k));
    }
    LTB_RETURN_IF_ERROR(sample::TracePixels(rd.geo, *camera, o.jobs, &hits));
    std::fill(needed.begin(), needed.end(), 0);
    uint64_t hit_pixels = 0, unshaded = 0;
    MarkSeenVertices(rd.geo, hits, &needed, &hit_pixels, &unshaded);
    const uint64_t visible = static_cast<uint64_t>(std::count(needed.begin(), needed.end(), uint8_t{1}));
    auto b = Clock::now();
    brdf_terms_sum = 0;
    LTB_RETURN_IF_ERROR(evaluate(eye));
    LTB_RETURN_IF_ERROR(stages::CheckRelitImageFinite(values, 0, o.env).WithContext("frame " + std::to_string(k)));
    auto c = Clock::now();
    InterpolateImage(rd.geo, hits, values, &image);
    auto d = Clock::now();
    nlohmann::json fr = {{"frame", k},
                         {"eye", {eye.x, eye.y, eye.z}},
                         {"pixels_hit", hit_pixels},
                         {"pixels_not_vertex_shaded", unshaded},
                         {"visible_vertices", visible},
                         {"light_deg", light_deg},
                         {"lighting_ms", Ms(a, a2)},
                         {"trace_ms", Ms(a2, b)},
                         {"relight_ms", Ms(b, c)},
                         {"image_ms", Ms(c, d)}};
    if (o.method == TripleMethod::kShared) {
      fr["brdf_rows_lit"] = shared_stats.rows_lit;
      fr["brdf_faces_lit"] = shared_stats.faces_lit;
    } else if (o.method != TripleMethod::kPixel && visible > 0) {
      fr["brdf_terms_per_vertex"] = static_cast<double>(brdf_terms_sum.load()) / static_cast<double>(visible);
    }
    frame_reports.push_back(fr);
    if (!o.output.empty()) LTB_RETURN_IF_ERROR(WriteFrame(o, k, image));
    if (k == 0) result.image = image;
  }
  report["frames"] = frame_reports;
  result.report = std::move(report);
  return result;
}

}  // namespace ltb::triple
