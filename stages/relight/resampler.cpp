// CubemapResampler (resampler.h): the source reduced to a working lat-long grid held as
// prefix sums, the texel edges cut into pieces per working row, and Resample.
#include "stages/relight/resampler.h"

#include <sys/mman.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <glm/geometric.hpp>
#include <new>
#include <utility>

#include "stages/common/cubemap.h"
#include "stages/relight/env_layout.h"
#include "stages/relight/envmap.h"
#include "stages/relight/image_readers.h"

namespace ltb::stages {

using envmap_internal::AngularDirection;
using envmap_internal::DirectionToAngular;
using envmap_internal::FaceGeometry;
using envmap_internal::FacesOf;
using envmap_internal::kPi;
using envmap_internal::kRowsPerPoll;
using envmap_internal::Size;

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

// "interrupted" when cancellation is asked for; polled every few rows (`i`) of each pass
// (a huge source or R = 512 takes seconds).
Status PollCancel(const Progress& progress, const std::string& path, uint64_t R, uint64_t i, const char* pass) {
  if (i % kRowsPerPoll != 0 || !progress.Cancelled()) return Status::Ok();
  return Cancelled(path + ": interrupted while resampling to the R = " + std::to_string(R) + " cubemap (" + pass + ")");
}

// The source reduced to the working lat-long grid: hw × ww × 3 values (`work`), and the
// source's power (Σ radiance × solid angle).
struct WorkingGrid {
  uint64_t hw = 0, ww = 0;
  uint64_t target_rows = 0, target_cols = 0;
  double power[3] = {0, 0, 0};
  std::vector<double> work;
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

// The working grid of any layout.
Result<WorkingGrid> BuildWorkingGrid(const EnvMap& env, uint64_t R, const Progress& progress) {
  // Working grid targets: 16R rows (about a fifth of the smallest texel's side, 0.94/R rad at
  // the cube corners; for a lat-long source at least 512, so that a 1024 × 512 map keeps its
  // pixels, and the texel averages stay exact, at every R), twice as many columns (as wide as
  // rows are high at the equator); both halved while the prefix table would pass 2^22 pixels
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

// Prefix sums per working row (radiance × working columns): hw × (ww + 1) × 3, + 1 pad.
Result<std::shared_ptr<double[]>> PrefixSums(const std::string& path, const WorkingGrid& g) {
  const uint64_t ww = g.ww, hw = g.hw;
  std::shared_ptr<double[]> table = AllocateTable(hw * (ww + 1) * 3 + 1);  // + 1: the last 4-lane load
  if (table == nullptr) {
    return InvalidArgument(path + ": no memory for the " + std::to_string(hw) + " x " + std::to_string(ww) +
                           " working grid");
  }
  for (uint64_t J = 0; J < hw; ++J) {
    double* P = table.get() + J * (ww + 1) * 3;
    for (uint64_t I = 0; I < ww; ++I)
      for (int c = 0; c < 3; ++c) P[(I + 1) * 3 + c] = P[I * 3 + c] + g.work[(J * ww + I) * 3 + c];
  }
  return table;
}

// The seam: working column where pieces of texel edges are cut, so that each lies in
// [kSeamColumn, kSeamColumn + ww). Not a multiple of a column's fraction that any meridian
// texel edge takes (those are at φ multiples of 90° and at φ = ±atan(v) of side-face lines).
constexpr double kSeamColumn = 0.30901699437494745;

// 8-point Gauss–Legendre nodes and weights on [−1, 1] (the positive half).
constexpr double kGaussX[4] = {0.1834346424956498, 0.5255324099163290, 0.7966664774136267, 0.9602898564975363};
constexpr double kGaussW[4] = {0.3626837833783620, 0.3137066458778873, 0.2223810344533745, 0.1012285362903763};

// A texel edge that is not along a meridian: the great circle n·d = 0 (n.z != 0) meets the
// meridian of working column c (φ = π − 2πc/ww) in one point, at height
// z(c) = q/√(1 + q²), q = z/ρ = −(n.x cos φ + n.y sin φ)/n.z.
struct ArcOverColumns {
  glm::dvec3 n;
  double ww;
  double Z(double c) const {
    const double phi = kPi - 2.0 * kPi * c / ww;
    const double q = -(n.x * std::cos(phi) + n.y * std::sin(phi)) / n.z;
    return q / std::sqrt(1.0 + q * q);
  }
  double Slope(double c) const {  // dz/dc
    const double phi = kPi - 2.0 * kPi * c / ww;
    const double q = -(n.x * std::cos(phi) + n.y * std::sin(phi)) / n.z;
    const double dq = (n.x * std::sin(phi) - n.y * std::cos(phi)) / n.z;
    return dq * (-2.0 * kPi / ww) / ((1.0 + q * q) * std::sqrt(1.0 + q * q));
  }
  // ∫_0^t (z_end − z(c0 + τ)) dτ by 8-point Gauss–Legendre (z is smooth, and the pieces are
  // a small part of its scale: halving a piece shrinks this error by 2^16).
  double K(double c0, double z_end, double t) const {
    double sum = 0;
    const double h = 0.5 * t, mid = c0 + h;
    for (int i = 0; i < 4; ++i) sum += kGaussW[i] * (Z(mid - h * kGaussX[i]) + Z(mid + h * kGaussX[i]));
    return t * z_end - h * sum;
  }
  // The column in [a, b] where z = target, z monotone on [a, b] from za to zb (target between):
  // Newton steps kept inside a shrinking bracket.
  double Solve(double a, double za, double b, double zb, double target) const {
    const bool rising = zb > za;
    double lo = a, hi = b;
    double c = a + (b - a) * (target - za) / (zb - za);
    if (!(c > lo && c < hi)) c = 0.5 * (lo + hi);
    for (int it = 0; it < 100; ++it) {
      const double f = Z(c) - target;
      if (f == 0) return c;
      if ((f < 0) == rising) {
        lo = c;
      } else {
        hi = c;
      }
      if (hi - lo <= 1e-13 * std::max(1.0, std::abs(c))) break;
      const double d = Slope(c);
      double next = d != 0 ? c - f / d : 0.5 * (lo + hi);
      if (!(next > lo && next < hi)) next = 0.5 * (lo + hi);
      if (std::abs(next - c) <= 1e-15 * std::max(1.0, std::abs(c))) return next;
      c = next;
    }
    return 0.5 * (lo + hi);
  }
};

// The cubic Hermite K of a piece (resampler.h): K(0) = 0, K'(0) = dz, K(w) = kw, K'(w) = 0.
inline double HermiteK(double dz, double w, double kw, double t) {
  const double x = t / w;
  return dz * w * x * (1.0 - x) * (1.0 - x) + kw * x * x * (3.0 - 2.0 * x);
}

// Row J of the working grid holds z in [zrow[J + 1], zrow[J]].
uint64_t RowHolding(const std::vector<double>& zrow, double z) {
  uint64_t lo = 0, hi = zrow.size() - 1;
  while (hi - lo > 1) {
    const uint64_t mid = (lo + hi) / 2;
    if (zrow[mid] >= z) {
      lo = mid;
    } else {
      hi = mid;
    }
  }
  return lo;
}

// Working column of a direction, in [0, ww).
double ColumnOf(const glm::dvec3& d, double ww) {
  double c = (kPi - std::atan2(d.y, d.x)) / (2.0 * kPi) * ww;
  if (c >= ww) c -= ww;
  if (c < 0) c += ww;
  return c;
}

// c + k·ww closest to `near`.
double LiftNear(double c, double near, double ww) { return c + ww * std::round((near - c) / ww); }

}  // namespace

Result<CubemapResampler> CubemapResampler::Create(const EnvMap& env, uint64_t cube_res, const Progress& progress) {
  // The tables are bounded by R (and the working grid by 2^22 pixels), but a row of the
  // source is held in double: a lat-long map of extreme width may not fit. No exception
  // leaves the library.
  try {
    return CreateUnchecked(env, cube_res, progress);
  } catch (const std::bad_alloc&) {
    return InvalidArgument(env.path + ": no memory to resample the " + Size(env.width, env.height) +
                           " map to an R = " + std::to_string(cube_res) + " cubemap");
  }
}

Result<CubemapResampler> CubemapResampler::CreateUnchecked(const EnvMap& env, uint64_t cube_res,
                                                           const Progress& progress) {
  if (cube_res < 1 || cube_res > kMaxCubeRes) {
    return InvalidArgument("cubemap resolution " + std::to_string(cube_res) + " is outside 1.." +
                           std::to_string(kMaxCubeRes));
  }
  if (env.width == 0 || env.height == 0 || env.rgb.size() != env.width * env.height * 3) {
    return InvalidArgument(env.path + ": environment map holds " + std::to_string(env.rgb.size()) +
                           " values, its size " + Size(env.width, env.height) + " needs 3 per pixel");
  }
  const uint64_t R = cube_res, n = 6 * R * R;
  CubemapResampler rs;
  rs.r_ = R;
  rs.omega_.resize(n);
  for (uint64_t t = 0; t < n; ++t) rs.omega_[t] = cubemap::TexelSolidAngle(cubemap::ColumnToTexel(t, R), uint32_t(R));

  LTB_ASSIGN_OR_RETURN(WorkingGrid grid, BuildWorkingGrid(env, R, progress));
  rs.hw_ = grid.hw;
  rs.ww_ = grid.ww;
  for (int c = 0; c < 3; ++c) rs.power_[c] = grid.power[c];
  LTB_ASSIGN_OR_RETURN(rs.prefix_, PrefixSums(env.path, grid));
  grid.work = {};

  std::vector<double> dsum(n, 0.0);
  LTB_RETURN_IF_ERROR(rs.BuildPieces(env.path, progress, &dsum));
  rs.Normalise(dsum);
  return rs;
}

// Pieces: every texel edge (the great-circle arc between two neighbouring grid corners of a
// face; an edge on a cube edge once) cut where it crosses a working row's boundary or the
// seam, then halved until the cubic Hermite K of each piece is within kPieceTolerance of a
// working pixel's area (1 column × the row's height in z; at most a pixel of a 32R × 16R grid)
// of the exact K half-way along it. And the seam terms: the texels the seam meridian passes
// through, per row.
Status CubemapResampler::BuildPieces(const std::string& path, const Progress& progress, std::vector<double>* dsum) {
  constexpr double kPieceTolerance = 1e-5;
  const uint64_t R = r_, ww = ww_, hw = hw_;
  const double wwd = double(ww), scale = 2.0 * kPi / wwd;
  const uint32_t r32 = uint32_t(R);
  // Row boundaries in z, exactly antisymmetric (the equator exactly 0 when it is one).
  std::vector<double> zrow(hw + 1);
  for (uint64_t J = 0; J <= hw; ++J) zrow[J] = std::cos(kPi * double(J) / double(hw));
  for (uint64_t J = 0; 2 * J <= hw; ++J) zrow[hw - J] = -zrow[J];
  zrow[0] = 1.0;
  zrow[hw] = -1.0;
  if (hw % 2 == 0) zrow[hw / 2] = 0.0;

  std::vector<Piece> pieces;
  std::vector<uint32_t> piece_row;
  auto emit = [&](uint64_t J, double c, double w, double dz, double kw, uint32_t up, uint32_t down) {
    c -= wwd * std::floor((c - kSeamColumn) / wwd);
    if (c >= kSeamColumn + wwd) c -= wwd;
    Piece p;
    p.c = c;
    p.dz = dz * scale;
    p.w = float(w);
    p.kw = float(kw * scale);
    p.up = up;
    p.down = down;
    pieces.push_back(p);
    piece_row.push_back(uint32_t(J));
  };
  // A piece of a non-meridian edge from (c0, z0) to (c1, z1) inside row J, halved while its
  // Hermite K is off by more than the tolerance.
  auto emit_arc = [&](auto&& self, const ArcOverColumns& arc, uint64_t J, double c0, double z0, double c1, double z1,
                      uint32_t up, uint32_t down, int depth) -> void {
    const double w = c1 - c0;
    if (!(w > 0)) return;
    const double dz = z1 - z0, kw = arc.K(c0, z1, w);
    // The area the tolerance is a fraction of: a working pixel, or a pixel of a 32R × 16R grid
    // where that is smaller (a source coarser than the cubemap): texels are ≥ 5 of those across.
    const double pixel =
        std::min(1.0, wwd / (32.0 * double(R))) * std::min(zrow[J] - zrow[J + 1], kPi / (16.0 * double(R)));
    if (depth < 40 && w > 0.5 * kPieceTolerance) {
      // The Hermite error, t²(w − t)²/24 times the fourth derivative of K, peaks mid-way.
      if (std::abs(arc.K(c0, z1, 0.5 * w) - HermiteK(dz, w, kw, 0.5 * w)) > kPieceTolerance * pixel) {
        const double cm = 0.5 * (c0 + c1), zm = arc.Z(cm);
        self(self, arc, J, c0, z0, cm, zm, up, down, depth + 1);
        self(self, arc, J, cm, zm, c1, z1, up, down, depth + 1);
        return;
      }
    }
    emit(J, c0, w, dz, kw, up, down);
  };
  // The row boundaries strictly between z values a and b, in the order met from a to b.
  std::vector<uint64_t> crossed;
  auto boundaries_between = [&](double a, double b) {
    crossed.clear();
    const double lo = std::min(a, b), hi = std::max(a, b);
    for (uint64_t J = RowHolding(zrow, hi); J <= hw && J <= RowHolding(zrow, lo) + 1; ++J) {
      if (zrow[J] > lo && zrow[J] < hi) crossed.push_back(J);
    }
    if (b > a) std::reverse(crossed.begin(), crossed.end());
  };

  std::vector<std::pair<double, double>> marks;  // (column, z) where an edge is cut
  struct SeamCrossing {
    double z;
    uint32_t below, above;
  };
  std::vector<SeamCrossing> seam_crossings;  // where edges cross the seam meridian
  for (int f = 0; f < 6; ++f)
    for (int family = 0; family < 2; ++family)
      for (uint64_t k = 0; k <= R; ++k) {
        LTB_RETURN_IF_ERROR(PollCancel(progress, path, R, (uint64_t(f) * 2 + family) * (R + 1) + k, "texel edges"));
        const double fixed = -1.0 + 2.0 * double(k) / double(R);
        for (uint64_t e = 0; e < R; ++e) {
          const double a = -1.0 + 2.0 * double(e) / double(R), b = -1.0 + 2.0 * double(e + 1) / double(R);
          const glm::dvec3 fa = family == 0 ? cubemap::FaceDirection(f, fixed, a) : cubemap::FaceDirection(f, a, fixed);
          const glm::dvec3 fb = family == 0 ? cubemap::FaceDirection(f, fixed, b) : cubemap::FaceDirection(f, b, fixed);
          const glm::dvec3 A = glm::normalize(fa), B = glm::normalize(fb), M = glm::normalize(A + B);
          const glm::dvec3 normal = glm::cross(fa, fb);
          const bool meridian = std::abs(normal.z) <= 1e-12 * glm::length(normal);
          // The texels on either side: above and below it, or left and right of a meridian
          // piece (left: larger φ, smaller column), probed 1e-7 rad away.
          glm::dvec3 p_up, p_down;
          if (meridian) {
            const double ce = std::cos(1e-7), se = std::sin(1e-7);
            p_up = {M.x * ce - M.y * se, M.x * se + M.y * ce, M.z};
            p_down = {M.x * ce + M.y * se, -M.x * se + M.y * ce, M.z};
          } else {
            const double phi = std::atan2(M.y, M.x);
            for (int side = 0; side < 2; ++side) {
              const double z = std::clamp(M.z + (side == 0 ? 1e-7 : -1e-7), -1.0, 1.0);
              const double rho = std::sqrt(std::max(0.0, 1.0 - z * z));
              (side == 0 ? p_up : p_down) = {rho * std::cos(phi), rho * std::sin(phi), z};
            }
          }
          const uint32_t up = uint32_t(cubemap::Column(cubemap::DirectionToTexel(p_up, r32), r32));
          const uint32_t down = uint32_t(cubemap::Column(cubemap::DirectionToTexel(p_down, r32), r32));
          if (up == down) continue;
          // An edge on a cube edge is met from both faces: kept from the lower face index.
          const uint64_t other = up / (R * R) != uint64_t(f) ? up / (R * R) : down / (R * R);
          if (other < uint64_t(f)) continue;
          if (meridian) {
            const double c = ColumnOf(M, wwd), zlo = std::min(A.z, B.z), zhi = std::max(A.z, B.z);
            boundaries_between(zlo, zhi);
            double z0 = zlo;
            for (size_t i = 0; i <= crossed.size(); ++i) {
              const double z1 = i < crossed.size() ? zrow[crossed[i]] : zhi;
              if (z1 > z0) emit(RowHolding(zrow, 0.5 * (z0 + z1)), c, 0.0, z1 - z0, 0.0, up, down);
              z0 = z1;
            }
            continue;
          }
          const ArcOverColumns arc{glm::normalize(normal), wwd};
          double c_a = ColumnOf(A, wwd), z_a = A.z;
          double c_b = LiftNear(ColumnOf(B, wwd), LiftNear(ColumnOf(M, wwd), c_a, wwd), wwd), z_b = B.z;
          if (c_a > c_b) {
            std::swap(c_a, c_b);
            std::swap(z_a, z_b);
          }
          marks.clear();
          marks.push_back({c_a, z_a});
          auto cut_rows = [&](double c0, double z0, double c1, double z1) {
            boundaries_between(z0, z1);
            for (uint64_t J : crossed) marks.push_back({arc.Solve(c0, z0, c1, z1, zrow[J]), zrow[J]});
          };
          // z along the arc has at most one extremum inside (dz/dc = 0 at φ = atan2(n.y, n.x) or
          // opposite); z is monotone on either side of it.
          double apex = c_a;
          const double phi_star = std::atan2(arc.n.y, arc.n.x);
          for (double candidate :
               {(kPi - phi_star) / (2.0 * kPi) * wwd, (kPi - phi_star) / (2.0 * kPi) * wwd + 0.5 * wwd}) {
            const double c = LiftNear(candidate, 0.5 * (c_a + c_b), wwd);
            if (c > c_a && c < c_b) apex = c;
          }
          if (apex > c_a) {
            const double z_apex = arc.Z(apex);
            cut_rows(c_a, z_a, apex, z_apex);
            cut_rows(apex, z_apex, c_b, z_b);
          } else {
            cut_rows(c_a, z_a, c_b, z_b);
          }
          marks.push_back({c_b, z_b});
          for (double s = kSeamColumn + wwd * std::ceil((c_a - kSeamColumn) / wwd); s < c_b; s += wwd) {
            if (!(s > c_a)) continue;
            marks.push_back({s, arc.Z(s)});
            seam_crossings.push_back({arc.Z(s), down, up});
          }
          std::stable_sort(marks.begin(), marks.end(), [](const auto& x, const auto& y) { return x.first < y.first; });
          for (size_t i = 0; i + 1 < marks.size(); ++i) {
            const double c0 = marks[i].first, c1 = marks[i + 1].first;
            if (!(c1 > c0)) continue;
            const uint64_t J = RowHolding(zrow, arc.Z(0.5 * (c0 + c1)));
            emit_arc(emit_arc, arc, J, c0, marks[i].second, c1, marks[i + 1].second, up, down, 0);
          }
        }
      }

  // Seam terms: walking up the seam meridian from the south pole, the texel changes where an
  // edge crosses it (from the texel below that edge to the one above), split at row boundaries.
  std::sort(seam_crossings.begin(), seam_crossings.end(),
            [](const SeamCrossing& x, const SeamCrossing& y) { return x.z < y.z; });
  uint32_t current = 0;
  if (seam_crossings.empty()) {
    const double phi = kPi - 2.0 * kPi * kSeamColumn / wwd;
    current = uint32_t(
        cubemap::Column(cubemap::DirectionToTexel({1e-9 * std::cos(phi), 1e-9 * std::sin(phi), -1.0}, r32), r32));
  } else {
    current = seam_crossings[0].below;
  }
  size_t next = 0;
  for (uint64_t J = hw; J-- > 0;) {
    double z0 = zrow[J + 1];
    const double z1 = zrow[J];
    for (; next < seam_crossings.size() && seam_crossings[next].z < z1; ++next) {
      const double z = std::max(z0, seam_crossings[next].z);
      if (z > z0) seam_.push_back({uint32_t(J), current, (z - z0) * scale});
      z0 = z;
      current = seam_crossings[next].above;
    }
    if (z1 > z0) seam_.push_back({uint32_t(J), current, (z1 - z0) * scale});
  }

  // By row, then column (Resample reads each row's prefix sums in order).
  std::vector<uint64_t> order(pieces.size());
  for (uint64_t i = 0; i < order.size(); ++i) order[i] = i;
  std::sort(order.begin(), order.end(), [&](uint64_t x, uint64_t y) {
    return piece_row[x] != piece_row[y] ? piece_row[x] < piece_row[y] : pieces[x].c < pieces[y].c;
  });
  pieces_.resize(pieces.size());
  row_first_.assign(hw + 1, 0);
  for (uint64_t i = 0; i < order.size(); ++i) {
    pieces_[i] = pieces[order[i]];
    ++row_first_[piece_row[order[i]] + 1];
  }
  for (uint64_t J = 0; J < hw; ++J) row_first_[J + 1] += row_first_[J];
  // Each texel's solid angle as the pieces see it: the same sums over a map of ones, whose
  // prefix function is S(x) = x (x = c at rotation 0; the seam terms see the row total ww).
  for (const Piece& p : pieces_) {
    const double v = p.dz * p.c + double(p.kw);
    (*dsum)[p.up] += v;
    (*dsum)[p.down] -= v;
  }
  for (const SeamTerm& s : seam_) (*dsum)[s.texel] += s.weight * wwd;
  return Status::Ok();
}

void CubemapResampler::Normalise(const std::vector<double>& dsum) {
  const uint64_t R = r_, n = 6 * R * R, ww = ww_, hw = hw_;
  texel_scale_.resize(n);
  for (uint64_t t = 0; t < n; ++t) {
    if (dsum[t] > 0) {
      texel_scale_[t] = 1.0 / dsum[t];
      continue;
    }
    texel_scale_[t] = 1.0;
    double u, v;
    DirectionToLatLong(cubemap::TexelCenter(cubemap::ColumnToTexel(t, R), uint32_t(R)), &u, &v);
    empty_.push_back({t, uint32_t(std::min<uint64_t>(uint64_t(v * hw), hw - 1)), u * ww});
  }
}

namespace {
// R, G, B and an unused lane: one AVX register, or two SSE2 ones. Passed by pointer only
// (a by-value 32-byte vector changes the ABI between AVX and non-AVX builds).
using Vec4 = double __attribute__((vector_size(32)));
inline void Load(const double* p, Vec4* v) { std::memcpy(v, p, sizeof *v); }
}  // namespace

void CubemapResampler::Resample(double rotation, float* out) const {
  const uint64_t n = 6 * r_ * r_, ww = ww_;
  const double wwd = double(ww);
  thread_local std::vector<Vec4> scratch;
  scratch.assign(n, Vec4{0, 0, 0, 0});
  Vec4* const acc = scratch.data();
  // The rotated map at working column c is the source at c + shift (docs/ENVMAPS.md).
  double turns = rotation / (2.0 * kPi);
  turns -= std::floor(turns);
  double shift = turns * wwd;
  if (!(shift >= 0.0 && shift < wwd)) shift = 0.0;
  const size_t stride = (ww + 1) * 3;
  const int64_t last = int64_t(ww) - 1;
  for (uint64_t J = 0; J < hw_; ++J) {
    const double* P = prefix_.get() + J * stride;
    Vec4 total;
    Load(P + ww * 3, &total);
    const Piece* piece = pieces_.data() + row_first_[J];
    const Piece* end = pieces_.data() + row_first_[J + 1];
    for (; piece != end; ++piece) {
      // S at the piece's start x = c + shift (∫_0^x of the row, extended periodically: each
      // pass of ww adds the row total), then Σ L·ΔK over the columns it crosses. Lane 3 is
      // the next column's R: ignored.
      double x = piece->c + shift;
      Vec4 wrap = {0, 0, 0, 0};
      while (x >= wwd) {
        x -= wwd;
        wrap += total;
      }
      const int64_t i = std::min<int64_t>(int64_t(x), last);
      const double f = x - double(i);
      Vec4 p0, p1;
      Load(P + 3 * i, &p0);
      Load(P + 3 * i + 3, &p1);
      const Vec4 li = p1 - p0;
      Vec4 v = piece->dz * (p0 + f * li + wrap);
      const double w = piece->w, kw = piece->kw, t1 = 1.0 - f;
      if (t1 >= w) {
        v += kw * li;
      } else {
        // K(t) = t·(dz + t·(a2 + t·a3)), the Hermite cubic (HermiteK) in powers of t.
        const double dz = piece->dz, inv = 1.0 / w, dzw = dz * w;
        const double a3 = (dzw - 2.0 * kw) * inv * inv * inv, a2 = (3.0 * kw - 2.0 * dzw) * inv * inv;
        double k_prev = t1 * (dz + t1 * (a2 + t1 * a3));
        v += k_prev * li;
        int64_t j = i + 2;
        Vec4 q0 = p1, q1;
        for (double t = t1 + 1.0;; t += 1.0, ++j) {
          if (j > int64_t(ww)) {  // past the row's end: on from column 0
            j -= int64_t(ww);
            Load(P, &q0);
          }
          Load(P + 3 * j, &q1);
          if (t >= w) {
            v += (kw - k_prev) * (q1 - q0);
            break;
          }
          const double k_next = t * (dz + t * (a2 + t * a3));
          v += (k_next - k_prev) * (q1 - q0);
          k_prev = k_next;
          q0 = q1;
        }
      }
      acc[piece->up] += v;
      acc[piece->down] -= v;
    }
  }
  for (const SeamTerm& s : seam_) {
    Vec4 total;
    Load(prefix_.get() + s.row * stride + ww * 3, &total);
    acc[s.texel] += s.weight * total;
  }
  for (const EmptyTexel& e : empty_) {
    double x = e.column + shift;
    if (x >= wwd) x -= wwd;
    const uint64_t i = std::min<uint64_t>(uint64_t(x), ww - 1);
    const double* p = prefix_.get() + e.row * stride + i * 3;
    Vec4 p0, p1;
    Load(p, &p0);
    Load(p + 3, &p1);
    acc[e.texel] = p1 - p0;
  }
  // Texel radiance = Σ L dΩ / Σ dΩ, then one factor per channel so that Σ texel·Ω_texel
  // equals the source's power.
  Vec4 sum = {0, 0, 0, 0};
  for (uint64_t t = 0; t < n; ++t) sum += acc[t] * (texel_scale_[t] * omega_[t]);
  double g[3];
  for (int c = 0; c < 3; ++c) g[c] = sum[c] > 0 ? power_[c] / sum[c] : 1.0;
  for (uint64_t t = 0; t < n; ++t)
    for (int c = 0; c < 3; ++c) out[t * 3 + c] = float(acc[t][c] * texel_scale_[t] * g[c]);
}

}  // namespace ltb::stages
