#include "stages/sample/sampler.h"

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstring>
#include <glm/geometric.hpp>
#include <glm/trigonometric.hpp>
#include <limits>

#include "stages/common/cubemap.h"

namespace ltb::sample {

namespace {

// Counter-based random numbers: one stream per (row, item), whatever thread runs it.
struct Rng {
  uint64_t state;
  Rng(uint64_t seed, uint64_t row, uint64_t item) {
    state = seed ^ (row * 0x9E3779B97F4A7C15ull) ^ (item * 0xC2B2AE3D27D4EB4Full);
    Next();
  }
  uint64_t Next() { return Mix64(state += 0x9E3779B97F4A7C15ull); }
  double Uniform() { return static_cast<double>(Next() >> 11) * 0x1.0p-53; }
  // Two independent uniforms in [0, 1) with 24 bits each, from one draw.
  void Uniform2(double* a, double* b) {
    uint64_t z = Next();
    *a = static_cast<double>(z >> 40) * 0x1.0p-24;
    *b = static_cast<double>((z >> 16) & 0xFFFFFF) * 0x1.0p-24;
  }
};

std::vector<TexelInfo> TexelTable(uint32_t r) {
  std::vector<TexelInfo> t(6ull * r * r);
  for (uint64_t c = 0; c < t.size(); ++c) {
    cubemap::Texel x = cubemap::ColumnToTexel(c, r);
    TexelInfo& ti = t[c];
    ti.face = x.face;
    ti.u0 = 2.0 * x.s / r - 1.0;
    ti.v0 = 2.0 * x.t / r - 1.0;
    ti.a = cubemap::FaceDirection(x.face, 0, 0);
    ti.b = cubemap::FaceDirection(x.face, 1, 0) - ti.a;
    ti.c = cubemap::FaceDirection(x.face, 0, 1) - ti.a;
    ti.centre = cubemap::TexelCenter(x, r);
    // The texel lies in the cone of half-angle ρ around its centre; it is wholly below the
    // horizon when the centre is at least 90° + ρ from the normal: n·centre <= -sin ρ.
    ti.cos_limit = -std::sin(cubemap::TexelAngularRadius(x, r)) - 1e-12;
  }
  return t;
}

// An orthonormal frame around n.
void Frame(const glm::dvec3& n, glm::dvec3* t, glm::dvec3* b) {
  glm::dvec3 a = std::fabs(n.x) > 0.9 ? glm::dvec3(0, 1, 0) : glm::dvec3(1, 0, 0);
  *t = glm::normalize(glm::cross(a, n));
  *b = glm::cross(n, *t);
}

glm::dvec3 CosineSample(const glm::dvec3& n, Rng& rng) {
  double u1 = rng.Uniform(), u2 = rng.Uniform();
  double r = std::sqrt(u1), phi = 2 * M_PI * u2;
  glm::dvec3 t, b;
  Frame(n, &t, &b);
  return glm::normalize(t * (r * std::cos(phi)) + b * (r * std::sin(phi)) + n * std::sqrt(std::max(0.0, 1 - u1)));
}

// The rest of one indirect path after its first direction d from o: at each of up to
// `bounces` hits, scale(hit) (the hit's albedo on the path's throughput) and a cosine draw
// from rng about the hit's shading normal; leave(column) when the path escapes after at
// least one bounce. Returns the rays traced. Indirect and IndirectFactored (a factored bake's
// terms, and the colour channels of TransportChannels) walk their paths with it (the same rays, the same arithmetic).
template <class Scale, class Leave>
uint64_t WalkPath(const Geometry& g, uint32_t bounces, uint32_t r, glm::dvec3 o, glm::dvec3 d, Rng& rng, Scale&& scale,
                  Leave&& leave) {
  Hit hit = g.rays->Intersect(o, d);
  uint64_t rays = 1;
  if (!hit.hit) return rays;  // escaped directly: that is the direct term
  for (uint32_t b = 0; b < bounces; ++b) {
    glm::dvec3 y = o + d * hit.t;
    // The hit's shading normal (the geometric one unless the object has vertex normals),
    // turned to the side of the surface the path arrived from (by the geometric normal).
    const glm::dvec3 facing = glm::dot(hit.normal, d) > 0 ? -hit.normal : hit.normal;
    const glm::dvec3 ns = g.ShadingNormal(hit);
    const glm::dvec3 ny = glm::dot(ns, facing) < 0 ? -ns : ns;
    scale(hit);
    d = CosineSample(ny, rng);
    // A tilted shading normal can send the path into the surface: it is absorbed there.
    if (ns != hit.normal && glm::dot(d, facing) <= 0) break;
    o = y + ny * g.epsilon;
    hit = g.rays->Intersect(o, d);
    ++rays;
    if (!hit.hit) {
      leave(cubemap::Column(cubemap::DirectionToTexel(d, r), r));
      break;
    }
  }
  return rays;
}

// x^e for x > 0: repeated squaring when e is a small whole number (the usual case).
inline double Power(double x, double e, int int_e) {
  if (int_e < 0) return std::pow(x, e);
  double r = 1.0;
  for (int k = int_e; k > 0; k >>= 1, x *= x)
    if (k & 1) r *= x;
  return r;
}

// Slots per batch: small enough that a batch (about 100 bytes a slot) stays in L2 between
// being generated and traced (measured: 1024 beats 4096 by ~5% CPU; 512 is no better).
constexpr uint64_t kBatchRays = 1024;
constexpr uint64_t kGolden = 0x9E3779B97F4A7C15ull;

// The glossy lobe max(0, r·d)^e of slots [0, n) into gl, from x = max(0, r·d) in pw
// (overwritten), by squaring over the exponent's bits in the outer loop so the lane loops
// vectorise.
void GlossyLobe(const PhongLobe& brdf, RowScratch& sc, size_t n) {
  double* __restrict gl = sc.gl.data();
  double* __restrict x = sc.pw.data();
  if (brdf.int_exponent >= 0) {
    for (size_t i = 0; i < n; ++i) gl[i] = 1.0;
    for (int k = brdf.int_exponent; k > 0; k >>= 1) {
      if (k & 1)
        for (size_t i = 0; i < n; ++i) gl[i] *= x[i];
      for (size_t i = 0; i < n; ++i) x[i] *= x[i];
    }
  } else {
    for (size_t i = 0; i < n; ++i) gl[i] = x[i] > 0 ? std::pow(x[i], brdf.exponent) : 0.0;
  }
}

// p[0, spp) = x; one store when spp is the compile-time 1 or 4.
template <uint32_t kSpp, typename T>
inline void Splat(T* __restrict p, T x, uint64_t spp) {
  if constexpr (kSpp == 1) {
    *p = x;
  } else if constexpr (kSpp == 4) {
    typedef T V __attribute__((vector_size(4 * sizeof(T))));
    const V v = {x, x, x, x};
    std::memcpy(p, &v, sizeof v);
  } else {
    for (uint64_t i = 0; i < spp; ++i) p[i] = x;
  }
}

}  // namespace

double PhongLobe::Eval(const glm::dvec3& w) const {
  double f = diffuse;
  if (ks_norm > 0) {
    double c = glm::dot(reflect, w);
    if (c > 0) f += ks_norm * Power(c, exponent, int_exponent);
  }
  return f;
}

namespace {

// ½ Σ_k Θ_k ĝ_k of the spherical polygon through the unit directions of p[0..m) (in order):
// Lambert's vector irradiance, so that ∫ n·ω dω over the polygon is ±n·Φ (the sign is the
// polygon's orientation). Θ_k is the arc from p_k to p_k+1, ĝ_k the unit normal of its plane.
glm::dvec3 LambertVector(const glm::dvec3* p, int m) {
  glm::dvec3 phi(0.0);
  for (int k = 0; k < m; ++k) {
    const glm::dvec3 a = glm::normalize(p[k]), b = glm::normalize(p[(k + 1) % m]);
    const glm::dvec3 g = glm::cross(a, b);
    const double s = glm::length(g);
    if (s > 0) phi += (std::atan2(s, glm::dot(a, b)) / s) * g;
  }
  return 0.5 * phi;
}

}  // namespace

Sampler::Sampler(const SceneDesc& s, const Geometry& g, uint32_t r, uint32_t spp, uint32_t bounces, uint64_t seed)
    : s_(s), g_(g), r_(r), spp_(spp), bounces_(bounces), seed_(seed), camera_(s.camera), texels_(TexelTable(r)) {
  // Strata tile the texel exactly: kx · ky = spp, as square as spp allows.
  kx_ = static_cast<uint32_t>(std::sqrt(static_cast<double>(spp)));
  while (spp % kx_ != 0) --kx_;
  ky_ = spp / kx_;
  for (const TexelInfo& t : texels_) {
    u0_.push_back(t.u0);
    v0_.push_back(t.v0);
    centre_x_.push_back(t.centre.x);
    centre_y_.push_back(t.centre.y);
    centre_z_.push_back(t.centre.z);
    cos_limit_.push_back(t.cos_limit);
    const double h = 2.0 / r;
    const glm::dvec3 q[4] = {t.a + t.u0 * t.b + t.v0 * t.c, t.a + (t.u0 + h) * t.b + t.v0 * t.c,
                             t.a + (t.u0 + h) * t.b + (t.v0 + h) * t.c, t.a + t.u0 * t.b + (t.v0 + h) * t.c};
    glm::dvec3 phi = LambertVector(q, 4);
    irradiance_.push_back(glm::dot(phi, t.centre) < 0 ? -phi : phi);  // pointing out through the texel
  }
  // Per slot of a batch (slot k is sample k mod spp of its texel).
  for (uint64_t k = 0; k < TexelsPerBatch() * spp; ++k) {
    stratum_x_.push_back(static_cast<double>((k % spp) % kx_));
    stratum_y_.push_back(static_cast<double>((k % spp) / kx_));
    stratum_salt_.push_back(((k % spp) + 2) * kGolden);
  }
}

bool Sampler::UnoccludedExact(const RowPoint& rp, double* out) const {
  const PhongLobe brdf = MakeBrdf(rp);
  if (brdf.ks_norm > 0) return false;
  const double h = 2.0 / r_;
  for (uint64_t c = 0; c < texels_.size(); ++c) {
    const TexelInfo& t = texels_[c];
    if (BelowHorizon(rp.n, c)) {
      out[c] = 0.0;
      continue;
    }
    // n·(a + u b + v c) at the corners, counter-clockwise in (u, v).
    const double na = glm::dot(rp.n, t.a), nb = glm::dot(rp.n, t.b), nc = glm::dot(rp.n, t.c);
    const double cu[4] = {t.u0, t.u0 + h, t.u0 + h, t.u0}, cv[4] = {t.v0, t.v0, t.v0 + h, t.v0 + h};
    double s[4];
    bool all_above = true;
    for (int k = 0; k < 4; ++k) {
      s[k] = na + cu[k] * nb + cv[k] * nc;
      all_above = all_above && s[k] >= 0;
    }
    if (all_above) {
      out[c] = brdf.diffuse * std::max(0.0, glm::dot(rp.n, irradiance_[c]));
      continue;
    }
    // Clipped to the horizon (n·ω ≥ 0 is a half-plane of the face): at most five corners.
    glm::dvec3 poly[8];
    int m = 0;
    for (int k = 0; k < 4; ++k) {
      const int j = (k + 1) % 4;
      if (s[k] >= 0) poly[m++] = t.a + cu[k] * t.b + cv[k] * t.c;
      if ((s[k] >= 0) != (s[j] >= 0)) {
        const double f = s[k] / (s[k] - s[j]);
        poly[m++] = t.a + (cu[k] + f * (cu[j] - cu[k])) * t.b + (cv[k] + f * (cv[j] - cv[k])) * t.c;
      }
    }
    out[c] = m >= 3 ? brdf.diffuse * std::abs(glm::dot(rp.n, LambertVector(poly, m))) : 0.0;
  }
  return true;
}

RowPoint Sampler::Primary(uint64_t row) const {
  if (s_.mode == SceneDesc::Mode::kVertex) return g_.vertex_rows[row];
  const Camera& c = s_.camera;
  const glm::dvec3 d = camera_.Direction(row % c.width, row / c.width);
  Hit h = g_.rays->Intersect(c.eye, d);
  RowPoint rp;
  if (!h.hit) return rp;
  rp.valid = true;
  rp.p = c.eye + d * h.t;
  const glm::dvec3 n = g_.ShadingNormal(h);  // the geometric normal unless the object has vertex normals
  rp.n = glm::dot(n, d) > 0 ? -n : n;        // facing the camera
  rp.wo = -d;
  rp.material = g_.geom_material[h.geom_id];
  rp.colour = g_.HitColour(h);
  return rp;
}

uint64_t Sampler::TexelsPerBatch() const { return std::max<uint64_t>(1, kBatchRays / spp_); }

PhongLobe Sampler::MakeBrdf(const RowPoint& rp) const {
  const Material& m = s_.materials[rp.material];
  // Vertex colours multiply the albedo in a channel's bake; the monochrome bake leaves
  // them to the reflectance table (docs/COLOUR.md).
  const double albedo = s_.channel >= 0 ? m.albedo * rp.colour[s_.channel] : m.albedo;
  PhongLobe brdf{albedo / M_PI, 0, m.exponent, {}};
  if (s_.mode == SceneDesc::Mode::kImage && m.ks > 0) {
    brdf.ks_norm = m.ks * (m.exponent + 2) / (2 * M_PI);
    brdf.reflect = 2 * glm::dot(rp.n, rp.wo) * rp.n - rp.wo;
    if (m.exponent == std::floor(m.exponent) && m.exponent <= 4096) brdf.int_exponent = static_cast<int>(m.exponent);
  }
  return brdf;
}

void Sampler::GenerateRays(uint64_t row, const RowPoint& rp, const PhongLobe& brdf, uint64_t c0, uint64_t c1,
                           RowScratch& sc, uint64_t* below, uint64_t* samples_below, const uint8_t* select) const {
  if (spp_ == 4) {
    GenerateRaysT<4>(row, rp, brdf, c0, c1, sc, below, samples_below, select);
  } else if (spp_ == 1) {
    GenerateRaysT<1>(row, rp, brdf, c0, c1, sc, below, samples_below, select);
  } else {
    GenerateRaysT<0>(row, rp, brdf, c0, c1, sc, below, samples_below, select);
  }
}

template <uint32_t kSpp>
void Sampler::GenerateRaysT(uint64_t row, const RowPoint& rp, const PhongLobe& brdf, uint64_t c0, uint64_t c1,
                            RowScratch& sc, uint64_t* below, uint64_t* samples_below, const uint8_t* select) const {
  const uint64_t spp = kSpp ? kSpp : spp_;
  const uint64_t slots = (c1 - c0) * spp;
  if (sc.wc.size() < slots) {
    for (auto* v : {&sc.wc, &sc.gl, &sc.pw}) v->resize(slots);
    sc.ray_value.resize(slots);
  }
  // One texel's slots more than the batch needs: pass 1 writes a texel's slots before
  // knowing whether it keeps them.
  if (sc.u0.size() < slots + spp) {
    for (auto* v : {&sc.u0, &sc.v0}) v->resize(slots + spp);
    sc.s0.resize(slots + spp);
  }
  sc.batch.Reserve(slots);
  if (sc.texel.size() < c1 - c0 + 1) sc.texel.resize(c1 - c0 + 1);
  if (sc.above.size() < c1 - c0) sc.above.resize(c1 - c0);
  size_t n = 0, m = 0;
  const bool glossy = brdf.ks_norm > 0;
  // Texels in runs of one face: the face's affine map (a, b, c) is shared by the run.
  for (uint64_t f0 = c0; f0 < c1;) {
    const uint64_t face_end = (f0 / (uint64_t{r_} * r_) + 1) * r_ * r_, f1 = std::min(c1, face_end);
    const size_t n0 = n;
    // Pass 1: the horizon test, vectorised over the run's texels; then each texel above
    // the horizon gets spp slots holding its corner and random stream origin (branch-free).
    const double pnx = rp.n.x, pny = rp.n.y, pnz = rp.n.z;
    const double* __restrict tcx = centre_x_.data();
    const double* __restrict tcy = centre_y_.data();
    const double* __restrict tcz = centre_z_.data();
    const double* __restrict tcl = cos_limit_.data();
    uint8_t* __restrict up = sc.above.data();
#pragma omp simd
    for (uint64_t c = f0; c < f1; ++c) {
      // glm::dot(rp.n, centre) <= cos_limit: wholly below the horizon.
      up[c - f0] = (pnx * tcx[c] + pny * tcy[c]) + pnz * tcz[c] <= tcl[c] ? 0 : 1;
    }
    if (select != nullptr) {
      for (uint64_t c = f0; c < f1; ++c) up[c - f0] &= select[c] != 0 ? 1 : 0;
    }
    const uint64_t stream_row = seed_ ^ (row * 0x9E3779B97F4A7C15ull);
    double* __restrict lu = sc.u0.data();
    double* __restrict lv = sc.v0.data();
    uint64_t* __restrict ls = sc.s0.data();
    uint32_t* __restrict texel = sc.texel.data();
    const double* __restrict tu0 = u0_.data();
    const double* __restrict tv0 = v0_.data();
    // Texel c's slots at n: its corner and stream origin (StreamStart(row, c)).
    auto slots_of = [&](uint64_t c) {
      Splat<kSpp>(lu + n, tu0[c], spp);
      Splat<kSpp>(lv + n, tv0[c], spp);
      Splat<kSpp>(ls + n, static_cast<uint64_t>(stream_row ^ (c * 0xC2B2AE3D27D4EB4Full)), spp);
      texel[m] = static_cast<uint32_t>(c);
    };
    if (select == nullptr) {  // most texels kept: branch-free, each texel's slots written, kept or not
      for (uint64_t c = f0; c < f1; ++c) {
        slots_of(c);
        const uint64_t a = up[c - f0];
        m += a;
        n += a * spp;
      }
    } else {  // a converged level's few selected texels: only theirs (the same slots, far fewer writes)
      for (uint64_t c = f0; c < f1; ++c) {
        if (up[c - f0] == 0) continue;
        slots_of(c);
        ++m;
        n += spp;
      }
    }
    *below += (f1 - f0) - (n - n0) / spp;
    if (n == n0) {
      f0 = f1;
      continue;
    }
    // Pass 2, vectorised across all slots of the run (DirectionsT).
    const TexelInfo& t = texels_[f0];
    const double na = glm::dot(rp.n, t.a), nb = glm::dot(rp.n, t.b), nc = glm::dot(rp.n, t.c);
    if (glossy) {
      DirectionsT<kSpp, kGlossy>(n0, n, na, nb, nc, t, brdf, sc);
    } else if (visibility_) {
      DirectionsT<kSpp, kSolidAngle>(n0, n, na, nb, nc, t, brdf, sc);
    } else {
      DirectionsT<kSpp, kDiffuse>(n0, n, na, nb, nc, t, brdf, sc);
    }
    f0 = f1;
  }
  if (glossy) {
    GlossyLobe(brdf, sc, n);
    const double* __restrict wc = sc.wc.data();
    const double* __restrict gl = sc.gl.data();
    double* __restrict val = sc.ray_value.data();
    const double diffuse = brdf.diffuse, ks = brdf.ks_norm;
#pragma omp simd
    for (size_t k = 0; k < n; ++k) val[k] = wc[k] * (diffuse + ks * gl[k]);  // inactive slots: never read
  }
  const float* __restrict tf = sc.batch.tfar.data();
  uint64_t inactive = 0;
#pragma omp simd reduction(+ : inactive)
  for (size_t k = 0; k < n; ++k) inactive += tf[k] < 0 ? 1 : 0;
  const glm::dvec3 origin = Origin(rp);
  sc.batch.SetOrigin(static_cast<float>(origin.x), static_cast<float>(origin.y), static_cast<float>(origin.z), n);
  *samples_below += inactive;
  sc.n = n;
  sc.active = n - inactive;
}

// Pass 2 of GenerateRaysT over slots [n0, n1) of one face's run, vectorised across the
// slots: jittered point, direction, trace or not (a sample below the horizon needs no
// ray: its slot is inactive, tfar = -inf < tnear, and its value is never read), weight; for a glossy
// BRDF the value waits for the lobe (wc and x = max(0, r·d) are kept).
namespace {

// The end of the texel range from c0 that holds `step` selected texels (select[c] != 0; every
// texel when select is null), or the rest; their count into *picked. Sparse selections so
// still trace full batches.
uint64_t SelectedRangeEnd(const uint8_t* select, uint64_t c0, uint64_t cols, uint64_t step, uint64_t* picked) {
  if (select == nullptr) {
    *picked = std::min(cols, c0 + step) - c0;
    return c0 + *picked;
  }
  uint64_t c1 = c0;
  for (*picked = 0; c1 < cols && *picked < step;) *picked += select[c1++] != 0 ? 1 : 0;
  return c1;
}

}  // namespace

// SplitMix64 is counter-based: draw k of the (row, texel) stream is Mix64(s0 + (k+2)·G).
template <uint32_t kSpp, int kKind>
void Sampler::DirectionsT(size_t n0, size_t n1, double na, double nb, double nc, const TexelInfo& t,
                          const PhongLobe& brdf, RowScratch& sc) const {
  const double h = 2.0 / r_, hx = h / kx_, hy = h / ky_;
  const double ax = t.a.x, ay = t.a.y, az = t.a.z, bx = t.b.x, by = t.b.y, bz = t.b.z;
  const double cx = t.c.x, cy = t.c.y, cz = t.c.z;
  const double rfx = brdf.reflect.x, rfy = brdf.reflect.y, rfz = brdf.reflect.z, diffuse = brdf.diffuse;
  const double* __restrict lu = sc.u0.data();
  const double* __restrict lv = sc.v0.data();
  const uint64_t* __restrict ls = sc.s0.data();
  const double* __restrict stx = stratum_x_.data();
  const double* __restrict sty = stratum_y_.data();
  const uint64_t* __restrict salt = stratum_salt_.data();
  double* __restrict wc = sc.wc.data();
  double* __restrict pw = sc.pw.data();
  double* __restrict val = sc.ray_value.data();
  float* __restrict rx = sc.batch.dir_x.data();
  float* __restrict ry = sc.batch.dir_y.data();
  float* __restrict rz = sc.batch.dir_z.data();
  float* __restrict tf = sc.batch.tfar.data();
  constexpr float kInf = std::numeric_limits<float>::infinity();
#pragma omp simd
  for (size_t k = n0; k < n1; ++k) {
    const uint64_t z = Mix64(ls[k] + salt[k]);  // ((k % spp) + 2)·kGolden, without the division
    // (z >> 40)·2^-24 and ((z >> 16) & 0xFFFFFF)·2^-24, exactly, built from bits (AVX2
    // has no vector uint64 -> double conversion): 1 + m·2^-24 has m in the mantissa.
    const double ju = std::bit_cast<double>(0x3FF0000000000000ull | ((z >> 40) << 28)) - 1.0;
    const double jv = std::bit_cast<double>(0x3FF0000000000000ull | (((z >> 16) & 0xFFFFFFull) << 28)) - 1.0;
    const double u = lu[k] + (stx[k] + ju) * hx;
    const double v = lv[k] + (sty[k] + jv) * hy;
    // |a + u b + v c| = sqrt(1 + u² + v²); dω / du dv = |.|^-3.
    const double inv = 1.0 / std::sqrt(1.0 + u * u + v * v);
    const double cosn = na + u * nb + v * nc;  // n·(a + u b + v c): the sign of the cosine
    const double dx = (ax + u * bx + v * cx) * inv;
    const double dy = (ay + u * by + v * cy) * inv;
    const double dz = (az + u * bz + v * cz) * inv;
    const double w = inv * inv * inv * (cosn * inv);  // w · cos
    rx[k] = static_cast<float>(dx);
    ry[k] = static_cast<float>(dy);
    rz[k] = static_cast<float>(dz);
    tf[k] = cosn > 0 ? kInf : -kInf;
    if constexpr (kKind == kGlossy) {
      wc[k] = w;
      pw[k] = std::max(0.0, rfx * dx + rfy * dy + rfz * dz);
    } else if constexpr (kKind == kSolidAngle) {
      val[k] = inv * inv * inv;  // every slot, inactive ones too: the texel's total weight
    } else {
      // Unconditional (the value of an inactive slot is never read), so it if-converts.
      val[k] = w * diffuse;
    }
  }
}

void Sampler::Accumulate(const RowScratch& sc, std::vector<double>& acc) const {
  if (spp_ == 4) {
    AccumulateT<4>(sc, acc);
  } else if (spp_ == 1) {
    AccumulateT<1>(sc, acc);
  } else {
    AccumulateT<0>(sc, acc);
  }
}

template <uint32_t kSpp>
void Sampler::AccumulateT(const RowScratch& sc, std::vector<double>& acc) const {
  const uint64_t spp = kSpp ? kSpp : spp_;
  const float* tf = sc.batch.tfar.data();
  const double* val = sc.ray_value.data();
  const size_t texels = sc.n / spp;
  for (size_t m = 0; m < texels; ++m) {
    double s = acc[sc.texel[m]];
    for (uint64_t i = 0; i < spp; ++i) {
      if (tf[m * spp + i] >= 0) s += val[m * spp + i];  // not occluded (inactive slots are -inf)
    }
    acc[sc.texel[m]] = s;
  }
}

void Sampler::AccumulateVisibility(const RowScratch& sc, std::vector<double>& acc, std::vector<double>& total) const {
  const float* tf = sc.batch.tfar.data();
  const double* val = sc.ray_value.data();
  const size_t texels = sc.n / spp_;
  for (size_t m = 0; m < texels; ++m) {
    double seen = 0, all = 0;
    for (uint64_t i = 0; i < spp_; ++i) {
      const double w = val[m * spp_ + i];
      all += w;
      if (tf[m * spp_ + i] >= 0) seen += w;  // traced and not occluded
    }
    acc[sc.texel[m]] = seen;
    total[sc.texel[m]] = all;
  }
}

void Sampler::Transport(uint64_t row, const RowPoint& rp, float* out, RowScratch& sc, Counters& cnt) const {
  uint64_t below = 0, samples_below = 0, rays = 0;
  const PhongLobe brdf = MakeBrdf(rp);
  const uint64_t cols = texels_.size(), step = TexelsPerBatch();
  std::vector<double>& acc = sc.sum_value;
  acc.assign(cols, 0.0);
  if (visibility_) sc.sum_weight.assign(cols, 0.0);
  for (uint64_t c0 = 0; c0 < cols; c0 += step) {
    GenerateRays(row, rp, brdf, c0, std::min(cols, c0 + step), sc, &below, &samples_below);
    g_.rays->Occluded(sc.batch, sc.n);
    if (visibility_) {
      AccumulateVisibility(sc, acc, sc.sum_weight);
    } else {
      Accumulate(sc, acc);
    }
    rays += sc.active;
  }
  if (visibility_) {  // texels wholly below the horizon were never generated: V = 0
    for (uint64_t c = 0; c < cols; ++c) {
      out[c] = sc.sum_weight[c] > 0 ? static_cast<float>(std::min(1.0, acc[c] / sc.sum_weight[c])) : 0.0f;
    }
    cnt.rays += rays;
    cnt.below += below;
    cnt.samples_below += samples_below;
    return;
  }
  // Stratified estimate of ∫_texel f cos V dω = ∫∫ f cos V w du dv: each of the spp
  // strata has area h²/spp in face coordinates (unbiased; docs/SAMPLE.md).
  const double h = 2.0 / r_, stratum_area = h * h / spp_;
  for (uint64_t c = 0; c < cols; ++c) acc[c] *= stratum_area;
  if (bounces_ > 0) rays += Indirect(row, rp, brdf, Origin(rp), DefaultPaths(), acc.data());
  for (uint64_t c = 0; c < cols; ++c) out[c] = static_cast<float>(acc[c]);
  cnt.rays += rays;
  cnt.below += below;
  cnt.samples_below += samples_below;
}

PhongLobe Sampler::MakeBrdfChannel(const RowPoint& rp, int c) const {
  const Material& m = s_.materials[rp.material];
  const double albedo = m.albedo_rgb[c] * rp.colour[c];  // ChannelScene's m.albedo · the vertex colour
  PhongLobe brdf{albedo / M_PI, 0, m.exponent, {}};
  if (s_.mode == SceneDesc::Mode::kImage && m.ks_rgb[c] > 0) {
    brdf.ks_norm = m.ks_rgb[c] * (m.exponent + 2) / (2 * M_PI);
    brdf.reflect = 2 * glm::dot(rp.n, rp.wo) * rp.n - rp.wo;
    if (m.exponent == std::floor(m.exponent) && m.exponent <= 4096) brdf.int_exponent = static_cast<int>(m.exponent);
  }
  return brdf;
}

void Sampler::TransportChannels(uint64_t row, const RowPoint& rp, float* const* out, RowScratch& sc,
                                Counters& cnt) const {
  const uint64_t cols = texels_.size(), step = TexelsPerBatch();
  uint64_t below = 0, samples_below = 0, rays = 0;
  PhongLobe b[3];
  int glossy = -1;  // a channel whose lobe the rays are generated with (the lobe's shape is shared)
  for (int c = 0; c < 3; ++c) {
    b[c] = MakeBrdfChannel(rp, c);
    if (b[c].ks_norm > 0) glossy = c;
  }
  PhongLobe gen = glossy >= 0 ? b[glossy] : b[0];
  if (glossy < 0) gen.diffuse = 1.0;  // ray values w·cos; ·diffuse_c is Transport's product, bit for bit
  std::vector<double>& acc = sc.sum_value;
  acc.assign(cols * 3, 0.0);  // channel c at [c·cols, (c+1)·cols)
  for (uint64_t c0 = 0; c0 < cols; c0 += step) {
    GenerateRays(row, rp, gen, c0, std::min(cols, c0 + step), sc, &below, &samples_below);
    g_.rays->Occluded(sc.batch, sc.n);
    const float* tf = sc.batch.tfar.data();
    const double* val = sc.ray_value.data();
    const double* wc = sc.wc.data();
    const double* gl = sc.gl.data();
    const size_t texels = sc.n / spp_;
    for (size_t m = 0; m < texels; ++m) {
      const uint64_t t = sc.texel[m];
      for (int c = 0; c < 3; ++c) {
        double s = acc[c * cols + t];
        for (uint64_t i = 0; i < spp_; ++i) {
          const size_t slot = m * spp_ + i;
          if (tf[slot] < 0) continue;  // occluded, or below the horizon
          // Transport's values: w·cos·(diffuse + ks·lobe) for a lobe, w·cos·diffuse otherwise.
          s += glossy >= 0 ? wc[slot] * (b[c].diffuse + b[c].ks_norm * gl[slot]) : val[slot] * b[c].diffuse;
        }
        acc[c * cols + t] = s;
      }
    }
    rays += sc.active;
  }
  const double h = 2.0 / r_, stratum_area = h * h / spp_;
  for (uint64_t k = 0; k < 3 * cols; ++k) acc[k] *= stratum_area;
  if (bounces_ > 0) {
    FactorWeights fw;  // no lobe terms: the three channels' diffuse (or image-mode Phong) parts
    for (int c = 0; c < 3; ++c) fw.brdf[c] = b[c];
    rays += IndirectFactored(row, rp, fw, {}, DefaultPaths(), true, acc.data());
  }
  for (int c = 0; c < 3; ++c)
    for (uint64_t t = 0; t < cols; ++t) out[c][t] = static_cast<float>(acc[c * cols + t]);
  cnt.rays += rays;
  cnt.below += below;
  cnt.samples_below += samples_below;
}

void Sampler::TransportFactored(uint64_t row, const RowPoint& rp, const std::vector<const brdf::ParabolicTable*>& f,
                                float* const* out, RowScratch& sc, Counters& cnt, bool rgb) const {
  const size_t terms = f.size() + 1, colours = rgb ? 3 : 1;
  const uint64_t cols = texels_.size(), step = TexelsPerBatch();
  uint64_t below = 0, samples_below = 0, rays = 0;
  FactorWeights fw;
  PhongLobe unit = MakeBrdf(rp);
  const sample::Material& mat = s_.materials[rp.material];
  for (size_t c = 0; c < colours; ++c) {
    fw.brdf[c] = rgb ? MakeBrdfChannel(rp, static_cast<int>(c)) : unit;
    // The lobe's share of channel c (ks_c / ks: the lobe's colour); 1 for a monochrome bake,
    // whose lobe colour is its terms' reflectance table.
    fw.lobe[c] = rgb && mat.ks > 0 ? mat.ks_rgb[c] / mat.ks : 1.0;
  }
  unit.diffuse = 1.0;  // ray values w·cos (w·cos·1.0, then ·diffuse: Transport's product, bit for bit)
  std::vector<double>& acc = sc.sum_value;
  acc.assign(cols * terms * colours, 0.0);  // (term k, colour c) at [(k·colours + c)·cols, ...)
  glm::dvec3 t, b;
  brdf::TangentFrame(rp.n, &t, &b);
  const uint32_t res = f.empty() ? 0 : f.front()->res;
  for (uint64_t c0 = 0; c0 < cols; c0 += step) {
    GenerateRays(row, rp, unit, c0, std::min(cols, c0 + step), sc, &below, &samples_below);
    g_.rays->Occluded(sc.batch, sc.n);
    const float* tf = sc.batch.tfar.data();
    const double* val = sc.ray_value.data();
    const size_t texels = sc.n / spp_;
    for (size_t m = 0; m < texels; ++m) {
      const uint64_t c = sc.texel[m];
      double s0[3] = {acc[c], colours == 3 ? acc[cols + c] : 0.0, colours == 3 ? acc[2 * cols + c] : 0.0};
      for (uint64_t i = 0; i < spp_; ++i) {
        const size_t slot = m * spp_ + i;
        if (tf[slot] < 0) continue;  // occluded, or below the horizon
        for (size_t ch = 0; ch < colours; ++ch) s0[ch] += val[slot] * fw.brdf[ch].diffuse;
        const glm::dvec3 d(sc.batch.dir_x[slot], sc.batch.dir_y[slot], sc.batch.dir_z[slot]);
        const brdf::ParabolicCoords pc(res, glm::dvec3(glm::dot(t, d), glm::dot(b, d), glm::dot(rp.n, d)));
        // A lobe term's sum is the same for every colour (its colour is fw.lobe): kept in colour 0.
        for (size_t k = 1; k < terms; ++k) acc[k * colours * cols + c] += val[slot] * f[k - 1]->At(pc);
      }
      for (size_t ch = 0; ch < colours; ++ch) acc[ch * cols + c] = s0[ch];
    }
    rays += sc.active;
  }
  const double h = 2.0 / r_, stratum_area = h * h / spp_;
  for (size_t k = 0; k < terms; ++k) {
    double* a0 = acc.data() + k * colours * cols;
    if (k == 0) {  // the diffuse part, summed per colour
      for (uint64_t i = 0; i < colours * cols; ++i) a0[i] *= stratum_area;
      continue;
    }
    for (uint64_t c = 0; c < cols; ++c) a0[c] *= stratum_area;
    for (size_t ch = colours; ch-- > 0;) {  // a lobe term's colours, colour 0 (read by the others) last
      for (uint64_t c = 0; c < cols; ++c) a0[ch * cols + c] = a0[c] * fw.lobe[ch];
    }
  }
  if (bounces_ > 0) rays += IndirectFactored(row, rp, fw, f, DefaultPaths(), rgb, acc.data());
  for (size_t k = 0; k < terms * colours; ++k)
    for (uint64_t c = 0; c < cols; ++c) out[k][c] = static_cast<float>(acc[k * cols + c]);
  cnt.rays += rays;
  cnt.below += below;
  cnt.samples_below += samples_below;
}

uint64_t Sampler::IndirectFactored(uint64_t row, const RowPoint& rp, const FactorWeights& fw,
                                   const std::vector<const brdf::ParabolicTable*>& f, uint64_t paths, bool rgb,
                                   double* acc) const {
  const uint64_t cols = texels_.size();
  const size_t terms = f.size() + 1, colours = rgb ? 3 : 1, n = terms * colours;
  const uint32_t res = f.empty() ? 0 : f.front()->res;
  glm::dvec3 t, b;
  if (!f.empty()) brdf::TangentFrame(rp.n, &t, &b);
  thread_local std::vector<double> beta;
  beta.resize(n);
  uint64_t rays = 0;
  for (uint64_t k = 0; k < paths; ++k) {
    Rng rng(seed_, row, cols + k);  // Indirect's paths: term 0 is its estimate, bit for bit
    const glm::dvec3 d = CosineSample(rp.n, rng);
    for (size_t c = 0; c < colours; ++c) beta[c] = fw.brdf[c].Eval(d) * M_PI;
    // Term j ≥ 1: f_j cos / pdf with pdf = cos / π, f_j·cos read from its table over cos.
    if (!f.empty()) {
      const brdf::ParabolicCoords pc(res, glm::dvec3(glm::dot(t, d), glm::dot(b, d), glm::dot(rp.n, d)));
      for (size_t j = 1; j < terms; ++j) {
        const double v = f[j - 1]->At(pc) * M_PI;
        for (size_t c = 0; c < colours; ++c) beta[j * colours + c] = v * fw.lobe[c];
      }
    }
    rays += WalkPath(
        g_, bounces_, r_, Origin(rp), d, rng,
        [&](const Hit& hit) {
          const sample::Material& m = s_.materials[g_.geom_material[hit.geom_id]];
          if (rgb) {  // per channel, vertex colours multiplying the albedo
            const glm::dvec3 colour = g_.HitColour(hit);
            for (size_t i = 0; i < n; ++i) {
              beta[i] *= m.albedo_rgb[static_cast<int>(i % 3)];
              beta[i] *= colour[static_cast<int>(i % 3)];
            }
            return;
          }
          // Monochrome: the scene's scalar albedo (a factored bake of one channel goes through
          // the colour path, so no channel's vertex colour applies here).
          for (size_t i = 0; i < n; ++i) beta[i] *= m.albedo;
        },
        [&](uint64_t c) {
          for (size_t i = 0; i < n; ++i) acc[i * cols + c] += beta[i] / static_cast<double>(paths);
        });
  }
  return rays;
}

uint64_t Sampler::DirectWithVariance(uint64_t row, const RowPoint& rp, double* est, double* var, RowScratch& sc,
                                     const uint8_t* select) const {
  sc.stats.resize(texels_.size());
  const uint64_t rays = DirectStats(row, rp, sc.stats.data(), sc, select);
  for (uint64_t c = 0; c < texels_.size(); ++c) {
    if (select != nullptr && select[c] == 0) continue;
    est[c] = sc.stats[c].vis;
    var[c] = sc.stats[c].vis_var;
  }
  return rays;
}

uint64_t Sampler::DirectStats(uint64_t row, const RowPoint& rp, TexelStats* out, RowScratch& sc,
                              const uint8_t* select) const {
  uint64_t below = 0, samples_below = 0, rays = 0;
  const PhongLobe brdf = MakeBrdf(rp);
  const uint64_t cols = texels_.size(), step = TexelsPerBatch(), spp = spp_;
  for (uint64_t c = 0; c < cols; ++c) {
    if (select == nullptr || select[c] != 0) out[c] = TexelStats{};  // below the horizon: no rays
  }
  // Sample i of a texel alone estimates its integral as value_i · h² (the stratum's area
  // times spp); the texel's estimate is their mean, as Transport's Σ value · h²/spp. Its
  // variance, (1/n²) Σ σ_i² over the n strata, is estimated from neighbouring pairs: E(v_a −
  // v_b)² = σ_a² + σ_b² + (μ_a − μ_b)², which overstates it by the pairs' difference in mean
  // only (the samples' spread, as an estimate for independent samples would take, overstates
  // it by all of the integrand's variation across the texel).
  const double h = 2.0 / r_, texel_area = h * h, n = static_cast<double>(spp);
  const double pair_scale = n / (2.0 * static_cast<double>(spp / 2)) / (n * n);
  for (uint64_t c0 = 0; c0 < cols;) {
    uint64_t picked = 0;
    const uint64_t c1 = SelectedRangeEnd(select, c0, cols, step, &picked);
    if (picked == 0) break;
    GenerateRays(row, rp, brdf, c0, c1, sc, &below, &samples_below, select);
    sc.live.resize(sc.n);
    const float* tf = sc.batch.tfar.data();
    for (size_t k = 0; k < sc.n; ++k) sc.live[k] = tf[k] >= 0 ? 1 : 0;  // before tracing: above the horizon
    g_.rays->Occluded(sc.batch, sc.n);
    rays += sc.active;
    const double* val = sc.ray_value.data();
    for (size_t m = 0; m < sc.n / spp; ++m) {
      TexelStats& st = out[sc.texel[m]];
      double s[2] = {0, 0}, s2[2] = {0, 0}, d2[2] = {0, 0}, prev[2] = {0, 0};
      for (uint64_t i = 0; i < spp; ++i) {
        const size_t k = m * spp + i;
        const double x = sc.live[k] ? val[k] * texel_area : 0.0;
        const bool seen = tf[k] >= 0;  // unoccluded (an inactive slot stays at -inf)
        const double part[2] = {seen ? x : 0.0, seen ? 0.0 : x};
        for (int j = 0; j < 2; ++j) {
          s[j] += part[j];
          s2[j] += part[j] * part[j];
          if (i % 2 == 1) d2[j] += (part[j] - prev[j]) * (part[j] - prev[j]);
          prev[j] = part[j];
        }
        st.active += sc.live[k];
        st.visible += seen ? 1 : 0;
      }
      st.vis = s[0] / n;
      st.occ = s[1] / n;
      st.vis_var = d2[0] * pair_scale;
      st.occ_var = d2[1] * pair_scale;
      st.vis_spread = std::max(0.0, s2[0] - s[0] * s[0] / n) / ((n - 1) * n);
      st.occ_spread = std::max(0.0, s2[1] - s[1] * s[1] / n) / ((n - 1) * n);
    }
    c0 = c1;
  }
  return rays;
}

uint64_t Sampler::DirectSelected(uint64_t row, const RowPoint& rp, const uint8_t* select, double* out,
                                 RowScratch& sc) const {
  uint64_t below = 0, samples_below = 0, rays = 0;
  const PhongLobe brdf = MakeBrdf(rp);
  const uint64_t cols = texels_.size(), step = TexelsPerBatch();
  std::vector<double>& acc = sc.sum_value;
  acc.assign(cols, 0.0);
  const double h = 2.0 / r_, stratum_area = h * h / spp_;
  // Ranges holding about a batch's worth of selected texels, so sparse selections still
  // trace full batches.
  for (uint64_t c0 = 0; c0 < cols;) {
    uint64_t picked = 0;
    const uint64_t c1 = SelectedRangeEnd(select, c0, cols, step, &picked);
    if (picked == 0) break;
    GenerateRays(row, rp, brdf, c0, c1, sc, &below, &samples_below, select);
    g_.rays->Occluded(sc.batch, sc.n);
    Accumulate(sc, acc);
    rays += sc.active;
    for (uint64_t c = c0; c < c1; ++c) {
      if (select[c] != 0) out[c] = acc[c] * stratum_area;
    }
    c0 = c1;
  }
  return rays;
}

void Sampler::Unoccluded(uint64_t row, const RowPoint& rp, double* out, RowScratch& sc) const {
  uint64_t below = 0, samples_below = 0;
  const PhongLobe brdf = MakeBrdf(rp);
  const uint64_t cols = texels_.size(), step = TexelsPerBatch();
  std::vector<double>& acc = sc.sum_value;
  acc.assign(cols, 0.0);
  for (uint64_t c0 = 0; c0 < cols; c0 += step) {
    GenerateRays(row, rp, brdf, c0, std::min(cols, c0 + step), sc, &below, &samples_below);
    Accumulate(sc, acc);  // before tracing, every active ray counts as unoccluded
  }
  const double h = 2.0 / r_, stratum_area = h * h / spp_;
  for (uint64_t c = 0; c < cols; ++c) out[c] = acc[c] * stratum_area;
}

uint64_t Sampler::IndirectTerm(uint64_t row, const RowPoint& rp, uint64_t paths, double* acc) const {
  return Indirect(row, rp, MakeBrdf(rp), Origin(rp), paths, acc);
}

// Paths that bounce at least once before escaping; each escaping path adds its
// throughput to the texel it leaves through. Diffuse at the bounces.
uint64_t Sampler::Indirect(uint64_t row, const RowPoint& rp, const PhongLobe& brdf, const glm::dvec3& origin,
                           uint64_t paths, double* acc) const {
  return IndirectPaths(row, rp, brdf, origin, 0, paths, static_cast<double>(paths), acc, nullptr);
}

uint64_t Sampler::IndirectStats(uint64_t row, const RowPoint& rp, uint64_t k0, uint64_t k1, double* sum, double* sum2,
                                const IndirectGuide* guide) const {
  const IndirectGuide* g = guide != nullptr && !guide->cdf.empty() && guide->cdf.back() > 0 ? guide : nullptr;
  return IndirectPaths(row, rp, MakeBrdf(rp), Origin(rp), k0, k1, 1.0, sum, sum2, g);
}

bool Sampler::GuidedFirst(const RowPoint& rp, const PhongLobe& brdf, const IndirectGuide& g, uint64_t row, uint64_t k,
                          glm::dvec3* d, double* beta) const {
  // Its own stream (the cosine branch draws as IndirectTerm does, from the path's stream).
  Rng pick(Mix64(seed_ ^ 0x6A09E667F3BCC909ull), row, texels_.size() + k);
  const double total = g.cdf.back(), h = 2.0 / r_;
  if (pick.Uniform() < g.alpha) {
    Rng rng(seed_, row, texels_.size() + k);
    *d = CosineSample(rp.n, rng);
  } else {
    const double x = pick.Uniform() * total;
    const auto it = std::upper_bound(g.cdf.begin(), g.cdf.end(), x);
    const uint64_t c = std::min<uint64_t>(static_cast<uint64_t>(it - g.cdf.begin()), g.cdf.size() - 1);
    const TexelInfo& t = texels_[c];
    const double u = t.u0 + pick.Uniform() * h, v = t.v0 + pick.Uniform() * h;
    *d = glm::normalize(t.a + u * t.b + v * t.c);
  }
  const double cosn = glm::dot(rp.n, *d);
  if (!(cosn > 0)) return false;
  // The mixture's density at d: the cosine's, and the texel's weight share over its solid
  // angle (uniform in face coordinates: dω = du dv · |d·a|³ for the face axis a).
  const uint64_t c = cubemap::Column(cubemap::DirectionToTexel(*d, r_), r_);
  const double w = g.cdf[c] - (c > 0 ? g.cdf[c - 1] : 0.0);
  const double da = std::abs(glm::dot(*d, texels_[c].a));
  const double pdf = g.alpha * cosn / M_PI + (1 - g.alpha) * (w / total) / (h * h * da * da * da);
  *beta = brdf.Eval(*d) * cosn / pdf;
  return true;
}

uint64_t Sampler::IndirectPaths(uint64_t row, const RowPoint& rp, const PhongLobe& brdf, const glm::dvec3& origin,
                                uint64_t k0, uint64_t k1, double divisor, double* acc, double* acc2,
                                const IndirectGuide* guide) const {
  const uint64_t cols = texels_.size();
  uint64_t rays = 0;
  for (uint64_t k = k0; k < k1; ++k) {
    Rng rng(seed_, row, cols + k);
    glm::dvec3 d;
    double beta;
    if (guide != nullptr) {
      if (!GuidedFirst(rp, brdf, *guide, row, k, &d, &beta)) continue;
      // The bounces draw from their own stream: the cosine branch's draws are not reused.
      rng = Rng(Mix64(seed_ ^ 0xBB67AE8584CAA73Bull), row, cols + k);
    } else {
      d = CosineSample(rp.n, rng);
      beta = brdf.Eval(d) * M_PI;  // f cos / pdf with pdf = cos / π
    }
    rays += WalkPath(
        g_, bounces_, r_, origin, d, rng,
        [&](const Hit& hit) {
          beta *= s_.materials[g_.geom_material[hit.geom_id]].albedo;
          if (s_.channel >= 0) beta *= g_.HitColour(hit)[s_.channel];
        },
        [&](uint64_t c) {
          acc[c] += beta / divisor;
          if (acc2 != nullptr) acc2[c] += beta * beta;
        });
  }
  return rays;
}
}  // namespace ltb::sample
