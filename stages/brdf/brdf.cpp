#include "stages/brdf/brdf.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <glm/geometric.hpp>
#include <numbers>
#include <string>
#include <vector>

namespace ltb::brdf {

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
  auto number = [&](const std::string& part, double* out) -> Status {
    char* end = nullptr;
    const double v = std::strtod(part.c_str(), &end);
    if (part.empty() || *end != '\0' || !std::isfinite(v) || v < 0) {
      return InvalidArgument("--brdf " + text + ": '" + part + "' is not a non-negative number");
    }
    *out = v;
    return Status::Ok();
  };
  // "A,B" -> two numbers.
  auto pair = [&](const std::string& part, double* a, double* b) -> Status {
    const size_t comma = part.find(',');
    if (comma == std::string::npos)
      return InvalidArgument("--brdf " + text + ": '" + part + "' is not two numbers A,B");
    LTB_RETURN_IF_ERROR(number(part.substr(0, comma), a));
    return number(part.substr(comma + 1), b);
  };
  const std::string& kind = parts[0];
  if (kind == "lambert" && parts.size() <= 2) {
    b.kind = Brdf::Kind::kLambert;
    if (parts.size() == 2) LTB_RETURN_IF_ERROR(number(parts[1], &b.albedo));
    return b;
  }
  if (parts.size() < 2 || parts.size() > 3) {
    return InvalidArgument("--brdf " + text +
                           ": expected lambert[:ALBEDO], phong:S[:KS], blinn:S[:KS], ward:A[:KS] or "
                           "cook-torrance:M,F0[:KS]");
  }
  if (parts.size() == 3) LTB_RETURN_IF_ERROR(number(parts[2], &b.albedo));
  if (kind == "phong" || kind == "blinn") {
    b.kind = kind == "phong" ? Brdf::Kind::kPhong : Brdf::Kind::kBlinn;
    LTB_RETURN_IF_ERROR(number(parts[1], &b.exponent));
    return b;
  }
  if (kind == "ward") {
    b.kind = Brdf::Kind::kWard;
    if (parts[1].find(',') != std::string::npos) {
      double ay = 0;
      LTB_RETURN_IF_ERROR(pair(parts[1], &b.roughness, &ay));
      if (ay != b.roughness) {
        return InvalidArgument("--brdf " + text +
                               ": an anisotropic Ward lobe (ax != ay) needs a tangent frame per vertex, which "
                               "vertex rows do not have; give one roughness, ward:A");
      }
    } else {
      LTB_RETURN_IF_ERROR(number(parts[1], &b.roughness));
    }
  } else if (kind == "cook-torrance") {
    b.kind = Brdf::Kind::kCookTorrance;
    LTB_RETURN_IF_ERROR(pair(parts[1], &b.roughness, &b.f0));
    if (b.f0 > 1) return InvalidArgument("--brdf " + text + ": F0 is a reflectance in [0, 1]");
  } else {
    return InvalidArgument("--brdf " + text +
                           ": expected lambert[:ALBEDO], phong:S[:KS], blinn:S[:KS], ward:A[:KS] or "
                           "cook-torrance:M,F0[:KS]");
  }
  if (!(b.roughness > 0)) return InvalidArgument("--brdf " + text + ": the roughness must be positive");
  return b;
}

const char* BrdfKindName(Brdf::Kind kind) {
  switch (kind) {
    case Brdf::Kind::kLambert:
      return "lambert";
    case Brdf::Kind::kPhong:
      return "phong";
    case Brdf::Kind::kBlinn:
      return "blinn";
    case Brdf::Kind::kWard:
      return "ward";
    default:
      return "cook-torrance";
  }
}

std::string BrdfSpec(const Brdf& b) {
  char buf[96];
  switch (b.kind) {
    case Brdf::Kind::kLambert:
      return "lambert";
    case Brdf::Kind::kPhong:
    case Brdf::Kind::kBlinn:
      std::snprintf(buf, sizeof buf, "%s:%g", BrdfKindName(b.kind), b.exponent);
      return buf;
    case Brdf::Kind::kWard:
      std::snprintf(buf, sizeof buf, "ward:%g", b.roughness);
      return buf;
    default:
      std::snprintf(buf, sizeof buf, "cook-torrance:%g,%g", b.roughness, b.f0);
      return buf;
  }
}

bool Brdf::SameLobe(const Brdf& o) const {
  auto close = [](double a, double b) { return std::fabs(a - b) <= 1e-9 * std::max(std::fabs(a), std::fabs(b)); };
  return kind == o.kind && close(exponent, o.exponent) && close(roughness, o.roughness) && close(f0, o.f0);
}

double BrdfValue(const Brdf& brdf, const glm::dvec3& n, const glm::dvec3& wr, const glm::dvec3& w) {
  constexpr double kPi = std::numbers::pi;
  if (brdf.kind == Brdf::Kind::kLambert) {
    const double c = glm::dot(n, w);
    return c > 0 ? brdf.albedo / kPi * c : 0.0;
  }
  if (brdf.kind == Brdf::Kind::kPhong) {
    const double c = glm::dot(wr, w);
    return c > 0 ? brdf.albedo * (brdf.exponent + 1) / (2 * kPi) * std::pow(c, brdf.exponent) : 0.0;
  }
  const double nw = glm::dot(n, w);
  const glm::dvec3 wo = 2 * glm::dot(n, wr) * n - wr;
  const double no = glm::dot(n, wo);
  if (nw <= 0 || no <= 0) return 0;
  const glm::dvec3 hsum = w + wo;
  const double hl = glm::length(hsum);
  if (!(hl > 0)) return 0;
  const glm::dvec3 h = hsum / hl;
  const double nh = std::max(0.0, glm::dot(n, h));
  double f = 0;
  if (brdf.kind == Brdf::Kind::kBlinn) {  // normalised Blinn–Phong
    f = brdf.albedo * (brdf.exponent + 2) / (8 * kPi) * std::pow(nh, brdf.exponent);
  } else {
    const double a2 = brdf.roughness * brdf.roughness;
    const double cos2 = nh * nh;
    if (!(cos2 > 0)) return 0;
    const double tan2 = (1 - cos2) / cos2;
    if (brdf.kind == Brdf::Kind::kWard) {  // isotropic Ward
      f = brdf.albedo * std::exp(-tan2 / a2) / (4 * kPi * a2 * std::sqrt(nw * no));
    } else {  // Cook–Torrance: Beckmann D, Schlick F, the V-groove G
      const double d = std::exp(-tan2 / a2) / (kPi * a2 * cos2 * cos2);
      const double wh = std::max(0.0, glm::dot(w, h));
      const double fr = brdf.f0 + (1 - brdf.f0) * std::pow(1 - wh, 5);
      const double oh = glm::dot(wo, h);
      const double g = oh > 0 ? std::min({1.0, 2 * nh * no / oh, 2 * nh * nw / oh}) : 0.0;
      f = brdf.albedo * d * fr * g / (4 * nw * no);
    }
  }
  return f * nw;
}

}  // namespace ltb::brdf
