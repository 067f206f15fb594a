// CubemapResampler (resampler.h): the texel edges cut into pieces per working row of the
// working grid (working_grid.h), the pieces gathered into bands, and Resample.
#include "stages/images/resampler.h"

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <glm/geometric.hpp>
#include <new>
#include <thread>
#include <utility>

#include "stages/common/cubemap.h"
#include "stages/images/env_layout.h"
#include "stages/images/envmap.h"
#include "stages/images/image_readers.h"
#include "stages/images/working_grid.h"

namespace ltb::stages {

using envmap_internal::BuildWorkingGrid;
using envmap_internal::kPi;
using envmap_internal::PollCancel;
using envmap_internal::Size;
using envmap_internal::WorkingGrid;
using envmap_internal::WorkingTable;

namespace {

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

// A piece of a texel edge inside one working row, traversed towards increasing column c (a
// piece along a meridian, w = 0: towards increasing z), between the texel above it (left of
// a meridian piece) and the one below (right of it).
struct CubemapResampler::RawPiece {
  double c = 0;  // working column where it starts, in [kSeamColumn, kSeamColumn + ww)
  double w = 0;  // width in working columns (0 along a meridian)
  double z0 = 0, z1 = 0;
  float kw = 0;  // K(w) (resampler.h, Edge)
  uint32_t row = 0, up = 0, down = 0;
};
// The texel the seam meridian (c = kSeamColumn) passes through in a row (once per stretch).
struct CubemapResampler::SeamCell {
  uint32_t row = 0, texel = 0;
};

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
  for (uint64_t i = 0; i < grid.work.size(); ++i) rs.peak_[i % 3] = std::max(rs.peak_[i % 3], grid.work[i]);
  LTB_ASSIGN_OR_RETURN(rs.values_, WorkingTable(env.path, grid));
  grid.work = {};

  // Row boundaries in z, exactly antisymmetric (the equator exactly 0 when it is one).
  const uint64_t hw = rs.hw_;
  std::vector<double> zrow(hw + 1);
  for (uint64_t J = 0; J <= hw; ++J) zrow[J] = std::cos(kPi * double(J) / double(hw));
  for (uint64_t J = 0; 2 * J <= hw; ++J) zrow[hw - J] = -zrow[J];
  zrow[0] = 1.0;
  zrow[hw] = -1.0;
  if (hw % 2 == 0) zrow[hw / 2] = 0.0;
  std::vector<RawPiece> pieces;
  std::vector<SeamCell> seam;
  LTB_RETURN_IF_ERROR(CutTexelEdges(R, rs.ww_, hw, env.path, progress, zrow, &pieces, &seam));
  rs.pieces_ = pieces.size();
  std::sort(pieces.begin(), pieces.end(), [](const RawPiece& a, const RawPiece& b) { return a.row < b.row; });
  std::sort(seam.begin(), seam.end(), [](const SeamCell& a, const SeamCell& b) { return a.row < b.row; });
  LTB_RETURN_IF_ERROR(rs.BuildBands(env.path, progress, zrow, pieces, seam));
  rs.Normalise();
  return rs;
}

// Pieces: every texel edge (the great-circle arc between two neighbouring grid corners of a
// face; an edge on a cube edge once) cut where it crosses a working row's boundary or the
// seam, then halved until the cubic Hermite K of each piece is within kPieceTolerance of a
// working pixel's area (1 column × the row's height in z; at most a pixel of a 32R × 16R grid)
// of the exact K half-way along it. And the cells of the seam meridian: the texel it passes
// through in each row, and for how long.
// Over 120 lines: one walk over every texel edge; its emit, arc and boundary lambdas share the
// piece list, the seam crossings and the row table.
Status CubemapResampler::CutTexelEdges(uint64_t R, uint64_t ww, uint64_t hw, const std::string& path,
                                       const Progress& progress, const std::vector<double>& zrow,
                                       std::vector<RawPiece>* out, std::vector<SeamCell>* seam) {
  constexpr double kPieceTolerance = 1e-5;
  const double wwd = double(ww);
  const uint32_t r32 = uint32_t(R);
  std::vector<RawPiece>& pieces = *out;
  auto emit = [&](uint64_t J, double c, double w, double z0, double z1, double kw, uint32_t up, uint32_t down) {
    c -= wwd * std::floor((c - kSeamColumn) / wwd);
    if (c >= kSeamColumn + wwd) c -= wwd;
    RawPiece p;
    p.c = c;
    p.w = w;
    p.z0 = z0;
    p.z1 = z1;
    p.kw = float(kw);
    p.row = uint32_t(J);
    p.up = up;
    p.down = down;
    pieces.push_back(p);
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
      // The Hermite error, t²(w − t)²/24 times the fourth derivative of K somewhere along the
      // piece, peaks mid-way where that derivative is even about the middle, and a quarter of
      // the way in where it is odd (a piece over the arc's apex, before it was cut there): both.
      auto off = [&](double t) {
        return std::abs(arc.K(c0, z1, t) - HermiteK(dz, w, kw, t)) > kPieceTolerance * pixel;
      };
      if (off(0.5 * w) || off(0.25 * w) || off(0.75 * w)) {
        const double cm = 0.5 * (c0 + c1), zm = arc.Z(cm);
        self(self, arc, J, c0, z0, cm, zm, up, down, depth + 1);
        self(self, arc, J, cm, zm, c1, z1, up, down, depth + 1);
        return;
      }
    }
    emit(J, c0, w, z0, z1, kw, up, down);
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
              if (z1 > z0) emit(RowHolding(zrow, 0.5 * (z0 + z1)), c, 0.0, z0, z1, 0.0, up, down);
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
            // Cut there too: each piece is then monotone in z.
            const double z_apex = arc.Z(apex);
            marks.push_back({apex, z_apex});
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

  // Seam cells: walking up the seam meridian from the south pole, the texel changes where an
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
      if (z > z0) seam->push_back({uint32_t(J), current});
      z0 = z;
      current = seam_crossings[next].above;
    }
    if (z1 > z0) seam->push_back({uint32_t(J), current});
  }
  return Status::Ok();
}

