// Internal to the sample stage (stages/sample/sample.h is its public header): the Monte
// Carlo estimator of one row of the transport matrix T (docs/SAMPLE.md) — the primary hit,
// the stratified occlusion rays per cubemap texel, traced in batches, and the indirect
// paths. RunSample and TraceBare (sample.cpp) drive it over rows.
#pragma once

#include <algorithm>
#include <atomic>
#include <cstddef>
#include <cstdint>
#include <glm/vec3.hpp>
#include <vector>

#include "stages/brdf/brdf_factor.h"
#include "stages/mesh/triangle_mesh.h"
#include "stages/sample/ray_scene.h"
#include "stages/sample/scene.h"
#include "stages/sample/scene_geometry.h"

namespace ltb::sample {

// SplitMix64's finaliser: the sampler's random streams, the sparse bake's row draws and the
// converged levels' seeds all hash with it.
inline uint64_t Mix64(uint64_t z) {
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
  return z ^ (z >> 31);
}

struct TexelInfo {
  int face;
  double u0, v0;       // lower corner in face coordinates
  glm::dvec3 a, b, c;  // the face as an affine map: FaceDirection(face, u, v) = a + u·b + v·c
  glm::dvec3 centre;
  double cos_limit;  // skip the texel when n·centre < cos_limit (wholly below the horizon)
};

// A row point's Phong lobe as the sampler evaluates it per ray (the BRDF model itself is
// stages/brdf).
struct PhongLobe {
  double diffuse;  // albedo / π
  double ks_norm;  // ks (n+2) / (2π), 0 when not glossy
  double exponent;
  glm::dvec3 reflect;     // mirror direction of the view
  int int_exponent = -1;  // exponent when it is a whole number up to 4096, else -1
  double Eval(const glm::dvec3& w) const;
};

// Converged sampling's view of one texel's direct-term samples (Sampler::DirectStats), each
// sample i alone an estimate of the texel's integral, x_i = f_i·A (f the integrand
// w·cos·albedo/π, A the texel's area in face coordinates), split by what its ray saw.
struct TexelStats {
  double vis = 0, vis_var = 0, vis_spread = 0;  // mean of V_i·x_i (Transport's estimate), its variance
  double occ = 0, occ_var = 0, occ_spread = 0;  // mean of (1 − V_i)·x_i, its variance
  uint32_t active = 0, visible = 0;             // samples above the horizon, and of those unoccluded
};
// *_var: from neighbouring strata's differences (Sampler::DirectStats); *_spread: the samples'
// own spread over n (what independent samples would give: it sees every stratum's difference).

struct RowScratch {
  // Per-slot arrays of one batch: the texel's lower corner and random stream origin,
  // then w·cos and the glossy lobe of each sample.
  std::vector<double> u0, v0, wc, gl, pw;
  std::vector<uint64_t> s0;
  std::vector<uint8_t> above;     // per texel of a run: 1 when not wholly below the horizon
  std::vector<uint8_t> live;      // per slot of a batch: 1 when above the horizon (DirectStats)
  std::vector<TexelStats> stats;  // per texel: DirectWithVariance's
  // One batch: texel[m] owns ray slots [m·spp, (m+1)·spp), a slot per sample in stratum
  // order; a sample below the horizon keeps its slot as an inactive ray of value 0.
  RayBatch batch;
  std::vector<uint32_t> texel;
  std::vector<double> ray_value;
  size_t n = 0;       // slots in use
  size_t active = 0;  // rays traced (slots above the horizon)
  std::vector<double> sum_value, sum_weight;
};

// Converged sampling's first-bounce guide (Sampler::IndirectStats): indirect light comes in
// only through the directions something blocks, so a path's first direction is drawn from
// the texels by weight (the occluded part of their direct term, from the row's own direct
// samples) with probability 1 − alpha, else from the cosine as IndirectTerm draws it. The
// estimate divides by the mixture's density, so it stays unbiased for any weights.
struct IndirectGuide {
  std::vector<double> cdf;  // per texel, the running sum of the weights (empty: no guide)
  double alpha = 1.0;
};

// The first-vertex weights per colour of IndirectFactored: term 0's lobe (a factored bake's
// diffuse part, or a colour channel's BRDF), and the glossy terms' share of each channel.
struct FactorWeights {
  PhongLobe brdf[3];
  double lobe[3] = {1.0, 1.0, 1.0};
};

struct Counters {
  std::atomic<uint64_t> rays{0}, below{0}, samples_below{0};
};

class Sampler {
 public:
  Sampler(const SceneDesc& s, const Geometry& g, uint32_t r, uint32_t spp, uint32_t bounces, uint64_t seed);

