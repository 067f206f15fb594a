// The BRDF model shared by the triple products (stages/triple), the material stage, the
// recipes and the in-out factorisation (brdf_factor.h): the lobes, their --brdf spelling and
// their value times the incident cosine.
#pragma once

#include <glm/vec3.hpp>
#include <string>

#include "format/status.h"

namespace ltb::brdf {

// A BRDF times the incident cosine, ρ̃, in global coordinates (docs/TRIPLE.md "The
// material"). Lambert depends on the normal n only, Phong on the reflection vector ω_r only
// (the paper's form, no cosine); the general isotropic ones on both: with the view
// ω_o = 2(n·ω_r)n − ω_r recovered from them, ρ̃(ω) = f(ω, ω_o)·max(0, n·ω), zero when ω_o is
// below the horizon.
struct Brdf {
  enum class Kind { kLambert, kPhong, kBlinn, kWard, kCookTorrance } kind = Kind::kLambert;
  double exponent = 0;   // Phong, Blinn s
  double albedo = 1;     // Lambert albedo; ks of the glossy ones
  double roughness = 0;  // Ward α, Cook-Torrance m (Beckmann slope)
  double f0 = 0;         // Cook-Torrance: Fresnel reflectance at normal incidence (Schlick)
  // Tabulated over (n, ω_r) rather than one direction.
  bool TwoDirections() const { return kind == Kind::kBlinn || kind == Kind::kWard || kind == Kind::kCookTorrance; }
  // The parameters equal (the field a scene material needs).
  bool SameLobe(const Brdf& o) const;
};
// "lambert[:ALBEDO]", "phong:S[:KS]", "blinn:S[:KS]", "ward:A[:KS]" or "ward:AX,AY[:KS]" (only
// isotropic, AX = AY: an anisotropic lobe needs a tangent frame per vertex),
// "cook-torrance:M,F0[:KS]".
Result<Brdf> ParseBrdf(const std::string& text);
// The --brdf spelling of a BRDF ("phong:64", "cook-torrance:0.3,0.04"), its albedo/ks omitted.
std::string BrdfSpec(const Brdf& brdf);
const char* BrdfKindName(Brdf::Kind kind);

// ρ̃ for the normal n and the reflection vector wr (unit; Lambert reads n only, Phong wr
// only) at the incident direction w (unit).
double BrdfValue(const Brdf& brdf, const glm::dvec3& n, const glm::dvec3& wr, const glm::dvec3& w);

}  // namespace ltb::brdf
