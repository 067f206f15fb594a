#include "stages/triple/haar_triple.h"

#include <algorithm>
#include <bit>
#include <cmath>
#include <numeric>

namespace ltb::triple {
namespace {

int Log2(uint64_t r) { return std::countr_zero(r); }  // R is a power of two

}  // namespace

HaarBasis BasisOf(uint64_t index) {
  HaarBasis b;
  if (index == 0) return b;
  const uint64_t k = index - 1, s = k / 3;
  b.type = static_cast<int>(k % 3);
  int l = 0;
  while (((uint64_t{1} << (2 * (l + 1))) - 1) / 3 <= s) ++l;
  const uint64_t within = s - ((uint64_t{1} << (2 * l)) - 1) / 3;
  b.level = l;
  b.i = within & ((uint64_t{1} << l) - 1);
  b.j = within >> l;
  return b;
}

uint64_t IndexOf(const HaarBasis& b) {
  return b.level < 0 ? 0 : 1 + 3 * SquareIndex(b.level, b.i, b.j) + static_cast<uint64_t>(b.type);
}

double TriplingCoefficient(const HaarBasis& u, const HaarBasis& v, const HaarBasis& w) {
  const HaarBasis* f[3] = {&u, &v, &w};
  int scaling = 0;
  for (const HaarBasis* b : f) scaling += b->level < 0;
  if (scaling == 3) return 1.0;  // case 1
  auto same_square = [](const HaarBasis& a, const HaarBasis& b) {
    return a.level == b.level && a.i == b.i && a.j == b.j;
  };
  if (scaling == 0 && same_square(u, v) && same_square(v, w) && u.type != v.type && v.type != w.type &&
      u.type != w.type) {
    return std::ldexp(1.0, u.level);  // case 2
  }
  // Case 3: two identical wavelets, the third coarser (or the scaling function).
  for (int k = 0; k < 3; ++k) {
    const HaarBasis& a = *f[(k + 1) % 3];
    const HaarBasis& b = *f[(k + 2) % 3];
    const HaarBasis& c = *f[k];
    if (a.level < 0 || !same_square(a, b) || a.type != b.type) continue;
    if (c.level < 0) return 1.0;
    if (c.level >= a.level) continue;
    const int shift = a.level - c.level;  // does c's square contain a's?
    if ((a.i >> shift) != c.i || (a.j >> shift) != c.j) continue;
    const int qx = static_cast<int>((a.i >> (shift - 1)) & 1), qy = static_cast<int>((a.j >> (shift - 1)) & 1);
    return SignOfQuadrant(c.type, qx, qy) * std::ldexp(1.0, c.level);
  }
  return 0.0;
}

double PixelTripleProduct(std::span<const double> l, std::span<const double> v, std::span<const double> rho) {
  double sum = 0;
  for (size_t p = 0; p < l.size(); ++p) sum += l[p] * v[p] * rho[p];
  return sum / static_cast<double>(l.size());
}

namespace {

// Case 2 of one square: three different types, C = 2^l.
double Case2(const double* r, const double* a, const double* b, double scale) {
  return scale * (r[0] * a[1] * b[2] + r[0] * a[2] * b[1] + r[1] * a[2] * b[0] + r[1] * a[0] * b[2] +
                  r[2] * a[0] * b[1] + r[2] * a[1] * b[0]);
}

}  // namespace

void ParentSums(const double* coef, int n, std::vector<double>* p) {
  p->assign(((uint64_t{1} << (2 * n)) - 1) / 3, 0.0);
  if (p->empty()) return;
  (*p)[0] = coef[0];
  for (int l = 1; l < n; ++l) {
    const uint64_t side = uint64_t{1} << l;
    const double scale = std::ldexp(1.0, l - 1);
    for (uint64_t j = 0; j < side; ++j) {
      for (uint64_t i = 0; i < side; ++i) {
        const uint64_t parent = SquareIndex(l - 1, i / 2, j / 2);
        (*p)[SquareIndex(l, i, j)] =
            (*p)[parent] + scale * SignedSum(&coef[1 + 3 * parent], static_cast<int>(i & 1), static_cast<int>(j & 1));
      }
    }
  }
}

double LinearTripleProductDense(const double* l, const double* pl, const double* v, const double* pv, const double* rho,
                                const double* pr, int n) {
  double integral = l[0] * v[0] * rho[0];
  for (int lv = 0; lv < n; ++lv) {
    const uint64_t first = SquareIndex(lv, 0, 0), count = uint64_t{1} << (2 * lv);
    const double scale = std::ldexp(1.0, lv);
    for (uint64_t s = first; s < first + count; ++s) {
      const double* a = &l[1 + 3 * s];
      const double* b = &v[1 + 3 * s];
      const double* r = &rho[1 + 3 * s];
      integral += Case2(r, a, b, scale);
      for (int t = 0; t < 3; ++t) integral += r[t] * a[t] * pv[s] + a[t] * b[t] * pr[s] + b[t] * r[t] * pl[s];
    }
  }
  return integral;
}

double LinearTripleProduct(const HaarFace& l, const HaarFace& v, const HaarFace& rho) {
  const int n = Log2(l.res);
  std::vector<double> pl, pv, pr;
  ParentSums(l.c.data(), n, &pl);
  ParentSums(v.c.data(), n, &pv);
  ParentSums(rho.c.data(), n, &pr);
  return LinearTripleProductDense(l.c.data(), pl.data(), v.c.data(), pv.data(), rho.c.data(), pr.data(), n);
}

std::vector<uint32_t> LargestTerms(const HaarFace& f, uint64_t n) {
  std::vector<uint32_t> idx(f.c.size());
  std::iota(idx.begin(), idx.end(), 0u);
  n = std::min<uint64_t>(n, idx.size());
  if (n == 0) return {};
  // The scaling coefficient first, then wavelets by magnitude (ties: lower index).
  std::partial_sort(idx.begin() + 1, idx.begin() + static_cast<std::ptrdiff_t>(n), idx.end(),
                    [&](uint32_t a, uint32_t b) {
                      const double x = std::fabs(f.c[a]), y = std::fabs(f.c[b]);
                      return x != y ? x > y : a < b;
                    });
  idx.resize(n);
  std::sort(idx.begin(), idx.end());
  return idx;
}

namespace {

// Parent sums computed on demand (psum_lazy, §5.3): a square's value is filled from its
// nearest computed ancestor down; `coef` gives X's coefficient by index.
template <typename Coef>
class LazyParentSums {
 public:
  LazyParentSums(uint64_t squares, double scaling, Coef coef) : value_(squares), known_(squares, 0), coef_(coef) {
    if (squares > 0) {
      value_[0] = scaling;
      known_[0] = 1;
    }
  }
  double operator()(int level, uint64_t i, uint64_t j) {
    const uint64_t s = SquareIndex(level, i, j);
    if (known_[s]) return value_[s];
    const double parent = (*this)(level - 1, i / 2, j / 2);
    const uint64_t ps = SquareIndex(level - 1, i / 2, j / 2);
    const double w[3] = {coef_(1 + 3 * ps), coef_(2 + 3 * ps), coef_(3 + 3 * ps)};
    value_[s] = parent + std::ldexp(1.0, level - 1) * SignedSum(w, static_cast<int>(i & 1), static_cast<int>(j & 1));
    known_[s] = 1;
    return value_[s];
  }