  // Visibility mode (`sample --visibility`, docs/TRIPLE.md): Transport gives each texel the
  // fraction of its solid angle that is above the horizon and unoccluded, V ∈ [0, 1]: the
  // ratio Σ_visible w / Σ_all w over its stratified samples (w = dω/du dv), so a texel wholly
  // visible is exactly 1 and one wholly below the horizon exactly 0. No bounces.
  void SetVisibility(bool on) { visibility_ = on; }

  RowPoint Primary(uint64_t row) const;

  // Texels per batch of rays: about kBatchRays rays, so a batch stays in L2 cache between
  // being generated and being traced.
  uint64_t TexelsPerBatch() const;

  PhongLobe MakeBrdf(const RowPoint& rp) const;

  // The occlusion rays of texels [c0, c1) of one row (a valid point) into sc, with each
  // ray's value w·f·cos; texels wholly below the horizon get none, nor (when select is
  // given) texels c with select[c] == 0. *below counts the texels that got no rays.
  void GenerateRays(uint64_t row, const RowPoint& rp, const PhongLobe& brdf, uint64_t c0, uint64_t c1, RowScratch& sc,
                    uint64_t* below, uint64_t* samples_below, const uint8_t* select = nullptr) const;

  // Sums of the unoccluded rays' values into acc, per texel in stratum order (the order
  // the values were generated in, so the sums do not depend on the batching).
  void Accumulate(const RowScratch& sc, std::vector<double>& acc) const;

  // One row of T (6R² values) for a valid point.
  void Transport(uint64_t row, const RowPoint& rp, float* out, RowScratch& sc, Counters& cnt) const;

  // The three colour channels' rows from one set of rays (`sample --channels rgb`,
  // docs/COLOUR.md): out[c] exactly what Transport writes for ChannelScene(scene, c) (the
  // same rays, the same sums in the same order, bounces included). The scene is the
  // original one (channel −1): each channel's albedo and ks are read from albedo_rgb and
  // ks_rgb, vertex colours multiply the albedo.
  void TransportChannels(uint64_t row, const RowPoint& rp, float* const* out, RowScratch& sc, Counters& cnt) const;

  // The K terms of a factored bake (`sample --factor K`, docs/GLOSSY.md) of one row from one
  // set of rays: out[0] exactly what Transport writes (the diffuse part), out[k] for
  // k = 1..K−1 the texels' ∫ V·cos·f_k(ω in the row's tangent frame) dω, f[k] the incident
  // factor tables of the row's material (f_k / cos θ). With bounces, each term gains its
  // indirect part from one set of paths (IndirectFactored). rgb (`--channels rgb
  // --factor K`): 3K outputs, out[3k + c] term k of channel c — term 0 exactly what
  // TransportChannels writes, a lobe term times the lobe's channel c (ks_c / ks), and the
  // bounces per channel.
  void TransportFactored(uint64_t row, const RowPoint& rp, const std::vector<const brdf::ParabolicTable*>& f,
                         float* const* out, RowScratch& sc, Counters& cnt, bool rgb = false) const;

