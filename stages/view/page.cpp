// The page `ltbake view` serves: plain HTML, CSS and JavaScript in one response, nothing
// fetched from elsewhere. One frame request is in flight at a time; while the lighting holds
// and an incremental method still has terms to apply, it keeps asking for frames (the image
// converges), then waits for the next input.
#include "stages/view/server.h"

namespace ltb::stages::view {

namespace {

// The page, its defaults (LTB_DEFAULTS) filled in by PageHtml.
constexpr const char* kPage = R"HTML(<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>ltbake view</title>
<style>
body{font:14px system-ui,sans-serif;margin:16px;background:#1b1b1b;color:#ddd}
#frame{cursor:grab;image-rendering:pixelated;border:1px solid #444;user-select:none;-webkit-user-drag:none;width:512px}
#env{display:block;margin-top:8px;border:1px solid #444;width:512px}
.row{margin:6px 0}label{display:inline-block;width:90px}
#figures span{display:inline-block;min-width:90px;margin-right:14px}
a{color:#8cf}
</style></head><body>
<h3>ltbake view <small id="matrix"></small></h3>
<div style="display:flex;gap:24px;flex-wrap:wrap">
<div><img id="frame" alt="relit frame" draggable="false"><div><small id="draghint">drag to rotate the environment</small></div></div>
<div>
<div class="row"><label for="map">map</label><select id="map"></select>
<label for="upload" id="uploadlabel" style="width:auto;cursor:pointer;color:#8cf">add a map…</label>
<input id="upload" type="file" accept=".exr,.hdr" hidden> <small id="uploadmsg"></small></div>
<div class="row"><label for="method">method</label><select id="method">
<option value="pbi">PBI (per-band incremental)</option><option value="bi">BI (basic incremental)</option>
<option value="nwa">NWA (non-incremental)</option></select></div>
<div class="row"><label for="terms">terms</label><input id="terms" type="range" min="1" max="500" value="100">
<span id="termsval">100</span> <label style="width:auto"><input id="allterms" type="checkbox"> all</label></div>
<div class="row"><label for="exposure">exposure</label><input id="exposure" type="range" min="-6" max="6" step="0.25" value="0">
<span id="expval">0 stops</span></div>
<div class="row"><label for="show">show</label><select id="show">
<option value="matrix">the matrix (A)</option><option value="reference">the reference (B)</option>
<option value="difference">|A − B|</option></select> <small id="showhint"></small></div>
<div class="row"><label>rotation</label><span id="rotval">0°</span></div>
<div class="row" id="lightrow" hidden><label for="light">light</label><input id="light" type="range" min="-180" max="180" step="1" value="0">
<span id="lightval">0°</span></div>
<div class="row" id="eyerow" hidden><label>eye</label><span id="eyeval">orbit 0°, tilt 0°</span></div>
<div class="row" id="timerow" hidden><label for="time">time</label><input id="time" type="range" min="0" max="0" value="0">
<span id="timeval">frame 0</span> <button id="play" type="button">play</button></div>
<div class="row"><a id="save" download="ltbake-frame.png" href="#">save this frame (PNG)</a> · <a id="saveexr" download="ltbake-frame.exr" href="#">linear (EXR)</a></div>
<div id="figures" class="row"><span id="ms">– ms</span><span id="used">– terms</span><span id="err"></span><span id="count">0 frames</span></div>
<div class="row"><small id="bands"></small></div>
<img id="env" alt="environment (lat-long), the frame's terms in red"><div><small>the frame's terms in red, finer
levels stronger</small></div>
</div></div>
<script>
"use strict";
const $ = (id) => document.getElementById(id);
const ltb = window.ltb = {frames: 0, rotate: 0, base: 0, last: null, stats: null, error: null};
const defaults = LTB_DEFAULTS;  // the command line's --terms and --method, filled in by the server
if (defaults.terms !== "all") { $("terms").value = defaults.terms; $("termsval").textContent = $("terms").value; }
// "all": every lighting term (--terms all, and a vertex bake's default: its lighting is relit
// once per change, so the exact one costs no more a frame); the slider waits meanwhile.
function showTerms() { $("terms").disabled = $("allterms").checked; $("termsval").textContent = $("allterms").checked ? "all" : $("terms").value; }
$("allterms").checked = defaults.terms === "all"; showTerms();
$("method").value = defaults.method;
function addMap(name, k) { const o = document.createElement("option"); o.value = k; o.textContent = name; $("map").appendChild(o); }
defaults.maps.forEach(addMap);
// A map from this computer (.exr or .hdr): sent to the server (POST /map), which checks and
// loads it like an --env map; it joins the map control and is shown.
$("upload").addEventListener("change", async () => {
  const f = $("upload").files[0], msg = $("uploadmsg");
  $("upload").value = "";
  if (!f) return;
  const name = f.name.replace(/[^A-Za-z0-9._-]/g, "_").replace(/^\./, "_");
  if (f.size > defaults.max_upload_bytes) {
    msg.textContent = f.name + " is " + (f.size / 1048576).toFixed(1) + " MiB; the most the server takes is " +
      (defaults.max_upload_bytes / 1048576).toFixed(0) + " MiB (give it as --env, or raise --mem-limit)";
    ltb.upload = {error: msg.textContent}; return;
  }
  msg.textContent = "loading " + name + "…";
  try {
    const res = await fetch("/map?name=" + encodeURIComponent(name), {method: "POST", body: f, headers: {"X-Ltb-Upload": "1"}});
    const text = await res.text();
    if (!res.ok) throw new Error(text.trim());
    const r = JSON.parse(text);
    addMap(r.maps[r.map], r.map);
    $("map").value = String(r.map); ltb.base = 0;  // the new map, at its own automatic exposure
    msg.textContent = "added " + r.maps[r.map]; ltb.upload = {map: r.map, name: r.maps[r.map]}; poke();
  } catch (e) {
    msg.textContent = String(e.message || e); ltb.upload = {error: msg.textContent};
  }
});
if (!defaults.reference) {  // A/B needs ltbake view --reference FILE
  for (const o of $("show").options) if (o.value !== "matrix") o.disabled = true;
  $("showhint").textContent = "(start with --reference to compare)";
}
// A vertex bake is seen from an eye: dragging moves the eye (sideways: orbit about +Z through
// the target, up and down: tilt), the light slider turns the environment; it is relit afresh
// every frame (NWA), so the incremental methods are not offered.
ltb.orbit = 0; ltb.tilt = 0;
if (defaults.from_eye) {
  $("lightrow").hidden = false; $("eyerow").hidden = false;
  $("draghint").textContent = "drag to move the eye (sideways: orbit, up and down: tilt)";
  for (const o of $("method").options) if (o.value !== "nwa") o.disabled = true;
  $("method").value = "nwa";
}
let dirty = true, wake = null;
function poke() { dirty = true; if (wake) { const w = wake; wake = null; w(); } }
function params() {
  const stops = parseFloat($("exposure").value);
  const exposure = ltb.base > 0 ? ltb.base * Math.pow(2, stops) : 0;
  const p = {map: $("map").value, rotate: ltb.rotate.toFixed(3), terms: $("allterms").checked ? "all" : $("terms").value, method: $("method").value, exposure: exposure,
          show: $("show").value};
  if (defaults.from_eye) { p.orbit = ltb.orbit.toFixed(3); p.tilt = ltb.tilt.toFixed(3); }
  if (defaults.sequence_frames > 0) p.t = $("time").value;  // the --sequence frame shown
  return p;
}
// --sequence: the time slider scrubs it; play steps one frame per frame received (so the
// incremental methods see the sequence as relight --sequence does), from the end back to 0.
ltb.playing = false;
if (defaults.sequence_frames > 0) {
  $("timerow").hidden = false;
  $("time").max = defaults.sequence_frames - 1;
  const show = () => { $("timeval").textContent = "frame " + $("time").value + " of " + defaults.sequence_frames; };
  show();
  $("time").addEventListener("input", () => { show(); poke(); });
  $("play").addEventListener("click", () => {
    ltb.playing = !ltb.playing; $("play").textContent = ltb.playing ? "pause" : "play"; poke();
  });
  ltb.step = () => { $("time").value = (parseInt($("time").value) + 1) % defaults.sequence_frames; show(); };
}
let dragging = false, lastX = 0, lastY = 0;
$("frame").addEventListener("pointerdown", (e) => { dragging = true; lastX = e.clientX; lastY = e.clientY; $("frame").setPointerCapture(e.pointerId); e.preventDefault(); });
$("frame").addEventListener("pointermove", (e) => {
  if (!dragging) return;
  if (defaults.from_eye) {  // the eye: dragging right turns the scene right (the eye left)
    ltb.orbit -= (e.clientX - lastX) * 0.5;
    ltb.tilt = Math.max(-170, Math.min(170, ltb.tilt + (e.clientY - lastY) * 0.5));
    $("eyeval").textContent = "orbit " + ltb.orbit.toFixed(1) + "°, tilt " + ltb.tilt.toFixed(1) + "°";
  } else {
    ltb.rotate += (e.clientX - lastX) * 0.5;
    $("rotval").textContent = ltb.rotate.toFixed(1) + "°";
  }
  lastX = e.clientX; lastY = e.clientY; poke();
});
$("light").addEventListener("input", () => {
  ltb.rotate = parseFloat($("light").value);
  $("lightval").textContent = $("light").value + "°"; $("rotval").textContent = ltb.rotate.toFixed(1) + "°"; poke();
});
for (const ev of ["pointerup", "pointercancel"]) $("frame").addEventListener(ev, () => { dragging = false; });
$("terms").addEventListener("input", () => { showTerms(); poke(); });
$("allterms").addEventListener("change", () => { showTerms(); poke(); });
$("method").addEventListener("change", poke);
$("map").addEventListener("change", () => { ltb.base = 0; poke(); });  // a new map: its own automatic exposure
$("show").addEventListener("change", poke);
$("exposure").addEventListener("input", () => { $("expval").textContent = $("exposure").value + " stops"; poke(); });
async function frame() {
  const p = params();
  const url = "/frame.png?" + new URLSearchParams(p).toString();
  const res = await fetch(url, {cache: "no-store"});
  if (!res.ok) throw new Error(await res.text());
  const stats = JSON.parse(res.headers.get("X-Ltb-Stats"));
  const blob = await res.blob();
  const img = $("frame");
  const old = img.src;
  await new Promise((ok, bad) => { img.onload = ok; img.onerror = bad; img.src = URL.createObjectURL(blob); });
  if (old.startsWith("blob:")) URL.revokeObjectURL(old);
  $("save").href = img.src;  // the frame as shown, named by what it is
  const name = "ltbake-" + stats.map_name.replace(/\.[^.]*$/, "") + "-" + p.show + "-" + p.method + "-" + p.terms + "-rot" + ltb.rotate.toFixed(1);
  $("save").download = name + ".png";
  $("saveexr").href = "/frame.exr?frame=" + stats.frame;  // the same frame, linear (the server keeps the last one)
  $("saveexr").download = name + ".exr";
  if (ltb.base === 0) ltb.base = stats.exposure;
  ltb.frames += 1; ltb.last = p; ltb.stats = stats;
  $("ms").textContent = stats.ms.toFixed(2) + " ms";
  $("used").textContent = stats.terms_used + " terms (" + stats.terms_in_effect + " in effect)";
  $("err").textContent = "rel_l2" in stats ? "error " + (100 * stats.rel_l2).toFixed(2) + "%" : "";
  if (stats.show === "difference" && stats.exposure > 0) {
    $("showhint").textContent = "at " + (stats.difference_exposure / stats.exposure).toPrecision(3) + "× the frame's exposure";
  } else if (defaults.reference) {
    $("showhint").textContent = "";
  }
  $("count").textContent = ltb.frames + " frames";
  $("bands").textContent = "bands: " + stats.bands.map((b) => b.terms + (b.incremental ? "i" : "r")).join(" ");
  $("env").src = "/env.png?f=" + stats.frame;
  return stats;
}
async function loop() {
  for (;;) {
    if (!dirty) await new Promise((ok) => { wake = ok; });
    dirty = false;
    try {
      const s = await frame();
      // Keep converging while the lighting holds and terms are still being applied.
      if (s.method !== "nwa" && s.columns_touched > 0) dirty = true;
      if (ltb.playing) { ltb.step(); dirty = true; }
    } catch (e) {
      ltb.error = String(e); $("err").textContent = ltb.error;
      await new Promise((ok) => setTimeout(ok, 500));
    }
  }
}
loop();
</script></body></html>
)HTML";

}  // namespace

std::string PageHtml(const std::string& defaults_json) {
  std::string page = kPage;
  const std::string marker = "LTB_DEFAULTS;";
  page.replace(page.find(marker), marker.size() - 1, defaults_json);
  return page;
}

}  // namespace ltb::stages::view
