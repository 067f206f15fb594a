// Exact texel averages of a cube-face or angular map (exact_cubemap.h): each source pixel,
// as a spherical polygon, clipped against the texels of every cube face it reaches.
#include "stages/images/exact_cubemap.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <functional>
#include <glm/geometric.hpp>
#include <string>

#include "stages/common/cubemap.h"
#include "stages/images/env_layout.h"
#include "stages/images/envmap.h"
#include "stages/images/image_readers.h"

namespace ltb::stages {
namespace {

using envmap_internal::kPi;

// A point of a face's plane: direction axis + x·U + y·V (cubemap::FaceDirection).
struct Point {
  double x, y;
};

// Up to 4 + 4 vertices: a quadrilateral clipped by the four sides of a cell.
struct Polygon {
  std::array<Point, 12> p;
  int n = 0;
};

// The part of `in` on the side a·x + b·y <= c of a line (Sutherland–Hodgman, one side).
Polygon ClipSide(const Polygon& in, double a, double b, double c) {
  Polygon out;
  for (int i = 0; i < in.n; ++i) {
    const Point& p = in.p[i];
    const Point& q = in.p[(i + 1) % in.n];
    const double dp = a * p.x + b * p.y - c, dq = a * q.x + b * q.y - c;
    if (dp <= 0) out.p[out.n++] = p;
    if ((dp < 0 && dq > 0) || (dp > 0 && dq < 0)) {
      const double t = dp / (dp - dq);
      out.p[out.n++] = {p.x + t * (q.x - p.x), p.y + t * (q.y - p.y)};
    }
  }
  return out;
}

struct FaceFrame {
  glm::dvec3 axis, u, v;
};

// Solid angle of a polygon of face g's plane (great-circle edges there): the triangles of
// a fan, each 2·atan2(a·(b × c), 1 + a·b + b·c + c·a) (Van Oosterom & Strackee 1983) of its
// unit corners. Signed by orientation; the caller takes |·|.
double PolygonSolidAngle(const FaceFrame& f, const Polygon& poly) {
  auto lift = [&](const Point& p) { return glm::normalize(f.axis + p.x * f.u + p.y * f.v); };
  const glm::dvec3 a = lift(poly.p[0]);
  glm::dvec3 b = lift(poly.p[1]);
  double sum = 0;
  for (int i = 2; i < poly.n; ++i) {
    const glm::dvec3 c = lift(poly.p[i]);
    const double det = glm::dot(a, glm::cross(b - a, c - a));  // a·(b × c), without cancellation
    sum += 2.0 * std::atan2(det, 1.0 + glm::dot(a, b) + glm::dot(b, c) + glm::dot(c, a));
    b = c;
  }
  return sum;
}

// Accumulates Σ L·Ω and Σ Ω per texel of an R-cubemap.
class TexelSums {
 public:
  TexelSums(uint32_t r, double rotation) : r_(r), acc_(size_t(6) * r * r * 4, 0.0) {
    cos_ = std::cos(rotation);
    sin_ = std::sin(rotation);
    for (int g = 0; g < 6; ++g) {
      frames_[g].axis = cubemap::FaceDirection(g, 0, 0);
      frames_[g].u = cubemap::FaceDirection(g, 1, 0) - frames_[g].axis;
      frames_[g].v = cubemap::FaceDirection(g, 0, 1) - frames_[g].axis;
    }
  }

  // A source direction where the cubemap shows it: Rz(rotation)·d.
  glm::dvec3 Rotated(const glm::dvec3& d) const { return {cos_ * d.x - sin_ * d.y, sin_ * d.x + cos_ * d.y, d.z}; }
  uint64_t Column(const glm::dvec3& d) const { return cubemap::Column(cubemap::DirectionToTexel(d, r_), r_); }

  void Add(uint64_t column, const float* L, double omega) {
    double* a = &acc_[column * 4];
    for (int c = 0; c < 3; ++c) a[c] += double(L[c]) * omega;
    a[3] += omega;
  }

