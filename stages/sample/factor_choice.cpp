#include "stages/sample/factor_choice.h"

#include <algorithm>
#include <cstdio>
#include <set>

#include "stages/brdf/brdf_factor.h"

namespace ltb::sample {

Result<FactorChoice> ChooseFactorTerms(const SceneDesc& s, double target, uint32_t incident_res, uint32_t view_res) {
  if (!(target > 0 && target < 1)) {
    char b[64];
    std::snprintf(b, sizeof b, "%g", target);
    return InvalidArgument(std::string("--factor auto:") + b + ": the error target must be in (0, 1), e.g. auto:5%");
  }
  if (s.mode != SceneDesc::Mode::kVertex) return InvalidArgument(s.path + ": --factor needs a vertex-mode scene");
  // The materials of the objects whose vertices are rows (a usemtl mesh: every material, as
  // which of them its faces pick is known only once the mesh is read).
  std::set<int> used;
  const std::set<std::string> rows(s.vertex_objects.begin(), s.vertex_objects.end());
  for (const Object& o : s.objects) {
    if (rows.count(o.name) == 0) continue;
    if (o.usemtl) {
      for (size_t m = 0; m < s.materials.size(); ++m) used.insert(static_cast<int>(m));
    } else {
      used.insert(o.material);
    }
  }
  FactorChoice c;
  std::vector<const Material*> glossy;
  for (int m : used) {
    const Material& mat = s.materials[static_cast<size_t>(m)];
    if (!(mat.ks > 0)) continue;
    if (mat.brdf != "phong") {
      return InvalidArgument(s.path + ": material \"" + mat.name + "\" has brdf \"" + mat.brdf +
                             "\"; sample --factor factors the Phong lobe only (the triple-product path renders the "
                             "others: docs/TRIPLE.md)");
    }
    LTB_ASSIGN_OR_RETURN(brdf::BrdfFactors f,
                         brdf::FactorPhong(mat.albedo, mat.ks, mat.exponent, kMaxFactorTerms, incident_res, view_res));
    c.errors.emplace_back(mat.name, f.error);
    glossy.push_back(&mat);
  }
  if (c.errors.empty()) return c;  // diffuse: K = 1 is exact
  for (uint32_t k = 1; k <= kMaxFactorTerms; ++k) {
    double worst = 0;
    std::string who;
    for (const auto& [name, e] : c.errors) {
      const double x = k <= e.size() ? e[k - 1] : e.back();
      if (x >= worst) {
        worst = x;
        who = name;
      }
    }
    c.terms = k;
    c.worst_error = worst;
    c.worst_material = who;
    if (worst <= target) return c;
  }
  char b[160];
  std::snprintf(b, sizeof b, "needs more than %u terms for a relative error of %g (at %u: %.3g)", kMaxFactorTerms,
                target, kMaxFactorTerms, c.worst_error);
  const auto it =
      std::find_if(glossy.begin(), glossy.end(), [&](const Material* m) { return m->name == c.worst_material; });
  char n[48];
  std::snprintf(n, sizeof n, " (Phong %g)", (*it)->exponent);
  return FailedPrecondition(s.path + ": material \"" + c.worst_material + "\"" + n + " " + b +
                            ": its lobe is too sharp for the in-out factorisation; render it with the "
                            "triple-product path (docs/TRIPLE.md), or allow a larger error");
}

}  // namespace ltb::sample
