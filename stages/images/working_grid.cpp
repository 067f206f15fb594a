// The working lat-long grid of the resampler (working_grid.h): a lat-long source averaged
// exactly onto it, crosses, faces and angular maps splatted into it.
#include "stages/images/working_grid.h"

#include <sys/mman.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <glm/geometric.hpp>

#include "stages/common/cubemap.h"
#include "stages/images/env_layout.h"
#include "stages/images/image_readers.h"

namespace ltb::stages::envmap_internal {
namespace {

// cos a − cos b without cancellation for nearby angles.
double CosDiff(double a, double b) { return 2.0 * std::sin(0.5 * (a + b)) * std::sin(0.5 * (b - a)); }

// Exact 1-D overlaps between a source grid of n_src equal cells and a target grid of n_dst
// equal cells over [0, 1]: for each target cell, (source cell, overlap [a, b]) with a and b
// as fractions. Integer arithmetic in units of 1/(n_src·n_dst), so aligned grids are exact.
struct Overlap {
  uint64_t src;
  double a, b;
};
std::vector<std::vector<Overlap>> Overlaps(uint64_t n_src, uint64_t n_dst) {
  std::vector<std::vector<Overlap>> out(n_dst);
  const double unit = 1.0 / (double(n_src) * double(n_dst));
  uint64_t i = 0;
  for (uint64_t j = 0; j < n_dst; ++j) {
    const uint64_t lo = j * n_src, hi = (j + 1) * n_src;
    while (i < n_src && (i + 1) * n_dst <= lo) ++i;
    for (uint64_t k = i; k < n_src && k * n_dst < hi; ++k) {
      const uint64_t a = std::max(lo, k * n_dst), b = std::min(hi, (k + 1) * n_dst);
      if (b > a) out[j].push_back({k, a * unit, b * unit});
    }
  }
  return out;
}

// A zeroed table of `count` doubles. Resample reads ~150·R² places of it per frame:
// on 2 MB pages (transparent huge pages, where the kernel grants them) the TLB covers the
// whole table, about 20% faster per frame than 4 KB pages. Shared: copies of a resampler
// share the (immutable) table.
std::shared_ptr<double[]> AllocateTable(uint64_t count) {
  constexpr size_t kHuge = size_t(2) << 20;
  const size_t bytes = count * sizeof(double);
  const size_t align = bytes >= 2 * kHuge ? kHuge : 64;
  const size_t rounded = (bytes + align - 1) / align * align;
  void* p = std::aligned_alloc(align, rounded);
  if (p == nullptr) return nullptr;
#ifdef MADV_HUGEPAGE
  if (align == kHuge) madvise(p, rounded, MADV_HUGEPAGE);  // advice only: failure is harmless
#endif
  std::memset(p, 0, rounded);
  return std::shared_ptr<double[]>(static_cast<double*>(p), [](double* q) { std::free(q); });
}

// Largest divisor g of n with n / g >= target (1 when n < target).
uint64_t GroupFor(uint64_t n, uint64_t target) {
  for (uint64_t g = std::max<uint64_t>(1, n / std::max<uint64_t>(1, target)); g > 1; --g) {
    if (n % g == 0 && n / g >= target) return g;
  }
  return 1;
}

// Sub-samples of a source (cube-face texels, angular-map pixels) splatted into the working
// lat-long grid: each adds its radiance × solid angle to the working pixel holding its
// centre direction; Finish divides by the solid angle gathered, and gives a pixel no
// sub-sample reached (thin ones near the poles) the source at its centre direction.
struct WorkingSplat {
  uint64_t hw, ww;
  std::vector<double> ldw, dw;
  WorkingSplat(uint64_t rows, uint64_t cols) : hw(rows), ww(cols), ldw(rows * cols * 3, 0.0), dw(rows * cols, 0.0) {}
  void Add(const glm::dvec3& d, const float* L, double domega) {
    double lu, lv;
    DirectionToLatLong(d, &lu, &lv);
    const uint64_t I = std::min<uint64_t>(uint64_t(lu * ww), ww - 1);
    const uint64_t J = std::min<uint64_t>(uint64_t(lv * hw), hw - 1);
    dw[J * ww + I] += domega;
    for (int c = 0; c < 3; ++c) ldw[(J * ww + I) * 3 + c] += L[c] * domega;
  }
  // at(direction) -> const float*: the source pixel holding a direction.
  template <typename At>
  void Finish(std::vector<double>* work, At at) const {
    work->assign(hw * ww * 3, 0.0);
    for (uint64_t J = 0; J < hw; ++J)
      for (uint64_t I = 0; I < ww; ++I) {
        const uint64_t px = J * ww + I;
        if (dw[px] > 0) {
          for (int c = 0; c < 3; ++c) (*work)[px * 3 + c] = ldw[px * 3 + c] / dw[px];
        } else {
          const float* L = at(LatLongDirection((I + 0.5) / ww, (J + 0.5) / hw));
          for (int c = 0; c < 3; ++c) (*work)[px * 3 + c] = L[c];
        }
      }
  }
};

// A lat-long source: a separable exact area average.
Status LatLongToWorking(const EnvMap& env, uint64_t R, const Progress& progress, WorkingGrid* g) {
  const uint64_t W = env.width, H = env.height;
  // Rows: whole groups of source rows when that lands at or above the target; a source with
  // fewer rows keeps them (each piece of a texel edge is exact over a row of any height).
  if (H >= g->target_rows) {
    g->hw = H / GroupFor(H, g->target_rows);
    if (g->hw > 4 * g->target_rows) g->hw = g->target_rows;  // no usable divisor: fractional rows
  } else {
    g->hw = H;
  }
  if (W >= g->target_cols) {
    g->ww = W / GroupFor(W, g->target_cols);
    if (g->ww > 4 * g->target_cols) g->ww = g->target_cols;
  } else {
    g->ww = W;
  }
  for (uint64_t j = 0; j < H; ++j) {
    LTB_RETURN_IF_ERROR(PollCancel(progress, env.path, R, j, "source power"));
    double omega = CosDiff(kPi * j / H, kPi * (j + 1) / H) * 2.0 * kPi / W;
    double s[3] = {0, 0, 0};
    for (uint64_t i = 0; i < W; ++i)
      for (int c = 0; c < 3; ++c) s[c] += env.rgb[(j * W + i) * 3 + c];
    for (int c = 0; c < 3; ++c) g->power[c] += s[c] * omega;
  }
  // Separable exact area average: θ overlaps weigh by Δcos θ, φ overlaps by length.
  auto rows = Overlaps(H, g->hw), cols = Overlaps(W, g->ww);
  std::vector<double>& work = g->work;
  work.assign(g->hw * g->ww * 3, 0.0);
  std::vector<double> row(W * 3);
  for (uint64_t J = 0; J < g->hw; ++J) {
    LTB_RETURN_IF_ERROR(PollCancel(progress, env.path, R, J, "working grid"));
    std::fill(row.begin(), row.end(), 0.0);
    double wsum = 0;
    for (const Overlap& o : rows[J]) {
      const double wt = CosDiff(kPi * o.a, kPi * o.b);
      wsum += wt;
      const float* src = &env.rgb[o.src * W * 3];
      for (uint64_t k = 0; k < W * 3; ++k) row[k] += wt * src[k];
    }
    for (uint64_t I = 0; I < g->ww; ++I) {
      double s[3] = {0, 0, 0}, lsum = 0;
      for (const Overlap& o : cols[I]) {
        const double wt = o.b - o.a;
        lsum += wt;
        for (int c = 0; c < 3; ++c) s[c] += wt * row[o.src * 3 + c];
      }
      for (int c = 0; c < 3; ++c) work[(J * g->ww + I) * 3 + c] = s[c] / (wsum * lsum);
    }
  }
  return Status::Ok();
}

// Cube faces (a cross or six faces): sub-texels splatted into the working grid.
Status FacesToWorking(const EnvMap& env, uint64_t R, const Progress& progress, WorkingGrid* g) {
  const FaceGeometry fg = FacesOf(env);
  const uint64_t F = fg.size;
  if (F == 0) return InvalidArgument(env.path + ": " + Size(env.width, env.height) + " holds no cube faces");
  g->hw = g->target_rows;
  g->ww = g->target_cols;
  auto source = [&](int f, uint64_t s, uint64_t t) {
    return &env.rgb[((fg.y0[f] + t) * env.width + fg.x0[f] + s) * 3];
  };
  for (int f = 0; f < 6; ++f)
    for (uint64_t t = 0; t < F; ++t) {
      LTB_RETURN_IF_ERROR(PollCancel(progress, env.path, R, t, "source power"));
      for (uint64_t s = 0; s < F; ++s) {
        const double omega = cubemap::TexelSolidAngle({f, uint32_t(s), uint32_t(t)}, uint32_t(F));
        for (int c = 0; c < 3; ++c) g->power[c] += source(f, s, t)[c] * omega;
      }
    }
  // Splat k×k sub-texels of each source texel (exact solid angles) into the working pixel
  // holding their centre; sub-texels about half a working row across at the face centre.
  uint64_t k = std::max<uint64_t>(1, uint64_t(std::ceil(4.0 * g->hw / (kPi * F))));
  while (k > 1 && 6 * F * F * k * k > (1ull << 25)) --k;
  const uint64_t m = k * F;
  std::vector<double> corner((m + 1) * (m + 1));
  for (uint64_t q = 0; q <= m; ++q)
    for (uint64_t p = 0; p <= m; ++p) {
      const double x = -1.0 + 2.0 * p / m, y = -1.0 + 2.0 * q / m;
      corner[q * (m + 1) + p] = std::atan2(x * y, std::sqrt(x * x + y * y + 1.0));
    }
  WorkingSplat splat(g->hw, g->ww);
  for (int f = 0; f < 6; ++f)
    for (uint64_t q = 0; q < m; ++q) {
      LTB_RETURN_IF_ERROR(PollCancel(progress, env.path, R, q, "working grid"));
      const double v = -1.0 + 2.0 * (q + 0.5) / m;
      for (uint64_t p = 0; p < m; ++p) {
        const double u = -1.0 + 2.0 * (p + 0.5) / m;
        const double domega = corner[(q + 1) * (m + 1) + p + 1] - corner[(q + 1) * (m + 1) + p] -
                              corner[q * (m + 1) + p + 1] + corner[q * (m + 1) + p];
        splat.Add(cubemap::FaceDirection(f, u, v), source(f, p / k, q / k), domega);
      }
    }
  splat.Finish(&g->work, [&](const glm::dvec3& d) {
    const cubemap::Texel x = cubemap::DirectionToTexel(d, uint32_t(F));
    return source(x.face, x.s, x.t);
  });
  return Status::Ok();
}

// An angular map: as for cube faces, k×k sub-pixels of each source pixel splatted into the
// working pixel holding their centre direction, each weighing its solid angle
// π·sin(πr)/r·du·dv (the map is equi-angular in r: dω = sin θ dθ dφ with θ = πr).
// Sub-pixels about half a working row across (a pixel spans 2π/W in θ).
Status AngularToWorking(const EnvMap& env, uint64_t R, const Progress& progress, WorkingGrid* g) {
  const uint64_t W = env.width;
  g->hw = g->target_rows;
  g->ww = g->target_cols;
  uint64_t k = std::max<uint64_t>(1, uint64_t(std::ceil(4.0 * double(g->hw) / double(W))));
  while (k > 1 && W * W * k * k > (1ull << 25)) --k;
  const double du = 2.0 / double(W * k);
  WorkingSplat splat(g->hw, g->ww);
  for (uint64_t y = 0; y < W * k; ++y) {
    LTB_RETURN_IF_ERROR(PollCancel(progress, env.path, R, y, "working grid"));
    const double v = 1.0 - (double(y) + 0.5) * du;
    for (uint64_t x = 0; x < W * k; ++x) {
      const double u = -1.0 + (double(x) + 0.5) * du;
      const double r = std::sqrt(u * u + v * v);
      if (r > 1.0) continue;
      const double domega = (r > 0 ? kPi * std::sin(kPi * r) / r : kPi * kPi) * du * du;
      const float* L = &env.rgb[((y / k) * W + x / k) * 3];
      splat.Add(AngularDirection(u, v), L, domega);
      for (int c = 0; c < 3; ++c) g->power[c] += L[c] * domega;
    }
  }
  splat.Finish(&g->work, [&](const glm::dvec3& d) {
    uint64_t x, y;
    DirectionToAngular(d, W, &x, &y);
    return &env.rgb[(y * W + x) * 3];
  });
  return Status::Ok();
}

}  // namespace

// "interrupted" when cancellation is asked for; polled every few rows (`i`) of each pass
// (a huge source or R = 512 takes seconds).
Status PollCancel(const Progress& progress, const std::string& path, uint64_t R, uint64_t i, const char* pass) {
  if (i % kRowsPerPoll != 0 || !progress.Cancelled()) return Status::Ok();
  return Cancelled(path + ": interrupted while resampling to the R = " + std::to_string(R) + " cubemap (" + pass + ")");
}

// The working grid of any layout.
Result<WorkingGrid> BuildWorkingGrid(const EnvMap& env, uint64_t R, const Progress& progress) {
  // Working grid targets: 16R rows (about a fifth of the smallest texel's side, 0.94/R rad at
  // the cube corners; for a lat-long source at least 512, so that a 1024 × 512 map keeps its
  // pixels, and the texel averages stay exact, at every R), twice as many columns (as wide as
  // rows are high at the equator); both halved while the table would pass 2^22 pixels
  // (100 MB).
  WorkingGrid g;
  g.target_rows = env.layout == EnvLayout::kLatLong ? std::max<uint64_t>(16 * R, 512) : 16 * R;
  g.target_cols = 2 * g.target_rows;
  while (g.target_rows * g.target_cols > (1ull << 22) && g.target_rows > 1) {
    g.target_rows /= 2;
    g.target_cols /= 2;
  }
  if (env.layout == EnvLayout::kLatLong) {
    LTB_RETURN_IF_ERROR(LatLongToWorking(env, R, progress, &g));
  } else if (env.layout == EnvLayout::kHCross || env.layout == EnvLayout::kVCross || env.layout == EnvLayout::kFaces) {
    LTB_RETURN_IF_ERROR(FacesToWorking(env, R, progress, &g));
  } else if (env.layout == EnvLayout::kAngular) {
    LTB_RETURN_IF_ERROR(AngularToWorking(env, R, progress, &g));
  } else {
    return InvalidArgument(env.path + ": environment map layout is unresolved (auto)");
  }
  return g;
}

// The working grid as the table Resample reads: hw × ww × 3 values, + 1 pad (the last
// 4-lane load).
Result<std::shared_ptr<double[]>> WorkingTable(const std::string& path, const WorkingGrid& g) {
  std::shared_ptr<double[]> table = AllocateTable(g.hw * g.ww * 3 + 1);
  if (table == nullptr) {
    return InvalidArgument(path + ": no memory for the " + std::to_string(g.hw) + " x " + std::to_string(g.ww) +
                           " working grid");
  }
  std::copy(g.work.begin(), g.work.end(), table.get());
  return table;
}

}  // namespace ltb::stages::envmap_internal
