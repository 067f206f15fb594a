#include "stages/brdf/brdf_factor.h"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <glm/geometric.hpp>

namespace ltb::brdf {

void TangentFrame(const glm::dvec3& n, glm::dvec3* t, glm::dvec3* b) {
  const double sign = std::copysign(1.0, n.z);
  const double a = -1.0 / (sign + n.z);
  const double c = n.x * n.y * a;
  *t = glm::dvec3(1.0 + sign * n.x * n.x * a, sign * c, -sign * n.x);
  *b = glm::dvec3(c, sign + n.y * n.y * a, -n.y);
}

glm::dvec3 ParabolicTable::Direction(uint32_t res, uint32_t i, uint32_t j, double* solid_angle) {
  const double h = 2.0 / res;
  double u = -1.0 + (i + 0.5) * h, v = -1.0 + (j + 0.5) * h;
  double s = u * u + v * v;
  if (s >= 1.0) {  // outside the disk: the horizon direction of the same azimuth
    *solid_angle = 0.0;
    const double r = std::sqrt(s);
    u /= r;
    v /= r;
    s = 1.0;
  } else {
    *solid_angle = 4.0 / ((1.0 + s) * (1.0 + s)) * h * h;
  }
  return glm::dvec3(2 * u, 2 * v, 1.0 - s) / (1.0 + s);
}

ParabolicCoords::ParabolicCoords(uint32_t res, const glm::dvec3& w) {
  glm::dvec3 d = w;
  if (d.z < 0) d.z = 0;
  const double len = glm::length(d);
  if (len > 0) {
    d /= len;
  } else {
    d = glm::dvec3(0, 0, 1);
  }
  const double u = d.x / (1.0 + d.z), v = d.y / (1.0 + d.z);
  const double fu = std::clamp((u + 1.0) * 0.5 * res - 0.5, 0.0, res - 1.0);
  const double fv = std::clamp((v + 1.0) * 0.5 * res - 0.5, 0.0, res - 1.0);
  i0 = static_cast<uint32_t>(fu);
  j0 = static_cast<uint32_t>(fv);
  i1 = std::min(i0 + 1, res - 1);
  j1 = std::min(j0 + 1, res - 1);
  a = fu - i0;
  b = fv - j0;
}

double ParabolicTable::At(const ParabolicCoords& c) const {
  const float* row0 = value.data() + static_cast<size_t>(c.j0) * res;
  const float* row1 = value.data() + static_cast<size_t>(c.j1) * res;
  return (1 - c.b) * ((1 - c.a) * row0[c.i0] + c.a * row0[c.i1]) + c.b * ((1 - c.a) * row1[c.i0] + c.a * row1[c.i1]);
}

double BrdfFactors::Eval(const glm::dvec3& w, const glm::dvec3& wo) const {
  const double len = glm::length(w);
  if (!(w.z > 0) || !(len > 0)) return 0.0;
  double s = 0;
  for (uint32_t k = 0; k < f.size(); ++k) s += f[k].Lookup(w) * g[k].Lookup(wo);
  return s * w.z / len;
}

double PhongCos(double albedo, double ks, double exponent, const glm::dvec3& w, const glm::dvec3& wo) {
  if (w.z <= 0) return 0.0;
  double f = albedo / M_PI;
  if (ks > 0) {
    const glm::dvec3 r(-wo.x, -wo.y, wo.z);  // the mirror of wo about z
    const double c = glm::dot(r, w);
    if (c > 0) f += ks * (exponent + 2) / (2 * M_PI) * std::pow(c, exponent);
  }
  return f * w.z;
}

Result<BrdfFactors> FactorPhong(double albedo, double ks, double exponent, uint32_t terms, uint32_t incident_res,
                                uint32_t view_res) {
  if (terms < 1 || terms > 64) return InvalidArgument("--factor " + std::to_string(terms) + ": expected 1..64");
  BrdfFactors out;
  out.terms = terms;
  const uint32_t max_rank = std::max<uint32_t>(terms, 8);
  // Incident and view cells (all, for the tables) and their solid angles (0 outside the disk).
  const uint32_t ni = incident_res * incident_res, nv = view_res * view_res;
  std::vector<glm::dvec3> wi(ni), wv(nv);
  std::vector<double> ai(ni), av(nv);
  for (uint32_t j = 0; j < incident_res; ++j)
    for (uint32_t i = 0; i < incident_res; ++i)
      wi[j * incident_res + i] = ParabolicTable::Direction(incident_res, i, j, &ai[j * incident_res + i]);
  for (uint32_t j = 0; j < view_res; ++j)
    for (uint32_t i = 0; i < view_res; ++i)
      wv[j * view_res + i] = ParabolicTable::Direction(view_res, i, j, &av[j * view_res + i]);
  std::vector<uint32_t> in_i, in_v;
  for (uint32_t k = 0; k < ni; ++k)
    if (ai[k] > 0) in_i.push_back(k);
  for (uint32_t k = 0; k < nv; ++k)
    if (av[k] > 0) in_v.push_back(k);
  // The glossy part, solid-angle weighted: A[i][j] = √a_i·ks·lobe·cos·√a_j (the diffuse part
  // albedo/π·cos is term 0, exact, g_0 = 1). ‖full‖² for the relative errors.
  using Mat = Eigen::MatrixXd;
  Mat a(in_i.size(), in_v.size());
  double full2 = 0;
  for (size_t jj = 0; jj < in_v.size(); ++jj) {
    const glm::dvec3& o = wv[in_v[jj]];
    const double sv = std::sqrt(av[in_v[jj]]);
    for (size_t ii = 0; ii < in_i.size(); ++ii) {
      const glm::dvec3& w = wi[in_i[ii]];
      const double si = std::sqrt(ai[in_i[ii]]);
      const double glossy = PhongCos(0.0, ks, exponent, w, o), diffuse = albedo / M_PI * w.z;
      a(static_cast<Eigen::Index>(ii), static_cast<Eigen::Index>(jj)) = si * glossy * sv;
      const double full = si * (glossy + diffuse) * sv;
      full2 += full * full;
    }
  }
  std::vector<double> sigma2;
  Mat v;
  if (ks > 0 && terms > 1) {
    const Mat c = a.transpose() * a;
    Eigen::SelfAdjointEigenSolver<Mat> es(c);
    if (es.info() != Eigen::Success) return Internal("the BRDF factorisation's eigensolver did not converge");
    // Largest first.
    const Eigen::Index n = c.rows();
    v.resize(n, n);
    for (Eigen::Index k = 0; k < n; ++k) {
      sigma2.push_back(std::max(0.0, es.eigenvalues()(n - 1 - k)));
      v.col(k) = es.eigenvectors().col(n - 1 - k);
    }
  } else if (ks > 0) {
    Eigen::SelfAdjointEigenSolver<Mat> es(a.transpose() * a, Eigen::EigenvaluesOnly);
    for (Eigen::Index k = es.eigenvalues().size() - 1; k >= 0; --k)
      sigma2.push_back(std::max(0.0, es.eigenvalues()(k)));
  }
  double tail = 0;
  for (double s : sigma2) tail += s;
  // K terms: the diffuse one and K − 1 glossy ones.
  for (uint32_t k = 1; k <= max_rank; ++k) {
    double rest = tail;
    for (uint32_t m = 0; m + 1 < k && m < sigma2.size(); ++m) rest -= sigma2[m];
    out.error.push_back(full2 > 0 ? std::sqrt(std::max(0.0, rest) / full2) : 0.0);
  }
  // Term 0: f = albedo/π (the diffuse bake computes it exactly; the table is for Eval).
  ParabolicTable f0{incident_res, std::vector<float>(ni, static_cast<float>(albedo / M_PI))},
      g0{view_res, std::vector<float>(nv, 1.0f)};
  // The glossy lobe without the cosine (horizon cells: the limit, cos → 0 cancels).
  auto lobe = [&](const glm::dvec3& w, const glm::dvec3& o) {
    const glm::dvec3 r(-o.x, -o.y, o.z);
    const double c = glm::dot(r, w);
    return c > 0 ? ks * (exponent + 2) / (2 * M_PI) * std::pow(c, exponent) : 0.0;
  };
  out.f.push_back(std::move(f0));
  out.g.push_back(std::move(g0));
  for (uint32_t k = 1; k < terms; ++k) {
    ParabolicTable fk{incident_res, std::vector<float>(ni, 0.0f)}, gk{view_res, std::vector<float>(nv, 0.0f)};
    const uint32_t col = k - 1;
    if (col < sigma2.size() && sigma2[col] > 1e-30 * (tail > 0 ? tail : 1.0) && v.cols() > col) {
      // f_k(ω) = cos θ·Σ_j lobe(ω, ω_j)·√a_j·v_jk for every incident cell (the disk's and
      // the rest's); the table holds the sum, f_k / cos θ.
      std::vector<double> fv(ni, 0.0);
      for (uint32_t i = 0; i < ni; ++i) {
        double s = 0;
        for (size_t jj = 0; jj < in_v.size(); ++jj) {
          s += lobe(wi[i], wv[in_v[jj]]) * std::sqrt(av[in_v[jj]]) * v(static_cast<Eigen::Index>(jj), col);
        }
        fv[i] = s * wi[i].z;
        fk.value[i] = static_cast<float>(s);
      }
      // g_k(ω_o) = Σ_i f_k(ω_i)·a_i·G(ω_i, ω_o) / σ_k² (= v_jk/√a_j on the disk's cells).
      for (uint32_t j = 0; j < nv; ++j) {
        double s = 0;
        for (uint32_t ii : in_i) s += fv[ii] * ai[ii] * lobe(wi[ii], wv[j]) * wi[ii].z;
        gk.value[j] = static_cast<float>(s / sigma2[col]);
      }
    }
    out.f.push_back(std::move(fk));
    out.g.push_back(std::move(gk));
  }
  return out;
}

}  // namespace ltb::brdf