 private:
  std::vector<double> value_;
  std::vector<uint8_t> known_;
  Coef coef_;
};

}  // namespace

double SublinearTripleProduct(const HaarFace& l, const HaarFace& v, const HaarFace& rho,
                              std::span<const uint32_t> l_terms, std::span<const uint32_t> rho_terms) {
  const uint64_t squares = (l.c.size() - 1) / 3;
  // ρ's approximation: its kept coefficients, zero elsewhere.
  std::vector<double> r(rho.c.size(), 0.0);
  r[0] = rho.c[0];  // the scaling coefficient is always kept
  std::vector<uint8_t> square_seen(squares, 0);
  std::vector<uint64_t> rho_squares;
  for (uint32_t k : rho_terms) {
    r[k] = rho.c[k];
    if (k > 0 && !square_seen[(k - 1) / 3]) {
      square_seen[(k - 1) / 3] = 1;
      rho_squares.push_back((k - 1) / 3);
    }
  }
  auto exact_l = [&](uint64_t k) { return l.c[k]; };
  auto exact_v = [&](uint64_t k) { return v.c[k]; };
  auto approx_r = [&](uint64_t k) { return r[k]; };
  LazyParentSums psum_l(squares, l.c[0], exact_l);
  LazyParentSums psum_v(squares, v.c[0], exact_v);
  LazyParentSums psum_r(squares, r[0], approx_r);

  double integral = r[0] * l.c[0] * v.c[0];
  for (uint64_t s : rho_squares) {  // case 2 over the squares of ρ's terms
    const HaarBasis b = BasisOf(1 + 3 * s);
    integral += Case2(&r[1 + 3 * s], &l.c[1 + 3 * s], &v.c[1 + 3 * s], std::ldexp(1.0, b.level));
  }
  for (uint32_t k : rho_terms) {  // case 3, ρ's wavelets: L and V exact
    if (k == 0) continue;
    const HaarBasis b = BasisOf(k);
    integral += r[k] * (l.c[k] * psum_v(b.level, b.i, b.j) + v.c[k] * psum_l(b.level, b.i, b.j));
  }
  for (uint32_t k : l_terms) {  // case 3, L's wavelets: the parent sums of ρ's approximation
    if (k == 0) continue;
    const HaarBasis b = BasisOf(k);
    integral += v.c[k] * l.c[k] * psum_r(b.level, b.i, b.j);
  }
  return integral;
}

}  // namespace ltb::triple
