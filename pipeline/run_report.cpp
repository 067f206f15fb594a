// run.html (pipeline/run_report.h): the run report as a page.
#include "pipeline/run_report.h"

#include <algorithm>
#include <cstdio>
#include <ctime>
#include <string>
#include <vector>

namespace ltb::pipeline {
namespace {

using nlohmann::json;

std::string Esc(const std::string& s) {
  std::string o;
  o.reserve(s.size());
  for (char c : s) {
    switch (c) {
      case '&':
        o += "&amp;";
        break;
      case '<':
        o += "&lt;";
        break;
      case '>':
        o += "&gt;";
        break;
      case '"':
        o += "&quot;";
        break;
      case '\'':
        o += "&#39;";
        break;
      default:
        o += c;
    }
  }
  return o;
}

std::string Num(double v, const char* fmt = "%.3g") {
  char b[48];
  std::snprintf(b, sizeof b, fmt, v);
  return b;
}

std::string Bytes(double b) {
  const char* unit[] = {"B", "KiB", "MiB", "GiB", "TiB"};
  int u = 0;
  while (b >= 1024 && u < 4) {
    b /= 1024;
    ++u;
  }
  return Num(b, u == 0 ? "%.0f" : "%.3g") + " " + unit[u];
}

std::string Str(const json& j, const char* key) {
  return j.is_object() && j.contains(key) && j[key].is_string() ? j[key].get<std::string>() : std::string();
}

double Number(const json& j, const char* key, double def = -1) {
  return j.is_object() && j.contains(key) && j[key].is_number() ? j[key].get<double>() : def;
}

double CpuSeconds(const json& e) {
  if (!e.contains("cpu_seconds") || !e["cpu_seconds"].is_object()) return -1;
  return std::max(0.0, Number(e["cpu_seconds"], "user", 0)) + std::max(0.0, Number(e["cpu_seconds"], "system", 0));
}

// A step of this run on the timeline: start offset and length in seconds.
struct Bar {
  std::string node, status;
  double start = 0, seconds = 0;
};

std::string Timeline(const std::vector<Bar>& bars) {
  if (bars.empty()) return "<p>No step ran in this run (everything was up to date).</p>\n";
  double end = 0;
  for (const Bar& b : bars) end = std::max(end, b.start + b.seconds);
  if (end <= 0) end = 1;
  const int label = 190, width = 560, row = 22;
  const int height = row * static_cast<int>(bars.size()) + 24;
  std::string s = "<svg class=\"timeline\" width=\"" + std::to_string(label + width + 90) + "\" height=\"" +
                  std::to_string(height) + "\" role=\"img\" aria-label=\"the steps on a timeline\">\n";
  for (size_t i = 0; i < bars.size(); ++i) {
    const Bar& b = bars[i];
    const double x = label + b.start / end * width, w = std::max(1.5, b.seconds / end * width);
    const int y = static_cast<int>(i) * row + 4;
    const char* fill = b.status == "done" ? "#4c9a6a" : b.status == "failed" ? "#c0392b" : "#8a8f98";
    s += "<text x=\"" + std::to_string(label - 8) + "\" y=\"" + std::to_string(y + 14) + "\" text-anchor=\"end\">" +
         Esc(b.node) + "</text>";
    s += "<rect x=\"" + Num(x, "%.1f") + "\" y=\"" + std::to_string(y) + "\" width=\"" + Num(w, "%.1f") +
         "\" height=\"16\" fill=\"" + fill + "\"><title>" + Esc(b.node) + ": " + Num(b.seconds) + " s from " +
         Num(b.start) + " s</title></rect>";
    s += "<text x=\"" + Num(x + w + 6, "%.1f") + "\" y=\"" + std::to_string(y + 13) + "\">" + Num(b.seconds) +
         " s</text>\n";
  }
  const int axis = row * static_cast<int>(bars.size()) + 18;
  s += "<text x=\"" + std::to_string(label) + "\" y=\"" + std::to_string(axis) + "\">0 s</text><text x=\"" +
       std::to_string(label + width) + "\" y=\"" + std::to_string(axis) + "\" text-anchor=\"end\">" + Num(end) +
       " s</text>\n</svg>\n";
  return s;
}

std::string StepTable(const json& stages) {
  std::string s =
      "<table>\n<tr><th>step</th><th>action</th><th>status</th><th>wall</th><th>CPU</th><th>peak memory</th>"
      "<th>output</th><th>size</th><th>content_hash</th></tr>\n";
  for (const json& e : stages) {
    const json out = e.value("output", json::object());
    const double wall = Number(e, "wall_seconds"), cpu = CpuSeconds(e), rss = Number(e, "peak_rss_bytes");
    const double bytes = Number(out, "bytes");
    s += "<tr><td>" + Esc(Str(e, "node")) + "</td><td title=\"" + Esc(Str(e, "reason")) + "\">" +
         Esc(Str(e, "action")) + "</td><td>" + Esc(Str(e, "status")) + "</td><td>" +
         (wall >= 0 ? Num(wall) + " s" : "") + "</td><td>" + (cpu >= 0 ? Num(cpu) + " s" : "") + "</td><td>" +
         (rss >= 0 ? Bytes(rss) : "") + "</td><td>" + Esc(Str(out, "file")) + "</td><td>" +
         (bytes >= 0 ? Bytes(bytes) : "") + "</td><td><code>" + Esc(Str(out, "content_hash")) + "</code></td></tr>\n";
  }
  return s + "</table>\n";
}

std::string ErrorText(const json& m) {
  auto part = [&](const char* key, const char* what) -> std::string {
    if (!m.contains(key) || !m[key].is_object()) return "";
    const json& e = m[key];
    std::string t = std::string(what) + ": rel. L2 " + Num(Number(e, "rel_l2", 0), "%.4f");
    if (e.contains("psnr_db")) t += ", PSNR " + Num(Number(e, "psnr_db", 0), "%.1f") + " dB";
    return t;
  };
  std::string t = part("error", "against the exact image");
  if (t.empty()) return "";
  for (const auto& [key, what] : {std::pair{"error_lighting_only", "lighting terms alone"},
                                  std::pair{"error_matrix_only", "matrix compression alone"}}) {
    const std::string p = part(key, what);
    if (!p.empty()) t += "<br>" + p;
  }
  return t;
}

std::string Previews(const json& stages) {
  std::string s;
  for (const json& e : stages) {
    const json out = e.value("output", json::object());
    const std::string file = Str(out, "file");
    auto ends = [&](const char* ext) {
      const std::string x = ext;
      return file.size() > x.size() && file.compare(file.size() - x.size(), x.size(), x) == 0;
    };
    if (file.empty() || Str(e, "status") != "done") continue;
    std::string media;
    if (ends(".png")) {
      media = "<img src=\"" + Esc(file) + "\" alt=\"" + Esc(file) + "\">";
    } else if (ends(".mp4")) {
      media = "<video src=\"" + Esc(file) + "\" controls loop></video>";
    } else if (ends(".exr")) {
      media = "<a href=\"" + Esc(file) + "\">" + Esc(file) + "</a> (OpenEXR: open it in an HDR viewer)";
    } else {
      continue;
    }
    const json m = e.value("metrics", json::object());
    std::string caption = "<b>" + Esc(Str(e, "node")) + "</b>";
    if (const double t = Number(m, "terms_used"); t >= 0) caption += ", " + Num(t, "%.0f") + " lighting terms";
    if (const double ms = Number(m, "relight_ms"); ms >= 0) caption += ", " + Num(ms) + " ms";
    if (const std::string err = ErrorText(m); !err.empty()) caption += "<br>" + err;
    s += "<figure>" + media + "<figcaption>" + caption + "</figcaption></figure>\n";
  }
  return s.empty() ? s : "<h2>Relit images</h2>\n<div class=\"figures\">\n" + s + "</div>\n";
}

}  // namespace

double ParseReportTime(const std::string& t) {
  std::tm tm{};
  int zone = 0;
  char sign = 0, tail = 0;
  if (std::sscanf(t.c_str(), "%4d-%2d-%2dT%2d:%2d:%2d%c%4d%c", &tm.tm_year, &tm.tm_mon, &tm.tm_mday, &tm.tm_hour,
                  &tm.tm_min, &tm.tm_sec, &sign, &zone, &tail) != 8 ||
      (sign != '+' && sign != '-')) {
    return -1;
  }
  tm.tm_year -= 1900;
  tm.tm_mon -= 1;
  const double offset = (zone / 100 * 3600 + zone % 100 * 60) * (sign == '-' ? -1.0 : 1.0);
  return static_cast<double>(timegm(&tm)) - offset;
}

std::string RunReportHtml(const json& report) {
  const json stages = report.value("stages", json::array());
  const json recipe = report.value("recipe", json::object());
  const double t0 = ParseReportTime(Str(report, "started"));
  std::vector<Bar> bars;
  double wall = 0, written = 0;
  for (const json& e : stages) {
    const double start = ParseReportTime(Str(e, "started")), seconds = Number(e, "wall_seconds");
    if (t0 < 0 || start < t0 || seconds < 0) continue;  // skipped, or made by an earlier run
    bars.push_back({Str(e, "node"), Str(e, "status"), start - t0, seconds});
    wall += seconds;
    if (e.contains("disk_bytes")) written += std::max(0.0, Number(e["disk_bytes"], "written", 0));
  }
  // Steps run one after another and run.json's times are whole seconds: a step starts at its
  // recorded second or when the one before it ended, whichever is later.
  std::stable_sort(bars.begin(), bars.end(), [](const Bar& a, const Bar& b) { return a.start < b.start; });
  for (size_t i = 1; i < bars.size(); ++i)
    bars[i].start = std::max(bars[i].start, bars[i - 1].start + bars[i - 1].seconds);
  const std::string name = Str(recipe, "name");
  std::string h = "<!doctype html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>ltbake run: " + Esc(name) +
                  "</title>\n<style>body{font:14px/1.4 system-ui,sans-serif;margin:2em;color:#222}"
                  "table{border-collapse:collapse}td,th{border:1px solid #ccc;padding:3px 8px;text-align:left}"
                  "svg text{font:12px system-ui,sans-serif}.figures{display:flex;flex-wrap:wrap;gap:1em}"
                  "figure{margin:0;width:256px}figure img,figure video{width:256px;image-rendering:pixelated}"
                  "code{font-size:12px}</style></head><body>\n";
  h += "<h1>" + Esc(name) + "</h1>\n<p>status <b>" + Esc(Str(report, "status")) + "</b>; started " +
       Esc(Str(report, "started")) + ", updated " + Esc(Str(report, "updated")) + "; ltbake " +
       Esc(Str(report, "ltbake")) + "<br>recipe <code>" + Esc(Str(recipe, "path")) + "</code>, work directory <code>" +
       Esc(Str(report, "workdir")) + "</code><br>this run: " + std::to_string(bars.size()) + " steps ran, " +
       Num(wall) + " s of steps, " + Bytes(written) + " written</p>\n";
  h += "<h2>Steps on a timeline (this run)</h2>\n" + Timeline(bars);
  h += "<h2>Every step</h2>\n" + StepTable(stages);
  h += Previews(stages);
  h += "<p>The same, in full: <a href=\"run.json\">run.json</a>; each step's log is in <code>logs/</code>.</p>\n";
  return h + "</body></html>\n";
}

}  // namespace ltb::pipeline
