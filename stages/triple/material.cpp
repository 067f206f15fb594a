#include "stages/triple/material.h"

#include <cmath>
#include <numbers>
#include <vector>

#include "stages/common/cubemap.h"

namespace ltb::triple {

Result<Brdf> ParseBrdf(const std::string& text) {
  Brdf b;
  std::vector<std::string> parts;
  size_t start = 0;
  for (size_t k = 0; k <= text.size(); ++k) {
    if (k == text.size() || text[k] == ':') {
      parts.push_back(text.substr(start, k - start));
      start = k + 1;
    }
  }
  auto number = [&](size_t i, double* out) -> Status {
    char* end = nullptr;
    const double v = std::strtod(parts[i].c_str(), &end);
    if (parts[i].empty() || *end != '\0' || !std::isfinite(v) || v < 0) {
      return InvalidArgument("--brdf " + text + ": '" + parts[i] + "' is not a non-negative number");
    }
    *out = v;
    return Status::Ok();
  };
  if (parts[0] == "lambert" && parts.size() <= 2) {
    b.kind = Brdf::Kind::kLambert;
    if (parts.size() == 2) LTB_RETURN_IF_ERROR(number(1, &b.albedo));
    return b;
  }
  if (parts[0] == "phong" && (parts.size() == 2 || parts.size() == 3)) {
    b.kind = Brdf::Kind::kPhong;
    LTB_RETURN_IF_ERROR(number(1, &b.exponent));
    if (parts.size() == 3) LTB_RETURN_IF_ERROR(number(2, &b.albedo));
    return b;
  }
  return InvalidArgument("--brdf " + text + ": expected lambert[:ALBEDO] or phong:EXPONENT[:KS]");
}

CubeFaces MaterialFaces(const Brdf& brdf, const glm::dvec3& dir, uint64_t res) {
  CubeFaces faces;
  const uint32_t r = static_cast<uint32_t>(res);
  std::vector<double> pixels(res * res);
  const double area = static_cast<double>(res * res);  // texel solid angle × R²: unit-square measure
  for (int f = 0; f < 6; ++f) {
    for (uint32_t t = 0; t < r; ++t) {
      for (uint32_t s = 0; s < r; ++s) {
        const cubemap::Texel x{f, s, t};
        const double c = glm::dot(dir, cubemap::TexelCenter(x, r));
        double value = 0;
        if (c > 0) {
          value = brdf.kind == Brdf::Kind::kLambert
                      ? brdf.albedo / std::numbers::pi * c
                      : brdf.albedo * (brdf.exponent + 1) / (2 * std::numbers::pi) * std::pow(c, brdf.exponent);
        }
        pixels[t * res + s] = value * cubemap::TexelSolidAngle(x, r) * area;
      }
    }
    faces[f] = HaarFace::Forward(pixels, res);
  }
  return faces;
}

CubeFaces CubeFunctionFaces(const double* values, uint64_t res) {
  CubeFaces faces;
  for (int f = 0; f < 6; ++f) {
    faces[f] = HaarFace::Forward(std::span<const double>(values + f * res * res, res * res), res);
  }
  return faces;
}

double CubeTripleProduct(const CubeFaces& l, const CubeFaces& v, const CubeFaces& rho) {
  double b = 0;
  for (int f = 0; f < 6; ++f) b += LinearTripleProduct(l[f], v[f], rho[f]);
  return b;
}

}  // namespace ltb::triple