  // Sparse sampling (docs/SPARSE.md). The direct term of the texels c with select[c] != 0
  // into out[c] (the others are left alone), estimated exactly as Transport estimates it
  // (the same rays, summed in the same order). Returns the rays traced.
  uint64_t DirectSelected(uint64_t row, const RowPoint& rp, const uint8_t* select, double* out, RowScratch& sc) const;
  // Converged sampling (`sample --tolerance`, docs/SAMPLE.md): the direct term of every
  // texel into est (as Transport estimates it, without bounces) and the variance of each
  // texel's estimate into var, from the differences of neighbouring strata's samples (each
  // sample alone an estimate of the texel's integral; an overestimate by the strata's
  // difference in mean). spp must be at least 2. Returns the rays traced.
  // With select, only the texels c with select[c] != 0 are traced and written.
  uint64_t DirectWithVariance(uint64_t row, const RowPoint& rp, double* est, double* var, RowScratch& sc,
                              const uint8_t* select = nullptr) const;
  // Converged sampling: the direct term's samples of every texel (select: of the texels c with
  // select[c] != 0) as TexelStats into out. spp must be at least 2. Returns the rays traced.
  uint64_t DirectStats(uint64_t row, const RowPoint& rp, TexelStats* out, RowScratch& sc,
                       const uint8_t* select = nullptr) const;
  // Every texel's direct term with V = 1, exactly: albedo/π · ∫ max(0, n·ω) dω over the texel
  // (Lambert's formula for a spherical polygon; a texel the horizon crosses clipped to it), what
  // Transport's estimate of a wholly unoccluded texel has for its mean. Diffuse row points
  // only: false (out untouched) where the lobe is glossy.
  bool UnoccludedExact(const RowPoint& rp, double* out) const;
  // Every texel's direct term with V = 1, from the same samples and without tracing: a
  // texel that Transport finds wholly unoccluded has exactly this value, a texel wholly
  // below the horizon 0.
  void Unoccluded(uint64_t row, const RowPoint& rp, double* out, RowScratch& sc) const;
  // The indirect term (bounces) of one row with `paths` paths, added into acc (6R² values).
  // Transport uses DefaultPaths(). Returns the rays traced.
  uint64_t IndirectTerm(uint64_t row, const RowPoint& rp, uint64_t paths, double* acc) const;
  // Converged sampling: paths k0..k1−1 of the indirect term (the same paths as
  // IndirectTerm's first ones), each escaping path's throughput β added into sum[c] and β²
  // into sum2[c] (unscaled). Returns the rays traced.
  // With a guide (non-empty cdf), the first directions are drawn as IndirectGuide says.
  uint64_t IndirectStats(uint64_t row, const RowPoint& rp, uint64_t k0, uint64_t k1, double* sum, double* sum2,
                         const IndirectGuide* guide = nullptr) const;
  uint64_t DefaultPaths() const { return std::max<uint64_t>(1, spp_ * texels_.size() / 2); }
  uint32_t bounces() const { return bounces_; }
  uint32_t cube_res() const { return r_; }
  uint32_t spp() const { return spp_; }
  // Whether texel c is wholly below the horizon of normal n (no ray of it is ever traced).
  bool BelowHorizon(const glm::dvec3& n, uint64_t c) const {
    return n.x * centre_x_[c] + n.y * centre_y_[c] + n.z * centre_z_[c] <= cos_limit_[c];
  }

  glm::dvec3 Origin(const RowPoint& rp) const { return rp.p + rp.n * g_.epsilon; }
  const RayScene& rays() const { return *g_.rays; }

