#include "stages/triple/shared_products.h"

#include <algorithm>
#include <atomic>
#include <bit>
#include <cmath>
#include <cstring>
#include <memory>

#include "stages/common/parallel_for.h"
#include "stages/wavelet/haar_face.h"

namespace ltb::triple {

using wavelet::SquareIndex;

namespace {

// kLanes values of T as one vector (GCC/Clang vector extensions: one AVX register for double,
// half of one for float, whatever the -march).
template <typename T>
struct Lanes {
  typedef T V __attribute__((vector_size(kLanes * sizeof(T))));
};
template <typename T>
typename Lanes<T>::V Load(const T* p) {
  typename Lanes<T>::V v;
  std::memcpy(&v, p, sizeof v);
  return v;
}
template <typename T>
void Store(T* p, const typename Lanes<T>::V& v) {
  std::memcpy(p, &v, sizeof v);
}

// Square (l, i, j) from its quadrants' means q[qy][qx]: its three wavelets into w (types 01,
// 10, 11: +1 above, right, and their product) and its mean.
template <typename V, typename T>
V Block(V q00, V q01, V q10, V q11, T scale, T* w) {
  const V a = q00 + q01, b = q10 + q11, c = q01 - q00, d = q11 - q10;
  Store(w, scale * (b - a));
  Store(w + kLanes, scale * (c + d));
  Store(w + 2 * kLanes, scale * (d - c));
  return static_cast<T>(0.25) * (a + b);
}

// Levels l = top .. 0 of the forward transform from level top + 1's means in m (side
// 2^(top+1)), each level's means written over m at j·side + i: every position written was
// read before (it precedes the block's own first value, 2j·2side + 2i, in row-major order),
// so one buffer serves every level. Then the scaling coefficient.
template <typename T>
void ForwardLevels(T* m, int top, T* coef) {
  using V = typename Lanes<T>::V;
  for (int l = top; l >= 0; --l) {
    const uint64_t side = uint64_t{1} << l, fine = side * 2;
    const T scale = static_cast<T>(std::ldexp(1.0, -l - 2));
    for (uint64_t j = 0; j < side; ++j) {
      T* w = coef + (1 + 3 * SquareIndex(l, 0, j)) * kLanes;
      for (uint64_t i = 0; i < side; ++i, w += 3 * kLanes) {
        const T* q00 = m + ((2 * j) * fine + 2 * i) * kLanes;
        const T* q10 = q00 + fine * kLanes;
        const V mean = Block(Load(q00), Load(q00 + kLanes), Load(q10), Load(q10 + kLanes), scale, w);
        Store(m + (j * side + i) * kLanes, mean);
      }
    }
  }
  std::copy(m, m + kLanes, coef);
}

// The forward transform of the lit face L ⊙ ρ (light: R² × kLanes, rho: R²), the product
// formed as the finest level reads it; m (R²/4 × kLanes) holds the coarser means.
void LitForward(const float* light, const float* rho, int levels, float* m, float* coef) {
  using V = Lanes<float>::V;
  if (levels == 0) {
    Store(coef, Load(light) * rho[0]);
    return;
  }
  const int l = levels - 1;
  const uint64_t side = uint64_t{1} << l, fine = side * 2;
  const float scale = static_cast<float>(std::ldexp(1.0, -l - 2));
  for (uint64_t j = 0; j < side; ++j) {
    float* w = coef + (1 + 3 * SquareIndex(l, 0, j)) * kLanes;
    for (uint64_t i = 0; i < side; ++i, w += 3 * kLanes) {
      const uint64_t p0 = (2 * j) * fine + 2 * i, p1 = p0 + fine;
      const V mean =
          Block(Load(light + p0 * kLanes) * rho[p0], Load(light + (p0 + 1) * kLanes) * rho[p0 + 1],
                Load(light + p1 * kLanes) * rho[p1], Load(light + (p1 + 1) * kLanes) * rho[p1 + 1], scale, w);
      Store(m + (j * side + i) * kLanes, mean);
    }
  }
  ForwardLevels(m, l - 1, coef);
}

}  // namespace

template <typename T>
void ForwardHaarLanes(T* m, int levels, T* coef) {
  ForwardLevels(m, levels - 1, coef);
}

template <typename T>
void InverseHaarFace(const T* coef, int levels, T* px) {
  // Level l's means (side 2^l, in px at j·side + i) refined into level l + 1's, in place: the
  // blocks from last to first, so a mean is read before any block writes over it.
  px[0] = coef[0];
  for (int l = 0; l < levels; ++l) {
    const uint64_t side = uint64_t{1} << l, fine = side * 2;
    const T scale = static_cast<T>(std::ldexp(1.0, l));
    for (uint64_t b = side * side; b-- > 0;) {
      const uint64_t j = b / side, i = b % side;
      const T mean = px[b];
      const T* w = coef + 1 + 3 * SquareIndex(l, i, j);
      const T a = scale * w[0], c = scale * w[1], d = scale * w[2];
      T* row0 = px + (2 * j) * fine + 2 * i;
      T* row1 = row0 + fine;
      row0[0] = mean - a - c + d;  // qx = 0, qy = 0
      row0[1] = mean - a + c - d;  // qx = 1, qy = 0
      row1[0] = mean + a - c - d;  // qx = 0, qy = 1
      row1[1] = mean + a + c + d;  // qx = 1, qy = 1
    }
  }
}

template void ForwardHaarLanes<float>(float*, int, float*);
template void ForwardHaarLanes<double>(double*, int, double*);
template void InverseHaarFace<float>(const float*, int, float*);
template void InverseHaarFace<double>(const double*, int, double*);

std::vector<float> LightingLanes(const std::vector<double> (&coef)[3], uint64_t res, int* exponent) {
  const uint64_t face = res * res;
  const int levels = std::countr_zero(res);
  std::vector<double> px(6 * face * kLanes, 0.0), one(face);
  double peak = 0;
  for (int ch = 0; ch < 3; ++ch) {
    for (uint64_t f = 0; f < 6; ++f) {
      InverseHaarFace(coef[ch].data() + f * face, levels, one.data());
      for (uint64_t p = 0; p < face; ++p) {
        px[(f * face + p) * kLanes + ch] = one[p];
        peak = std::max(peak, std::fabs(one[p]));
      }
    }
  }
  *exponent = peak > 0 && std::isfinite(peak) ? std::ilogb(peak) : 0;
  std::vector<float> out(px.size());
  for (size_t k = 0; k < px.size(); ++k) out[k] = static_cast<float>(std::ldexp(px[k], -*exponent));
  return out;
}

namespace {

// A texel's lanes, in float (a lit row) and double (the sums).
using F4 = Lanes<float>::V;
using D4 = Lanes<double>::V;

// One thread's buffers for lighting rows: the row's coefficients (dense, 6R², zero outside
// the row), a face of ρ̃ pixels, the coarser means of a lit face and the lit row's coefficients.
struct LitScratch {
  std::vector<float> rho, rho_px, lit_px, g;
  explicit LitScratch(uint64_t face) : rho(6 * face, 0.0f), rho_px(face), lit_px(face * kLanes), g(6 * face * kLanes) {}
};

// The sampled rows the parts use, grouped: key k = the field's first key + the row, and the
// parts using key k at part[first[k] .. first[k + 1]).
struct Buckets {
  std::vector<uint64_t> first, part, keys;  // keys: the used ones, ascending
};

Result<Buckets> GroupParts(const VertexRho& rho, std::span<const MaterialField> fields,
                           std::vector<uint64_t>* field_base) {
  field_base->assign(1, 0);
  for (const MaterialField& f : fields) field_base->push_back(field_base->back() + f.rows.rows);
  Buckets b;
  b.first.assign(field_base->back() + 1, 0);
  std::vector<uint64_t> key(rho.parts.size());
  for (uint64_t s = 0; s < rho.parts.size(); ++s) {
    const RhoPart& p = rho.parts[s];
    uint64_t fi = 0;
    while (fi < fields.size() && &fields[fi] != p.field) ++fi;
    if (fi == fields.size() || p.row >= p.field->rows.rows) {
      return Internal("a vertex's BRDF part names a row outside the material fields");
    }
    key[s] = (*field_base)[fi] + p.row;
    ++b.first[key[s] + 1];
  }
  for (uint64_t k = 0; k + 1 < b.first.size(); ++k) {
    if (b.first[k + 1] > 0) b.keys.push_back(k);
    b.first[k + 1] += b.first[k];
  }
  b.part.resize(rho.parts.size());
  std::vector<uint64_t> fill(b.first.begin(), b.first.end() - 1);
  for (uint64_t s = 0; s < rho.parts.size(); ++s) b.part[fill[key[s]]++] = s;
  return b;
}

}  // namespace

Status SharedTripleProducts(const SparseRows& vis, uint64_t res, std::span<const float> light,
                            std::span<const uint64_t> vertex_rows, const VertexRho& rho,
                            std::span<const MaterialField> fields, uint64_t brdf_terms, int jobs,
                            const Progress& progress, std::vector<double>* out, SharedStats* stats) {
  const uint64_t face = res * res, cols = 6 * face;
  const int levels = std::countr_zero(res), face_shift = 2 * levels;
  if (light.size() != cols * kLanes || rho.offset.size() != vertex_rows.size() + 1 ||
      rho.offset.back() != rho.parts.size()) {
    return Internal("shared triple products: inputs of inconsistent sizes");
  }
  std::vector<uint64_t> field_base;
  LTB_ASSIGN_OR_RETURN(Buckets b, GroupParts(rho, fields, &field_base));
  // Each part's vertex, and where each face's entries begin in its visibility row (the
  // columns ascend: sparse chunks store them so), so a part reads only its row's lit faces.
  std::vector<uint64_t> part_vertex(rho.parts.size()), face_begin(vertex_rows.size() * 7);
  for (uint64_t i = 0; i < vertex_rows.size(); ++i) {
    for (uint64_t s = rho.offset[i]; s < rho.offset[i + 1]; ++s) part_vertex[s] = i;
    const uint64_t vr = vertex_rows[i];
    const uint32_t* c0 = vis.col.data() + vis.offset[vr];
    const uint32_t* c1 = vis.col.data() + vis.offset[vr + 1];
    for (uint64_t f = 0; f <= 6; ++f) {
      face_begin[i * 7 + f] = vis.offset[vr] + static_cast<uint64_t>(std::lower_bound(c0, c1, f * face) - c0);
    }
  }
  std::vector<double> contrib(rho.parts.size() * 3, 0.0);  // each part's weighted product
  std::atomic<uint64_t> faces_lit{0};
  Status st = stages::ParallelFor(
      b.keys, jobs, Progress{.update = nullptr, .cancelled = progress.cancelled}, "rows", [&](uint64_t k) -> Status {
        thread_local std::unique_ptr<LitScratch> tls;
        if (!tls || tls->rho.size() != cols) tls = std::make_unique<LitScratch>(face);
        LitScratch& sc = *tls;
        const uint64_t fi =
            static_cast<uint64_t>(std::upper_bound(field_base.begin(), field_base.end(), k) - field_base.begin()) - 1;
        const MaterialField& mf = fields[fi];
        const uint64_t row = k - field_base[fi];
        const uint64_t e0 = mf.rows.offset[row], e1 = mf.rows.offset[row + 1];
        const uint64_t keep =
            brdf_terms == UINT64_MAX ? e1 - e0 : std::min<uint64_t>(e1 - e0, mf.scaling[row] + brdf_terms);
        unsigned lit = 0;  // faces of the row with a non-zero coefficient
        for (uint64_t e = e0; e < e0 + keep; ++e) {
          sc.rho[mf.rows.col[e]] = mf.rows.val[e];
          if (mf.rows.val[e] != 0) lit |= 1u << (mf.rows.col[e] >> face_shift);
        }
        for (uint64_t f = 0; f < 6; ++f) {
          if (!(lit >> f & 1)) continue;
          InverseHaarFace(sc.rho.data() + f * face, levels, sc.rho_px.data());
          LitForward(light.data() + f * face * kLanes, sc.rho_px.data(), levels, sc.lit_px.data(),
                     sc.g.data() + f * face * kLanes);
        }
        for (uint64_t e = e0; e < e0 + keep; ++e) sc.rho[mf.rows.col[e]] = 0;
        faces_lit += static_cast<uint64_t>(std::popcount(lit));
        for (uint64_t q = b.first[k]; q < b.first[k + 1]; ++q) {
          const uint64_t s = b.part[q];
          const uint64_t* fb = face_begin.data() + part_vertex[s] * 7;
          D4 acc[2] = {{0, 0, 0, 0}, {0, 0, 0, 0}};  // two chains: the loads' latency overlaps
          for (uint64_t f = 0; f < 6; ++f) {
            if (!(lit >> f & 1)) continue;
            for (uint64_t e = fb[f]; e < fb[f + 1]; ++e) {
              const F4 g = Load(sc.g.data() + uint64_t{vis.col[e]} * kLanes);
              acc[e & 1] += static_cast<double>(vis.val[e]) * __builtin_convertvector(g, D4);
            }
          }
          const D4 sum = acc[0] + acc[1];
          for (int ch = 0; ch < 3; ++ch) contrib[s * 3 + ch] = rho.parts[s].weight * sum[ch];
        }
        return Status::Ok();
      });
  LTB_RETURN_IF_ERROR(st);
  out->assign(vertex_rows.size() * 3, 0.0);
  for (uint64_t i = 0; i < vertex_rows.size(); ++i) {  // the parts in their order: deterministic
    for (uint64_t s = rho.offset[i]; s < rho.offset[i + 1]; ++s)
      for (int ch = 0; ch < 3; ++ch) (*out)[i * 3 + ch] += contrib[s * 3 + ch];
  }
  if (stats) *stats = {.rows_lit = b.keys.size(), .faces_lit = faces_lit.load()};
  return Status::Ok();
}

}  // namespace ltb::triple