// Bands: the pieces (and the seam's cells) grouped by row and texel. The ends of a band's
// pieces cut the row's circle into arcs; over each arc the band covers either the whole
// height of the row, or none of it, or the part a piece of it bounds: present when one of its
// pieces spans the arc, else when the texel holds the arc's midpoint at the row's middle
// height (no edge of the texel crosses the row there). The band's own coordinate starts
// after its widest absent arc (at its first end when it covers the whole circle), so that its
// spans and edges are contiguous; a texel is convex, so each column meets it in one interval
// of z, bounded by at most one top and one bottom piece.
// Over 120 lines: one pass from the sorted piece references to the bands, each step reading
// the previous step's locals.
Status CubemapResampler::BuildBands(const std::string& path, const Progress& progress, const std::vector<double>& zrow,
                                    const std::vector<RawPiece>& pieces, const std::vector<SeamCell>& seam) {
  const uint64_t n = 6 * r_ * r_;
  const double wwd = double(ww_);
  const uint32_t r32 = uint32_t(r_);
  constexpr uint32_t kSeamRef = UINT32_MAX;
  constexpr double kSameEnd = 1e-9;  // columns: ends closer than this are one
  struct Ref {
    uint64_t key;    // row · 6R² + texel
    uint32_t piece;  // kSeamRef: a seam cell
    uint32_t top;    // the texel lies below the piece
  };
  // Row by row (pieces and seam cells come sorted by row), so that the references are one
  // row's at a time.
  uint64_t non_meridian = 0;
  for (const RawPiece& p : pieces) non_meridian += p.w > 0;
  edges_.reserve(2 * non_meridian);
  std::vector<Ref> refs;
  size_t next_piece = 0, next_seam = 0;
  std::vector<double> ends;
  std::vector<char> present;
  uint64_t groups = 0;
  for (uint32_t J = 0; J < hw_; ++J) {
    refs.clear();
    for (; next_piece < pieces.size() && pieces[next_piece].row == J; ++next_piece) {
      const RawPiece& p = pieces[next_piece];
      refs.push_back({uint64_t(p.row) * n + p.up, uint32_t(next_piece), 0});
      refs.push_back({uint64_t(p.row) * n + p.down, uint32_t(next_piece), 1});
    }
    for (; next_seam < seam.size() && seam[next_seam].row == J; ++next_seam) {
      refs.push_back({uint64_t(J) * n + seam[next_seam].texel, kSeamRef, 0});
    }
    std::sort(refs.begin(), refs.end(), [](const Ref& a, const Ref& b) {
      return a.key != b.key ? a.key < b.key : a.top != b.top ? a.top > b.top : a.piece < b.piece;
    });
    for (size_t g = 0; g < refs.size();) {
      size_t e = g;
      while (e < refs.size() && refs[e].key == refs[g].key) ++e;
      LTB_RETURN_IF_ERROR(PollCancel(progress, path, r_, groups++, "bands"));
      const uint32_t row = uint32_t(refs[g].key / n), texel = uint32_t(refs[g].key % n);
      const double ztop = zrow[row], zbottom = zrow[row + 1], zmid = 0.5 * (ztop + zbottom);
      // The ends on the circle [kSeamColumn, kSeamColumn + ww).
      ends.clear();
      for (size_t k = g; k < e; ++k) {
        if (refs[k].piece == kSeamRef) continue;
        const RawPiece& p = pieces[refs[k].piece];
        ends.push_back(p.c);
        double end = p.c + p.w;
        if (end >= kSeamColumn + wwd) end -= wwd;
        ends.push_back(end);
      }
      std::sort(ends.begin(), ends.end());
      size_t m = 0;
      for (double x : ends) {
        if (m == 0 || x - ends[m - 1] > kSameEnd) ends[m++] = x;
      }
      ends.resize(m);
      if (m > 1 && ends[0] + wwd - ends[m - 1] <= kSameEnd) ends.pop_back(), --m;
      if (m == 0) ends.push_back(kSeamColumn);  // no piece: one arc, the whole circle
      const size_t arcs = ends.size();
      auto arc_start = [&](size_t k) { return ends[k]; };
      auto arc_end = [&](size_t k) { return k + 1 < arcs ? ends[k + 1] : ends[0] + wwd; };
      present.assign(arcs, 0);
      for (size_t k = 0; k < arcs; ++k) {
        const double mid = 0.5 * (arc_start(k) + arc_end(k));
        bool spanned = false;
        for (size_t q = g; q < e && !spanned; ++q) {
          if (refs[q].piece == kSeamRef) continue;
          const RawPiece& p = pieces[refs[q].piece];
          for (double x : {mid, mid - wwd}) spanned |= p.w > 0 && x >= p.c && x <= p.c + p.w;
        }
        if (!spanned) {
          const double phi = kPi - 2.0 * kPi * mid / wwd, rho = std::sqrt(std::max(0.0, 1.0 - zmid * zmid));
          const glm::dvec3 d(rho * std::cos(phi), rho * std::sin(phi), zmid);
          spanned = cubemap::Column(cubemap::DirectionToTexel(d, r32), r32) == texel;
        }
        present[k] = spanned;
      }
      size_t first = 0;  // the arc the band's coordinate starts with
      double widest = -1;
      for (size_t k = 0; k < arcs; ++k) {
        if (!present[k] && arc_end(k) - arc_start(k) > widest) {
          widest = arc_end(k) - arc_start(k);
          first = (k + 1) % arcs;
        }
      }
      const double origin = arc_start(first);
      Band band;
      band.texel = texel;
      band.row = row;
      band.height = ztop - zbottom;
      band.first_span = uint32_t(spans_.size());
      for (size_t i = 0; i < arcs; ++i) {
        const size_t k = (first + i) % arcs;
        if (!present[k]) continue;
        const double lift = k < first ? wwd : 0.0, a = arc_start(k) + lift, b = arc_end(k) + lift;
        if (spans_.size() > band.first_span && a - spans_.back().b <= kSameEnd) {
          spans_.back().b = b;
        } else {
          spans_.push_back({a, b});
        }
      }
      band.spans = uint32_t(spans_.size() - band.first_span);
      if (band.spans == 0) {
        g = e;
        continue;
      }
      band.first_edge = uint32_t(edges_.size());
      for (size_t k = g; k < e; ++k) {  // top pieces first (the sort's order)
        if (refs[k].piece == kSeamRef) continue;
        const RawPiece& p = pieces[refs[k].piece];
        if (!(p.w > 0)) continue;  // along a meridian: it bounds the spans, not the height
        Edge edge;
        edge.c = p.c < origin - kSameEnd ? p.c + wwd : p.c;
        // The Hermite cubic (HermiteK) in powers of t.
        const double dz = p.z1 - p.z0, kw = p.kw, inv = 1.0 / p.w, dzw = dz * p.w;
        edge.h = refs[k].top ? ztop - p.z1 : p.z1 - zbottom;
        edge.dz = dz;
        edge.a2 = (3.0 * kw - 2.0 * dzw) * inv * inv;
        edge.a3 = (dzw - 2.0 * kw) * inv * inv * inv;
        edge.w = p.w;
        edges_.push_back(edge);
        ++(refs[k].top ? band.top_edges : band.bottom_edges);
      }
      const double lo = spans_[band.first_span].a, hi = spans_.back().b;
      widest_band_ = std::max<uint64_t>(widest_band_, uint64_t(std::floor(hi) - std::floor(lo)) + 2);
      bands_.push_back(band);
      g = e;
    }
  }
  // By row, then first column, and the spans and edges in that order: Integrate then reads
  // the working grid and every table in order.
  std::sort(bands_.begin(), bands_.end(), [&](const Band& x, const Band& y) {
    return x.row != y.row ? x.row < y.row : spans_[x.first_span].a < spans_[y.first_span].a;
  });
  std::vector<Span> spans;
  spans.reserve(spans_.size());
  for (Band& b : bands_) {
    spans.insert(spans.end(), spans_.begin() + b.first_span, spans_.begin() + b.first_span + b.spans);
    b.first_span = uint32_t(spans.size() - b.spans);
  }
  spans_ = std::move(spans);
  std::vector<Edge> edges;
  edges.reserve(edges_.size());
  for (Band& b : bands_) {
    const uint32_t count = b.top_edges + b.bottom_edges;
    edges.insert(edges.end(), edges_.begin() + b.first_edge, edges_.begin() + b.first_edge + count);
    b.first_edge = uint32_t(edges.size() - count);
  }
  edges_ = std::move(edges);
  return Status::Ok();
}

