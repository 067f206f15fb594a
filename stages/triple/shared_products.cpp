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

template <typename T>
void ForwardHaarLanes(T* m, int levels, T* coef) {
  // Level l's squares from the means of level l + 1 (in m, side 2^(l+1)), their means written
  // over m at j·side + i: every position written was read before (it precedes the block's own
  // first value, 2j·2side + 2i, in row-major order), so one buffer serves every level.
  for (int l = levels - 1; l >= 0; --l) {
    const uint64_t side = uint64_t{1} << l, fine = side * 2;
    const T scale = static_cast<T>(std::ldexp(1.0, -l - 2)), quarter = 0.25;
    for (uint64_t j = 0; j < side; ++j) {
      for (uint64_t i = 0; i < side; ++i) {
        const T* q00 = m + ((2 * j) * fine + 2 * i) * kLanes;  // q[qy][qx]
        const T* q01 = q00 + kLanes;
        const T* q10 = q00 + fine * kLanes;
        const T* q11 = q10 + kLanes;
        T* w = coef + (1 + 3 * SquareIndex(l, i, j)) * kLanes;
        T mean[kLanes];
        for (int k = 0; k < kLanes; ++k) {
          w[k] = scale * (q10[k] + q11[k] - q00[k] - q01[k]);               // type 01: +1 above
          w[kLanes + k] = scale * (q01[k] + q11[k] - q00[k] - q10[k]);      // type 10: +1 right
          w[2 * kLanes + k] = scale * (q00[k] + q11[k] - q01[k] - q10[k]);  // type 11: the product
          mean[k] = quarter * (q00[k] + q01[k] + q10[k] + q11[k]);
        }
        std::copy(mean, mean + kLanes, m + (j * side + i) * kLanes);
      }
    }
  }
  std::copy(m, m + kLanes, coef);
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
  std::vector<double> px(6 * face * kLanes, 0.0);
  double peak = 0;
  for (int ch = 0; ch < 3; ++ch) {
    for (uint64_t f = 0; f < 6; ++f) {
      std::vector<double> one(face);
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
using F4 = float __attribute__((vector_size(4 * sizeof(float))));
using D4 = double __attribute__((vector_size(4 * sizeof(double))));
static_assert(kLanes == 4);

// One thread's buffers for lighting rows: the row's coefficients (dense, 6R², zero outside
// the row), a face of ρ̃ pixels, a face of lit pixels and the lit row's coefficients.
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
          const float* l = light.data() + f * face * kLanes;
          for (uint64_t p = 0; p < face; ++p) {
            F4 x;
            std::memcpy(&x, l + p * kLanes, sizeof x);
            x *= sc.rho_px[p];
            std::memcpy(sc.lit_px.data() + p * kLanes, &x, sizeof x);
          }
          ForwardHaarLanes(sc.lit_px.data(), levels, sc.g.data() + f * face * kLanes);
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
              F4 g;
              std::memcpy(&g, sc.g.data() + uint64_t{vis.col[e]} * kLanes, sizeof g);
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
