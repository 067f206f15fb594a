// CubemapResampler (resampler.h): the source reduced to a working lat-long grid held as
// prefix sums, the latitude bands' column intervals per texel, and Resample.
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

// A zeroed table of `count` doubles. Resample reads ~50·R² scattered places of it per frame:
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

// The source reduced to the working lat-long grid: hw × ww × 3 values (`work`), `sub`
// latitude bands per working row, and the source's power (Σ radiance × solid angle).
struct WorkingGrid {
  uint64_t hw = 0, ww = 0, sub = 1;
  uint64_t target_rows = 0, target_cols = 0;
  double power[3] = {0, 0, 0};
  std::vector<double> work;
};

// A lat-long source: a separable exact area average.
Status LatLongToWorking(const EnvMap& env, uint64_t R, const Progress& progress, WorkingGrid* g) {
  const uint64_t W = env.width, H = env.height;
  // Rows: whole groups of source rows when that lands at or above the target (bands then
  // never split a source row), sub-bands of each source row when the source is coarser.
  if (H >= g->target_rows) {
    g->hw = H / GroupFor(H, g->target_rows);
    if (g->hw > 4 * g->target_rows) g->hw = g->target_rows;  // no usable divisor: fractional rows
  } else {
    g->hw = H;
    g->sub *= (g->target_rows + H - 1) / H;
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
  // Working grid targets: 16R rows of 180°/16R (about a fifth of the smallest texel's side,
  // 0.94/R rad at the cube corners), 32R columns (as wide as rows are high at the equator);
  // both halved (with more bands per row) while the prefix tables would pass 2^22 pixels.
  WorkingGrid g;
  g.target_rows = 16 * R;
  g.target_cols = 32 * R;
  while (g.target_rows * g.target_cols > (1ull << 22) && g.target_rows > 1) {
    g.target_rows /= 2;
    g.target_cols /= 2;
    g.sub *= 2;
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

// The column intervals where the circle at height z (radius rho) crosses each texel of the
// R-cubemap, over ww working columns: (start column, texel), ascending; never empty. Sampled
// every 1/64 of a face width, each change of texel located by bisection to 1e-11 of the
// circle.
void BandMarks(double z, double rho, uint64_t R, uint64_t ww, std::vector<std::pair<double, uint32_t>>* marks_out) {
  std::vector<std::pair<double, uint32_t>>& marks = *marks_out;
  const uint64_t samples = 64 * R;
  const double eps = 1e-11 * ww;
  auto texel_at = [&](double col) {
    const double phi = kPi - 2.0 * kPi * col / ww;
    return uint32_t(cubemap::Column(
        cubemap::DirectionToTexel({rho * std::cos(phi), rho * std::sin(phi), z}, uint32_t(R)), uint32_t(R)));
  };
  marks.clear();
  // Bisects (lo, hi) where the texel changes from tlo to thi; a third texel in between
  // splits the search.
  auto bisect = [&](auto&& self, double lo, uint32_t tlo, double hi, uint32_t thi) -> void {
    while (hi - lo > eps) {
      const double mid = 0.5 * (lo + hi);
      const uint32_t tm = texel_at(mid);
      if (tm == tlo) {
        lo = mid;
      } else if (tm == thi) {
        hi = mid;
      } else {
        self(self, lo, tlo, mid, tm);
        lo = mid;
        tlo = tm;
      }
    }
    marks.push_back({0.5 * (lo + hi), thi});
  };
  const uint32_t t0 = texel_at(0.0);
  uint32_t prev = t0;
  for (uint64_t s = 1; s <= samples; ++s) {
    const double c = s == samples ? double(ww) : double(ww) * s / samples;
    const uint32_t t = s == samples ? t0 : texel_at(c);
    if (t != prev) bisect(bisect, double(ww) * (s - 1) / samples, prev, c, t);
    prev = t;
  }
  if (marks.empty()) marks.push_back({0.0, t0});
}

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
  LTB_RETURN_IF_ERROR(rs.BuildBands(grid.sub, env.path, progress, &dsum));
  rs.Normalise(dsum);
  return rs;
}

// Bands: `sub` per working row. In each, the column intervals where the circle of the
// band's mean z (its area centroid) crosses each texel (BandMarks).
Status CubemapResampler::BuildBands(uint64_t sub, const std::string& path, const Progress& progress,
                                    std::vector<double>* dsum) {
  const uint64_t R = r_, ww = ww_, hw = hw_;
  std::vector<std::pair<double, uint32_t>> marks;
  for (uint64_t J = 0; J < hw; ++J) {
    LTB_RETURN_IF_ERROR(PollCancel(progress, path, R, J, "latitude bands"));
    for (uint64_t q = 0; q < sub; ++q) {
      const double ta = kPi * double(J * sub + q) / double(hw * sub),
                   tb = kPi * double(J * sub + q + 1) / double(hw * sub);
      Band band;
      band.row = uint32_t(J);
      band.weight = CosDiff(ta, tb) * 2.0 * kPi / ww;
      const double z = 0.5 * (std::cos(ta) + std::cos(tb)), rho = std::sqrt(std::max(0.0, 1.0 - z * z));
      BandMarks(z, rho, R, ww, &marks);
      band.first_run = run_start_.size();
      band.run_count = marks.size();
      for (size_t i = 0; i < marks.size(); ++i) {
        run_start_.push_back(marks[i].first);
        run_texel_.push_back(marks[i].second);
        const double end = i + 1 < marks.size() ? marks[i + 1].first : marks[0].first + ww;
        (*dsum)[marks[i].second] += band.weight * (end - marks[i].first);
      }
      bands_.push_back(band);
    }
  }
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
  thread_local std::vector<Vec4> acc;
  acc.assign(n, Vec4{0, 0, 0, 0});
  // The rotated map at working column c is the source at c + shift (docs/ENVMAPS.md).
  double turns = rotation / (2.0 * kPi);
  turns -= std::floor(turns);
  double shift = turns * wwd;
  if (!(shift >= 0.0 && shift < wwd)) shift = 0.0;
  const size_t stride = (ww + 1) * 3;
  for (const Band& b : bands_) {
    const double* P = prefix_.get() + b.row * stride;
    Vec4 total;
    Load(P + ww * 3, &total);
    const double* start = &run_start_[b.first_run];
    const uint32_t* texel = &run_texel_[b.first_run];
    const uint64_t count = b.run_count;
    // ∫_0^x of the row at x = start[k] + shift, extended periodically: the starts that pass
    // ww wrap (and gain one row total). Lane 3 is the next column's R: ignored.
    auto eval = [&](double x, const Vec4& wrap, Vec4* q) {
      const int64_t i = std::min<int64_t>(int64_t(x), int64_t(ww) - 1);
      const double f = x - double(i);
      Vec4 p0, p1;
      Load(P + 3 * i, &p0);
      Load(P + 3 * i + 3, &p1);
      *q = p0 + f * (p1 - p0) + wrap;
    };
    const Vec4 zero = {0, 0, 0, 0};
    Vec4 first, prev, next;
    if (start[0] + shift >= wwd) {
      eval(start[0] + shift - wwd, total, &first);
    } else {
      eval(start[0] + shift, zero, &first);
    }
    prev = first;
    uint64_t k = 0;
    for (; k + 1 < count && start[k + 1] + shift < wwd; ++k) {
      eval(start[k + 1] + shift, zero, &next);
      acc[texel[k]] += b.weight * (next - prev);
      prev = next;
    }
    for (; k + 1 < count; ++k) {
      eval(start[k + 1] + shift - wwd, total, &next);
      acc[texel[k]] += b.weight * (next - prev);
      prev = next;
    }
    acc[texel[count - 1]] += b.weight * (first + total - prev);
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