namespace {
// R, G, B and an unused lane: one AVX register, or two SSE2 ones. Passed by pointer only
// (a by-value 32-byte vector changes the ABI between AVX and non-AVX builds).
using Vec4 = double __attribute__((vector_size(32)));
inline void Load(const double* p, Vec4* v) { std::memcpy(v, p, sizeof *v); }
}  // namespace

// Per band: the area of the band in each column it covers (the spans' full height, less what
// its top and bottom pieces cut off), then Σ L·max(area, 0) over those columns: a sum of
// non-negative terms. Column j of the band's coordinate x = c + shift is working column
// j mod ww.
void CubemapResampler::Integrate(double shift, const double* values, double* acc, uint32_t part, uint32_t parts) const {
  thread_local std::vector<double> area;
  area.resize(widest_band_ + 2);
  const int64_t ww = int64_t(ww_);
  Vec4* const out = reinterpret_cast<Vec4*>(acc);
  for (const Band& b : bands_) {
    if (parts > 1 && b.texel % parts != part) continue;
    const Span* spans = spans_.data() + b.first_span;
    const int64_t j0 = int64_t(std::floor(spans[0].a + shift));
    const int64_t cols =
        std::min<int64_t>(int64_t(std::floor(spans[b.spans - 1].b + shift)) - j0 + 1, int64_t(area.size()));
    std::fill_n(area.data(), cols, 0.0);
    auto at = [&](int64_t j) -> double& { return area[std::clamp<int64_t>(j - j0, 0, cols - 1)]; };
    for (uint32_t k = 0; k < b.spans; ++k) {
      // The span's full height in each column it covers: a fraction of it in the first and last.
      const double x0 = spans[k].a + shift, x1 = spans[k].b + shift;
      const int64_t ja = int64_t(std::floor(x0)), jb = std::min(int64_t(std::floor(x1)), j0 + cols - 1);
      if (jb <= ja) {
        at(ja) += b.height * (x1 - x0);
        continue;
      }
      at(ja) += b.height * (double(ja + 1) - x0);
      double* const mid = area.data() + (ja - j0);
      for (int64_t j = 1; j < jb - ja; ++j) mid[j] += b.height;
      at(jb) += b.height * (x1 - double(jb));
    }
    const Edge* edges = edges_.data() + b.first_edge;
    for (uint32_t k = 0; k < b.top_edges + b.bottom_edges; ++k) {
      const Edge& e = edges[k];
      const bool top = k < b.top_edges;
      const double x = e.c + shift, w = e.w, dz = e.dz, a2 = e.a2, a3 = e.a3;
      double t_prev = 0, k_prev = 0;
      for (int64_t j = int64_t(std::floor(x));; ++j) {
        const double t = std::min(w, double(j + 1) - x);
        const double kt = t * (dz + t * (a2 + t * a3));
        const double dt = t - t_prev, dk = kt - k_prev;
        at(j) -= top ? dt * e.h + dk : dt * e.h - dk;
        if (t >= w) break;
        t_prev = t;
        k_prev = kt;
      }
    }
    Vec4 sum = {0, 0, 0, 0};
    if (values == nullptr) {
      for (int64_t k = 0; k < cols; ++k) sum += std::max(area[k], 0.0);
    } else {
      // Two runs: up to the row's end, then on from its column 0. Two sums, to overlap the
      // loads. Lane 3 is the next column's R: ignored.
      const double* row = values + uint64_t(b.row) * ww_ * 3;
      const int64_t c0 = j0 % ww, first = std::min(cols, ww - c0);
      Vec4 other = {0, 0, 0, 0};
      auto add = [&](const double* p, const double* a, int64_t count) {
        int64_t k = 0;
        for (; k + 1 < count; k += 2) {
          Vec4 v, u;
          Load(p + 3 * k, &v);
          Load(p + 3 * k + 3, &u);
          sum += std::max(a[k], 0.0) * v;
          other += std::max(a[k + 1], 0.0) * u;
        }
        if (k < count) {
          Vec4 v;
          Load(p + 3 * k, &v);
          sum += std::max(a[k], 0.0) * v;
        }
      };
      add(row + 3 * c0, area.data(), first);
      for (int64_t done = first; done < cols; done += ww) add(row, area.data() + done, std::min(ww, cols - done));
      sum += other;
    }
    out[b.texel] += sum;
  }
}

