#include "stages/triple/material_field.h"

#include <algorithm>
#include <cmath>
#include <glm/geometric.hpp>
#include <numeric>

#include "stages/common/cubemap.h"
#include "stages/triple/haar_triple.h"

namespace ltb::triple {

double L1Norm(uint64_t index) { return index == 0 ? 1.0 : std::ldexp(1.0, -BasisOf(index).level); }

Status ReadSparseRows(const io::ContainerReader& in, SparseRows* out) {
  const format::ArraySpec& a = in.metadata().matrix();
  if (a.dtype != format::DType::kF32 || a.layout != format::Layout::kRows) {
    return InvalidArgument(in.path() + ": the matrix must be f32 in row blocks");
  }
  out->rows = a.rows;
  out->cols = a.cols;
  out->offset.assign(1, 0);
  out->offset.reserve(a.rows + 1);
  for (uint64_t k = 0; k < a.ChunkCount(); ++k) {
    LTB_ASSIGN_OR_RETURN(format::SparseChunk c, in.ReadSparse(0, k));
    const auto values = c.as<float>();
    uint64_t e = 0;
    for (uint64_t r = 0; r < c.extent.rows; ++r) {
      const uint64_t end = (r + 1) * a.cols;
      for (; e < c.index.size() && c.index[e] < end; ++e) {
        if (values[e] == 0) continue;  // a stored -0 or 0
        out->col.push_back(static_cast<uint32_t>(c.index[e] - r * a.cols));
        out->val.push_back(values[e]);
      }
      out->offset.push_back(out->col.size());
    }
  }
  return Status::Ok();
}

Result<MaterialField> LoadMaterialField(const std::string& path, uint64_t res) {
  LTB_ASSIGN_OR_RETURN(io::ContainerReader in, io::ContainerReader::Open(path));
  if (!in.complete()) return FailedPrecondition(path + ": not complete; rerun `ltbake material` to finish it");
  const nlohmann::json& j = in.metadata().json;
  if (!j.contains("material") || !j["material"].is_object() || !j["material"].contains("brdf")) {
    return InvalidArgument(path + ": is not a material field (made by `ltbake material`)");
  }
  MaterialField m;
  m.path = path;
  try {
    const auto& b = j["material"]["brdf"];
    const std::string kind = b.at("kind").get<std::string>();
    m.brdf.albedo = b.at("albedo").get<double>();
    if (kind == "lambert") {
      m.brdf.kind = Brdf::Kind::kLambert;
    } else if (kind == "phong" || kind == "blinn") {
      m.brdf.kind = kind == "phong" ? Brdf::Kind::kPhong : Brdf::Kind::kBlinn;
      m.brdf.exponent = b.at("exponent").get<double>();
    } else if (kind == "ward" || kind == "cook-torrance") {
      m.brdf.kind = kind == "ward" ? Brdf::Kind::kWard : Brdf::Kind::kCookTorrance;
      m.brdf.roughness = b.at("roughness").get<double>();
      if (kind == "cook-torrance") m.brdf.f0 = b.at("f0").get<double>();
    } else {
      return InvalidArgument(path + ": material BRDF \"" + kind + "\" is not one this renderer knows");
    }
    if (m.brdf.TwoDirections()) m.nres = j["material"].at("normals_res").get<uint32_t>();
    m.sres = j["material"].at("samples_res").get<uint32_t>();
    const uint64_t field_res = j.at("basis").at("cols").at("cube_res").get<uint64_t>();
    if (field_res != res) {
      return InvalidArgument(path + ": the material field is at cube resolution " + std::to_string(field_res) +
                             " but the visibility field at " + std::to_string(res) +
                             "; make it again with --cube-res " + std::to_string(res));
    }
  } catch (const nlohmann::json::exception& e) {
    return InvalidArgument(path + ": malformed material metadata: " + e.what());
  }
  if (!(m.brdf.albedo > 0) || !std::isfinite(m.brdf.albedo)) {
    return InvalidArgument(path + ": the material field's albedo/ks is not a positive number");
  }
  if (m.sres < 1 || m.sres > 512 || (m.brdf.TwoDirections() && (m.nres < 1 || m.nres > 64))) {
    return InvalidArgument(path + ": samples_res " + std::to_string(m.sres) + " / normals_res " +
                           std::to_string(m.nres) + " out of range");
  }
  LTB_RETURN_IF_ERROR(ReadSparseRows(in, &m.rows));
  const uint64_t want_rows = 6ull * m.sres * m.sres * (m.brdf.TwoDirections() ? 6ull * m.nres * m.nres : 1);
  if (m.rows.rows != want_rows) {
    return InvalidArgument(path + ": " + std::to_string(m.rows.rows) + " rows, not the " + std::to_string(want_rows) +
                           " its sampled directions make");
  }
  const uint64_t face = res * res;
  std::vector<double> l1(face);
  for (uint64_t k = 0; k < face; ++k) l1[k] = L1Norm(k);
  m.scaling.resize(m.rows.rows);
  for (uint64_t r = 0; r < m.rows.rows; ++r) {
    const uint64_t b = m.rows.offset[r], e = m.rows.offset[r + 1];
    std::vector<uint64_t> order(e - b);
    std::iota(order.begin(), order.end(), b);
    std::sort(order.begin(), order.end(), [&](uint64_t x, uint64_t y) {
      const bool sx = m.rows.col[x] % face == 0, sy = m.rows.col[y] % face == 0;
      if (sx != sy) return sx;
      const double ax = std::fabs(m.rows.val[x]) * l1[m.rows.col[x] % face],
                   ay = std::fabs(m.rows.val[y]) * l1[m.rows.col[y] % face];
      return ax != ay ? ax > ay : m.rows.col[x] < m.rows.col[y];
    });
    std::vector<uint32_t> col(order.size());
    std::vector<float> val(order.size());
    for (size_t k = 0; k < order.size(); ++k) {
      col[k] = m.rows.col[order[k]];
      val[k] = m.rows.val[order[k]];
      if (col[k] % face == 0) m.scaling[r]++;
    }
    std::copy(col.begin(), col.end(), m.rows.col.begin() + static_cast<std::ptrdiff_t>(b));
    std::copy(val.begin(), val.end(), m.rows.val.begin() + static_cast<std::ptrdiff_t>(b));
  }
  return m;
}

bool Bilinear(const glm::dvec3& dir, uint32_t res, uint64_t index[4], double weight[4]) {
  if (!std::isfinite(dir.x) || !std::isfinite(dir.y) || !std::isfinite(dir.z) || glm::dot(dir, dir) < 1e-24) {
    return false;
  }
  int face = 0;
  double u = 0, v = 0;
  cubemap::DirectionToFace(dir, &face, &u, &v);
  const double x = (u + 1) / 2 * res - 0.5, y = (v + 1) / 2 * res - 0.5;
  const double fx0 = std::floor(x), fy0 = std::floor(y);
  const double ax = x - fx0, ay = y - fy0;
  const int64_t last = static_cast<int64_t>(res) - 1;
  auto clampi = [&](double t) { return static_cast<uint64_t>(std::clamp<int64_t>(static_cast<int64_t>(t), 0, last)); };
  const uint64_t xs[2] = {clampi(fx0), clampi(fx0 + 1)}, ys[2] = {clampi(fy0), clampi(fy0 + 1)};
  const double wx[2] = {1 - ax, ax}, wy[2] = {1 - ay, ay};
  for (int b = 0; b < 2; ++b) {
    for (int a = 0; a < 2; ++a) {
      index[2 * b + a] = (uint64_t(face) * res + ys[b]) * res + xs[a];
      weight[2 * b + a] = wx[a] * wy[b];
    }
  }
  return true;
}

void Interpolate(const MaterialField& f, const glm::dvec3& n, const glm::dvec3& wr, double scale,
                 std::vector<RhoPart>* out) {
  uint64_t ri[4], ni[4];
  double rw[4], nw[4];
  const double k = scale / f.brdf.albedo;
  if (!f.brdf.TwoDirections()) {
    if (!Bilinear(f.brdf.kind == Brdf::Kind::kLambert ? n : wr, f.sres, ri, rw)) return;
    for (int a = 0; a < 4; ++a) {
      if (rw[a] != 0) out->push_back({&f, ri[a], rw[a] * k});
    }
    return;
  }
  if (!Bilinear(n, f.nres, ni, nw) || !Bilinear(wr, f.sres, ri, rw)) return;
  const uint64_t per_normal = 6ull * f.sres * f.sres;
  for (int b = 0; b < 4; ++b) {
    for (int a = 0; a < 4; ++a) {
      const double w = nw[b] * rw[a];
      if (w != 0) out->push_back({&f, ni[b] * per_normal + ri[a], w * k});
    }
  }
}

}  // namespace ltb::triple