 private:
  // kSpp: spp_ when known at compile time (the common 4, and 1), else 0.
  template <uint32_t kSpp>
  void GenerateRaysT(uint64_t row, const RowPoint& rp, const PhongLobe& brdf, uint64_t c0, uint64_t c1, RowScratch& sc,
                     uint64_t* below, uint64_t* samples_below, const uint8_t* select) const;
  // kKind: what a ray's value is — kDiffuse w·cos·albedo/π, kGlossy w·cos (the lobe follows),
  // kSolidAngle w alone (visibility).
  enum Kind : int { kDiffuse = 0, kGlossy = 1, kSolidAngle = 2 };
  template <uint32_t kSpp, int kKind>
  void DirectionsT(size_t n0, size_t n1, double na, double nb, double nc, const TexelInfo& t, const PhongLobe& brdf,
                   RowScratch& sc) const;
  template <uint32_t kSpp>
  void AccumulateT(const RowScratch& sc, std::vector<double>& acc) const;
  // Visibility mode: per texel of the batch, Σ w of its unoccluded samples into acc and Σ w
  // of all its samples (below the horizon included) into total.
  void AccumulateVisibility(const RowScratch& sc, std::vector<double>& acc, std::vector<double>& total) const;
  uint64_t Indirect(uint64_t row, const RowPoint& rp, const PhongLobe& brdf, const glm::dvec3& origin, uint64_t paths,
                    double* acc) const;
  // The indirect term of a factored bake's terms, or (f empty, rgb) of the three colour
  // channels of TransportChannels: Indirect's paths, each term's throughput from its own
  // first-vertex factor (term 0 fw.brdf; term j the table f[j−1] in the row's tangent frame,
  // times fw.lobe), added into acc (term j, colour c at [(j·C + c)·6R², ...), C = 3 with
  // rgb, else 1). Diffuse at the bounces.
  uint64_t IndirectFactored(uint64_t row, const RowPoint& rp, const FactorWeights& fw,
                            const std::vector<const brdf::ParabolicTable*>& f, uint64_t paths, bool rgb,
                            double* acc) const;
  // Paths k0..k1−1: β/divisor into acc at the texel each leaves through, β² into acc2 (if any).
  uint64_t IndirectPaths(uint64_t row, const RowPoint& rp, const PhongLobe& brdf, const glm::dvec3& origin, uint64_t k0,
                         uint64_t k1, double divisor, double* acc, double* acc2,
                         const IndirectGuide* guide = nullptr) const;
  // A guided first direction into *d and f·cos/pdf into *beta; false when it falls below the
  // horizon (no light that way: the path ends, no ray).
  bool GuidedFirst(const RowPoint& rp, const PhongLobe& brdf, const IndirectGuide& g, uint64_t row, uint64_t k,
                   glm::dvec3* d, double* beta) const;
  // Channel c's BRDF at a row point (MakeBrdf of ChannelScene(scene, c)).
  PhongLobe MakeBrdfChannel(const RowPoint& rp, int c) const;

  const SceneDesc& s_;
  const Geometry& g_;
  uint32_t r_, spp_, bounces_;
  uint64_t seed_;
  PinholeCamera camera_;  // image mode's
  bool visibility_ = false;
  std::vector<TexelInfo> texels_;
  uint32_t kx_ = 1, ky_ = 1;
  // The texel table's fields the ray generator reads, as arrays it can vectorise over.
  std::vector<double> u0_, v0_, centre_x_, centre_y_, centre_z_, cos_limit_;
  std::vector<double> stratum_x_, stratum_y_;  // stratum column and row of the sample in batch slot k
  std::vector<uint64_t> stratum_salt_;         // ((k mod spp) + 2)·golden: slot k's offset in its texel's stream
  // Per texel: ½ Σ_k Θ_k ĝ_k over its spherical quadrilateral (Lambert), so that
  // ∫_texel n·ω dω = n · irradiance_[c] for a texel wholly above the horizon.
  std::vector<glm::dvec3> irradiance_;

  // The (row, texel) stream's counter origin, as Rng(seed, row, texel) sets it.
  uint64_t StreamStart(uint64_t row, uint64_t c) const {
    return seed_ ^ (row * 0x9E3779B97F4A7C15ull) ^ (c * 0xC2B2AE3D27D4EB4Full);
  }
};

}  // namespace ltb::sample
