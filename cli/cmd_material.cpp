// ltbake material --brdf lambert|phong:S|blinn:S|ward:A|cook-torrance:M,F0 -o mat.ltm [--cube-res R]
//                 [--samples-res S] [--normals-res N] [--energy 0.9999]
#include <iostream>
#include <nlohmann/json.hpp>

#include "cli/commands.h"
#include "cli/common.h"
#include "format/json_text.h"
#include "stages/triple/material.h"

namespace ltb::cli {
namespace {

class MaterialCommand : public Command {
 public:
  explicit MaterialCommand(CLI::App* parent) {
    auto* app = parent->add_subcommand(
        "material",
        "tabulate a BRDF for the triple-product relighting (docs/TRIPLE.md): Haar coefficients of its lobe "
        "over the cubemap (lambert with the cosine), per sampled normal (lambert) or reflection vector (phong)");
    app->add_option("--brdf", brdf_,
                    "lambert[:ALBEDO], phong:EXPONENT[:KS], blinn:EXPONENT[:KS], ward:ALPHA[:KS] or "
                    "cook-torrance:M,F0[:KS]")
        ->required();
    app->add_option("-o,--output", options_.output, "output container (mat.ltm)")->required();
    app->add_option("--cube-res", options_.cube_res, "face size R of the lighting's cubemap (a power of two)")
        ->default_val(32);
    app->add_option("--samples-res", options_.samples_res,
                    "face size of the cube of sampled normals (lambert) / reflection vectors (default 16 for lambert, "
                    "32 for phong, 16 for blinn, ward, cook-torrance)");
    app->add_option("--normals-res", options_.normals_res,
                    "blinn, ward, cook-torrance: face size of the cube of sampled normals (default 4); rows are "
                    "every (normal, reflection vector) pair");
    app->add_option("--energy", options_.energy, "fraction of each row's energy the kept coefficients hold")
        ->default_val(0.9999);
    app->add_flag("--overwrite", options_.overwrite, "replace an output that was made with other parameters");
    app->add_flag("--json", json_, "print the summary as JSON");
    AddCommonFlags(app, &flags_);
  }

  int Run() override {
    auto brdf = triple::ParseBrdf(brdf_);
    if (!brdf.ok()) return ReportUsage(brdf.status());
    options_.brdf = *brdf;
    options_.jobs = flags_.jobs;
    ProgressBar bar(flags_, "material");
    auto r = triple::RunMaterial(options_, bar.hook());
    bar.Done();
    if (!r.ok()) return ReportFailure(r.status());
    const nlohmann::json out = {{"output", options_.output},
                                {"rows", r->rows},
                                {"cols", r->cols},
                                {"samples_res", r->samples_res},
                                {"normals_res", r->normals_res},
                                {"terms_kept", r->terms_kept},
                                {"worst_energy_kept", r->worst_energy_kept},
                                {"chunks_written", r->chunks_written},
                                {"chunks_already_committed", r->chunks_already_committed},
                                {"file_bytes", r->file_bytes}};
    if (json_) {
      std::cout << JsonText(out, 2) << "\n";
    } else if (!flags_.quiet) {
      std::cout << "wrote " << options_.output << ": " << r->rows << " sampled directions x " << r->cols
                << " Haar coefficients, " << r->terms_kept << " kept (" << HumanBytes(r->file_bytes) << ")\n";
    }
    return kExitOk;
  }

 private:
  triple::MaterialOptions options_;
  std::string brdf_;
  bool json_ = false;
  CommonFlags flags_;
};

}  // namespace

std::unique_ptr<Command> RegisterMaterial(CLI::App* parent) { return std::make_unique<MaterialCommand>(parent); }

}  // namespace ltb::cli