  // Radiance L over the spherical quadrilateral q (rotated unit corners in order, great-circle
  // edges, less than ~0.5 rad across), of solid angle `omega`: to the texel holding it, or
  // spread over the texels it overlaps in proportion to the solid angle of each part.
  void AddQuad(const glm::dvec3 (&q)[4], const float* L, double omega) {
    const uint64_t cols[4] = {Column(q[0]), Column(q[1]), Column(q[2]), Column(q[3])};
    AddQuad(q, cols, L, omega);
  }
  // The same with the corners' texels known (`cols`: Column of each).
  void AddQuad(const glm::dvec3 (&q)[4], const uint64_t (&cols)[4], const float* L, double omega) {
    const uint64_t c0 = cols[0];
    if (cols[1] == c0 && cols[2] == c0 && cols[3] == c0) {
      Add(c0, L, omega);  // a texel is convex: a quadrilateral with its corners in it is in it
      return;
    }
    parts_.clear();
    double total = 0;
    for (int g = 0; g < 6; ++g) {
      // Face g's square holds directions within 54.7° of its axis: a quadrilateral this small
      // with a corner at or behind 90° from it cannot reach the square.
      const FaceFrame& f = frames_[g];
      Polygon poly;
      poly.n = 4;
      bool in_front = true;
      double x0 = 2, x1 = -2, y0 = 2, y1 = -2;
      for (int k = 0; k < 4 && in_front; ++k) {
        const double w = glm::dot(q[k], f.axis);
        if (!(w > 1e-12)) {
          in_front = false;
          break;
        }
        poly.p[k] = {glm::dot(q[k], f.u) / w, glm::dot(q[k], f.v) / w};
        x0 = std::min(x0, poly.p[k].x);
        x1 = std::max(x1, poly.p[k].x);
        y0 = std::min(y0, poly.p[k].y);
        y1 = std::max(y1, poly.p[k].y);
      }
      if (!in_front || x1 <= -1 || x0 >= 1 || y1 <= -1 || y0 >= 1) continue;
      auto cell = [this](double c) {
        return uint32_t(std::clamp<double>(std::floor((c + 1.0) * 0.5 * r_), 0.0, double(r_ - 1)));
      };
      for (uint32_t t = cell(y0); t <= cell(y1); ++t)
        for (uint32_t s = cell(x0); s <= cell(x1); ++s) {
          const double cx0 = 2.0 * s / r_ - 1, cx1 = 2.0 * (s + 1) / r_ - 1;
          const double cy0 = 2.0 * t / r_ - 1, cy1 = 2.0 * (t + 1) / r_ - 1;
          Polygon piece = ClipSide(poly, -1, 0, -cx0);
          piece = ClipSide(piece, 1, 0, cx1);
          piece = ClipSide(piece, 0, -1, -cy0);
          piece = ClipSide(piece, 0, 1, cy1);
          if (piece.n < 3) continue;
          const double a = std::fabs(PolygonSolidAngle(f, piece));
          if (!(a > 0)) continue;
          parts_.push_back({cubemap::Column({g, s, t}, r_), a});
          total += a;
        }
    }
    if (!(total > 0)) {  // degenerate (corners at one point): to the texel of its centre
      Add(Column(q[0] + q[1] + q[2] + q[3]), L, omega);
      return;
    }
    for (const Part& p : parts_) Add(p.column, L, omega * p.omega / total);
  }

  // The cubemap: Σ L·Ω / Σ Ω per texel (`fill(direction)` for a texel no pixel reached: the
  // source there), one factor per channel for the power, clamped to [0, peak].
  std::vector<float> Finish(const double power[3], const double peak[3],
                            const std::function<const float*(const glm::dvec3&)>& fill) const {
    const uint64_t texels = uint64_t(6) * r_ * r_;
    std::vector<double> avg(texels * 3);
    double got[3] = {0, 0, 0};
    for (uint64_t t = 0; t < texels; ++t) {
      const double* a = &acc_[t * 4];
      const cubemap::Texel x = cubemap::ColumnToTexel(t, r_);
      const double omega = cubemap::TexelSolidAngle(x, r_);
      const glm::dvec3 centre = cubemap::TexelCenter(x, r_);
      const float* L =
          a[3] > 0 ? nullptr : fill({cos_ * centre.x + sin_ * centre.y, -sin_ * centre.x + cos_ * centre.y, centre.z});
      for (int c = 0; c < 3; ++c) {
        avg[t * 3 + c] = a[3] > 0 ? a[c] / a[3] : double(L[c]);
        got[c] += avg[t * 3 + c] * omega;
      }
    }
    std::vector<float> out(texels * 3);
    for (int c = 0; c < 3; ++c) {
      const double k = got[c] > 0 ? power[c] / got[c] : 1.0;
      for (uint64_t t = 0; t < texels; ++t) {
        out[t * 3 + c] = float(std::clamp(avg[t * 3 + c] * k, 0.0, peak[c]));
      }
    }
    return out;
  }

