// The run report as a page: `ltbake run` writes run.html beside run.json (docs/RECIPE.md
// "The run report"), with what people look at first — the steps on a timeline, how long each
// took and how much it wrote, and the relit images with their errors.
#pragma once

#include <nlohmann/json.hpp>
#include <string>

namespace ltb::pipeline {

// run.html from run.json's object: self-contained HTML (inline CSS and SVG; the relit
// images are linked by their file names, which sit beside run.html in the work directory).
// Every string from the report is escaped; missing fields are left out, never guessed.
std::string RunReportHtml(const nlohmann::json& report);

// "2026-11-26T09:24:56+0000" (run.json's timestamps, UTC) -> seconds since the epoch; -1
// for anything else.
double ParseReportTime(const std::string& t);

}  // namespace ltb::pipeline