void CubemapResampler::Normalise() {
  const uint64_t R = r_, n = 6 * R * R, ww = ww_, hw = hw_;
  std::vector<Vec4> area(n, Vec4{0, 0, 0, 0});
  Integrate(0.0, nullptr, reinterpret_cast<double*>(area.data()));
  const double* d = reinterpret_cast<const double*>(area.data());
  const double scale = 2.0 * kPi / double(ww);  // dω = dz·dφ, a column is 2π/ww of φ
  texel_scale_.resize(n);
  for (uint64_t t = 0; t < n; ++t) {
    if (d[4 * t] > 0) {
      texel_scale_[t] = 1.0 / d[4 * t];
      solid_angle_error_ = std::max(solid_angle_error_, std::abs(d[4 * t] * scale / omega_[t] - 1.0));
      continue;
    }
    texel_scale_[t] = 1.0;
    solid_angle_error_ = 1.0;
    double u, v;
    DirectionToLatLong(cubemap::TexelCenter(cubemap::ColumnToTexel(t, R), uint32_t(R)), &u, &v);
    empty_.push_back({t, uint32_t(std::min<uint64_t>(uint64_t(v * hw), hw - 1)), u * ww});
  }
}

void CubemapResampler::Resample(double rotation, float* out, int jobs) const {
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
  // Threads for texels of their own (every texel's bands in the same order: the same sums),
  // when the cube is large enough to pay for starting them.
  const uint32_t parts = r_ >= 16 ? uint32_t(std::clamp(jobs, 1, 8)) : 1;
  std::vector<std::thread> pool;
  for (uint32_t p = 1; p < parts; ++p)
    pool.emplace_back([&, p] { Integrate(shift, values_.get(), reinterpret_cast<double*>(acc), p, parts); });
  Integrate(shift, values_.get(), reinterpret_cast<double*>(acc), 0, parts);
  for (std::thread& t : pool) t.join();
  for (const EmptyTexel& e : empty_) {
    double x = e.column + shift;
    if (x >= wwd) x -= wwd;
    const uint64_t i = std::min<uint64_t>(uint64_t(x), ww - 1);
    Load(values_.get() + (e.row * ww + i) * 3, &acc[e.texel]);
  }
  // Texel radiance = Σ L dΩ / Σ dΩ, then one factor per channel so that Σ texel·Ω_texel
  // equals the source's power; a texel is an average of the working grid, so at most its
  // largest value (which keeps a map near float32's largest value finite).
  Vec4 sum = {0, 0, 0, 0};
  for (uint64_t t = 0; t < n; ++t) sum += acc[t] * (texel_scale_[t] * omega_[t]);
  double g[3];
  for (int c = 0; c < 3; ++c) g[c] = sum[c] > 0 ? power_[c] / sum[c] : 1.0;
  for (uint64_t t = 0; t < n; ++t)
    for (int c = 0; c < 3; ++c) out[t * 3 + c] = float(std::min(acc[t][c] * texel_scale_[t] * g[c], peak_[c]));
}

}  // namespace ltb::stages