 private:
  uint32_t r_;
  double cos_ = 1, sin_ = 0;
  std::vector<double> acc_;  // per texel: Σ L·Ω (3 channels), Σ Ω
  struct Part {
    uint64_t column;
    double omega;
  };
  std::vector<Part> parts_;  // AddQuad's scratch
  FaceFrame frames_[6];
};

void Peak(const EnvMap& env, double peak[3]) {
  for (int c = 0; c < 3; ++c) peak[c] = 0;
  for (size_t i = 0; i < env.rgb.size(); ++i) peak[i % 3] = std::max(peak[i % 3], double(env.rgb[i]));
}

Status PollCancel(const Progress& progress, const std::string& path, uint64_t R, uint64_t row) {
  if (row % envmap_internal::kRowsPerPoll != 0 || !progress.Cancelled()) return Status::Ok();
  return Cancelled(path + ": interrupted while resampling to the R = " + std::to_string(R) + " cubemap");
}

// Cube faces: every pixel is a great-circle quadrilateral of exact solid angle.
Result<std::vector<float>> FromFaces(const EnvMap& env, uint32_t R, double rotation, const Progress& progress) {
  const envmap_internal::FaceGeometry fg = envmap_internal::FacesOf(env);
  const uint64_t F = fg.size;
  if (F == 0) return InvalidArgument(env.path + ": holds no cube faces");
  auto source = [&](int f, uint64_t s, uint64_t t) {
    return &env.rgb[((fg.y0[f] + t) * env.width + fg.x0[f] + s) * 3];
  };
  TexelSums sums(R, rotation);
  double power[3] = {0, 0, 0};
  // Faces under 8 pixels across go as 8 (or more) sub-pixels: every quadrilateral is then
  // less than 0.3 rad across (AddQuad's premise).
  const uint64_t k = std::max<uint64_t>(1, (8 + F - 1) / F), n = F * k;
  std::vector<glm::dvec3> above(n + 1), below(n + 1);
  auto corners = [&](int f, uint64_t t, std::vector<glm::dvec3>* row) {
    for (uint64_t s = 0; s <= n; ++s) {
      (*row)[s] = sums.Rotated(glm::normalize(cubemap::FaceDirection(f, 2.0 * s / n - 1, 2.0 * t / n - 1)));
    }
  };
  for (int f = 0; f < 6; ++f) {
    corners(f, 0, &above);
    for (uint64_t t = 0; t < n; ++t) {
      LTB_RETURN_IF_ERROR(PollCancel(progress, env.path, R, t));
      corners(f, t + 1, &below);
      const double v0 = 2.0 * t / n - 1, v1 = 2.0 * (t + 1) / n - 1;
      for (uint64_t s = 0; s < n; ++s) {
        const double omega = cubemap::SolidAngle(2.0 * s / n - 1, v0, 2.0 * (s + 1) / n - 1, v1);
        const float* L = source(f, s / k, t / k);
        for (int c = 0; c < 3; ++c) power[c] += double(L[c]) * omega;
        const glm::dvec3 q[4] = {above[s], above[s + 1], below[s + 1], below[s]};
        sums.AddQuad(q, L, omega);
      }
      std::swap(above, below);
    }
  }
  double peak[3];
  Peak(env, peak);
  return sums.Finish(power, peak, [&](const glm::dvec3& d) {
    const cubemap::Texel x = cubemap::DirectionToTexel(d, uint32_t(F));
    return source(x.face, x.s, x.t);
  });
}

// The angular map's solid-angle density in (u, v): π·sin(πr)/r (dω = sin θ dθ dφ, θ = πr).
double AngularDensity(double u, double v) {
  const double r = std::sqrt(u * u + v * v);
  return r > 0 ? kPi * std::sin(kPi * r) / r : kPi * kPi;
}

// ∫ density over [u0, u1] × [v0, v1] (inside the disk): 2 × 2 Gauss–Legendre. The density
// is analytic; the rule's error is ~(side/2)⁴·|∂⁴ density|/135, below 1e-7 relative for the
// 64-pixel-wide map's pixels, the largest the loop below integrates.
double AngularSolidAngle(double u0, double u1, double v0, double v1) {
  constexpr double kX = 0.5773502691896258;  // 1/√3
  const double hu = 0.5 * (u1 - u0), hv = 0.5 * (v1 - v0), cu = 0.5 * (u0 + u1), cv = 0.5 * (v0 + v1);
  return hu * hv *
         (AngularDensity(cu - hu * kX, cv - hv * kX) + AngularDensity(cu + hu * kX, cv - hv * kX) +
          AngularDensity(cu - hu * kX, cv + hv * kX) + AngularDensity(cu + hu * kX, cv + hv * kX));
}

// Parts per side of an angular pixel across a texel edge. A part is taken as the spherical
// quadrilateral of its corners; its sides bow from great circles, which misplaces about
// 2.2·side²/T of a texel of side T (measured: docs/ENVMAPS.md). Parts of side ≤
// √(1.4e-4·T), with T the smallest texel's side (half the face centre's π/(2R)), keep that
// under 3e-4. A pixel's side is 2π/n rad (at most; less off the centre).
int AngularParts(uint64_t n, uint32_t R) {
  const double side = 2.0 * kPi / double(n), texel = 0.5 * kPi / (2.0 * R);
  return int(std::clamp(std::ceil(side / std::sqrt(1.4e-4 * texel)), 1.0, 16.0));
}

// Angular maps: pixels inside one texel whole, pixels across a texel edge split into parts
// (AngularParts), pixels across the rim by 8 × 8 sub-sample centres.
Result<std::vector<float>> FromAngular(const EnvMap& env, uint32_t R, double rotation, const Progress& progress) {
  const uint64_t W = env.width;
  // Maps under 64 pixels across go as 64 (or more) sub-pixels, so that each quadrilateral is
  // small against the sphere.
  const uint64_t k = std::max<uint64_t>(1, (64 + W - 1) / W), n = W * k;
  const double h = 2.0 / double(n);
  TexelSums sums(R, rotation);
  double power[3] = {0, 0, 0};
  auto dir = [&](double u, double v) { return sums.Rotated(envmap_internal::AngularDirection(u, v)); };
  const int m = AngularParts(n, R);
  std::vector<glm::dvec3> grid((m + 1) * (m + 1));
  std::vector<uint64_t> grid_col((m + 1) * (m + 1));
  std::vector<double> part_w(m * m);
  // A row of pixel corners: direction and texel (kOutside beyond the disk).
  constexpr uint64_t kOutside = ~uint64_t(0);
  struct Corner {
    glm::dvec3 d;
    uint64_t col;
  };
  std::vector<Corner> above(n + 1), below(n + 1);
  auto corners = [&](uint64_t y, std::vector<Corner>* row) {
    const double v = 1.0 - h * double(y);
    for (uint64_t x = 0; x <= n; ++x) {
      const double u = -1.0 + h * double(x);
      if (u * u + v * v <= 1.0) {
        const glm::dvec3 d = dir(u, v);
        (*row)[x] = {d, sums.Column(d)};
      } else {
        (*row)[x] = {glm::dvec3(0.0), kOutside};
      }
    }
  };
  corners(0, &above);
  for (uint64_t y = 0; y < n; ++y) {
    LTB_RETURN_IF_ERROR(PollCancel(progress, env.path, R, y));
    corners(y + 1, &below);
    const double v1 = 1.0 - h * double(y), v0 = v1 - h;
    for (uint64_t x = 0; x < n; ++x) {
      const double u0 = -1.0 + h * double(x), u1 = u0 + h;
      const float* L = &env.rgb[((y / k) * W + x / k) * 3];
      const Corner* q[4] = {&above[x], &above[x + 1], &below[x + 1], &below[x]};
      if (q[0]->col == kOutside || q[1]->col == kOutside || q[2]->col == kOutside || q[3]->col == kOutside) {
        // Across the rim (or outside): sub-sample centres inside the disk.
        constexpr int s = 8;
        for (int j = 0; j < s; ++j)
          for (int i = 0; i < s; ++i) {
            const double u = u0 + (i + 0.5) * h / s, v = v0 + (j + 0.5) * h / s;
            if (u * u + v * v >= 1.0) continue;
            const double omega = AngularDensity(u, v) * (h / s) * (h / s);
            for (int c = 0; c < 3; ++c) power[c] += double(L[c]) * omega;
            sums.Add(sums.Column(dir(u, v)), L, omega);
          }
        continue;
      }
      const double omega = AngularSolidAngle(u0, u1, v0, v1);
      for (int c = 0; c < 3; ++c) power[c] += double(L[c]) * omega;
      const uint64_t c0 = q[0]->col;
      if (q[1]->col == c0 && q[2]->col == c0 && q[3]->col == c0) {
        sums.Add(c0, L, omega);
        continue;
      }
      // Across a texel edge: m × m parts, each the quadrilateral of its corners.
      const double g = h / double(m);
      for (int j = 0; j <= m; ++j)
        for (int i = 0; i <= m; ++i) {
          const int at = j * (m + 1) + i;
          grid[at] = i == 0 && j == 0   ? q[0]->d
                     : i == m && j == 0 ? q[1]->d
                     : i == m && j == m ? q[2]->d
                     : i == 0 && j == m ? q[3]->d
                                        : dir(u0 + i * g, v1 - j * g);
          grid_col[at] = sums.Column(grid[at]);
        }
      // A part's solid angle: the density at its centre, scaled so that the parts sum to the
      // pixel's (the density's variation inside a pixel is second order).
      double centres = 0;
      for (int j = 0; j < m; ++j)
        for (int i = 0; i < m; ++i)
          centres += (part_w[j * m + i] = AngularDensity(u0 + (i + 0.5) * g, v1 - (j + 0.5) * g));
      for (int j = 0; j < m; ++j)
        for (int i = 0; i < m; ++i) {
          const int a = j * (m + 1) + i, b = a + 1, c = b + m + 1, d = a + m + 1;
          const double part = omega * part_w[j * m + i] / centres;
          const glm::dvec3 p[4] = {grid[a], grid[b], grid[c], grid[d]};
          const uint64_t cols[4] = {grid_col[a], grid_col[b], grid_col[c], grid_col[d]};
          sums.AddQuad(p, cols, L, part);
        }
    }
    std::swap(above, below);
  }
  double peak[3];
  Peak(env, peak);
  return sums.Finish(power, peak, [&](const glm::dvec3& d) {
    uint64_t x, y;
    envmap_internal::DirectionToAngular(d, W, &x, &y);
    return &env.rgb[(y * W + x) * 3];
  });
}

}  // namespace

Result<std::vector<float>> ExactCubemap(const EnvMap& env, uint64_t cube_res, double rotation,
                                        const Progress& progress) {
  if (cube_res == 0 || cube_res > (1u << 16)) {
    return InvalidArgument(env.path + ": cube resolution " + std::to_string(cube_res) + " is outside 1..65536");
  }
  if (!std::isfinite(rotation)) rotation = 0;
  const uint32_t R = uint32_t(cube_res);
  switch (env.layout) {
    case EnvLayout::kHCross:
    case EnvLayout::kVCross:
    case EnvLayout::kFaces:
      return FromFaces(env, R, rotation, progress);
    case EnvLayout::kAngular:
      return FromAngular(env, R, rotation, progress);
    default:
      return InvalidArgument(env.path +
                             ": exact texel averages are for cube-face and angular maps (a lat-long map "
                             "goes through the resampler, exact for it)");
  }
}

}  // namespace ltb::stages
