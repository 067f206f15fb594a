#include "stages/view/server.h"

#include <algorithm>
#include <mutex>
#include <optional>

#include "format/json_text.h"
#include "stages/view/http_server.h"

namespace ltb::stages::view {

Status Serve(const ViewOptions& o, const std::function<void(const std::string& url)>& ready,
             const std::function<bool()>& stop) {
  LTB_ASSIGN_OR_RETURN(std::unique_ptr<ViewSession> session, ViewSession::Open(o));
  std::mutex mu;  // one frame at a time: the approximation carries from frame to frame
  const FrameRequest& d = session->defaults();
  // An uploaded map's file (POST /map): a quarter of --mem-limit, within 16–512 MiB.
  HttpServerOptions http;
  http.max_body_bytes = std::clamp<uint64_t>(o.mem_limit / 4, 16ull << 20, 512ull << 20);
  // The page, made for each GET / so that a reload lists the maps uploaded so far.
  auto page = [&] {
    return PageHtml(JsonText(nlohmann::json{{"terms", TermsJson(d.terms)},
                                            {"method", SequenceMethodName(d.method)},
                                            {"reference", session->has_reference()},
                                            {"maps", session->map_names()},
                                            {"sequence_frames", session->sequence_frames()},
                                            {"max_upload_bytes", http.max_body_bytes},
                                            {"max_maps", ViewSession::kMaxMaps},
                                            {"from_eye", session->from_eye()}}));
  };

  auto fail = [](int code, const std::string& message) {
    HttpResponse r;
    r.status = code;
    r.body = message + "\n";
    return r;
  };
  auto handler = [&](const HttpRequest& req) -> HttpResponse {
    HttpResponse res;
    res.headers.push_back({"Cache-Control", "no-store"});
    if ((req.method == "POST") != (req.path == "/map")) {
      return fail(405, req.path == "/map" ? "/map takes a POST of the map's file"
                                          : "POST is taken only by /map (an environment map's file)");
    }
    if (req.path == "/map") {  // a map from the page: ?name=FILE.exr|.hdr, the file as the body
      // A page of another origin cannot send this header without asking first (CORS), which
      // this server never allows: only the page itself uploads.
      if (req.headers.count("x-ltb-upload") == 0)
        return fail(403, "an upload needs the header X-Ltb-Upload: 1 (the page sends it)");
      std::string name;
      for (const auto& [key, value] : req.params) {
        if (key != "name") return fail(400, key.substr(0, 40) + ": /map takes only name=FILE.exr or FILE.hdr");
        name = value;
      }
      // Loaded outside the lock (LoadMap changes nothing in the session, so frames keep
      // rendering while a big map loads), added under it (AddMap counts the maps again).
      auto loaded = session->LoadMap(name, req.body);
      Status failed = loaded.status();
      if (loaded.ok()) {
        std::lock_guard<std::mutex> lock(mu);
        auto k = session->AddMap(std::move(*loaded));
        if (k.ok()) {
          res.content_type = "application/json";
          res.body = JsonText(nlohmann::json{{"map", *k}, {"maps", session->map_names()}});
        }
        failed = k.status();
      }
      if (!failed.ok()) {
        const StatusCode c = failed.code();
        return fail(c == StatusCode::kInvalidArgument      ? 400
                    : c == StatusCode::kFailedPrecondition ? 409
                                                           : 500,
                    failed.message());
      }
    } else if (req.path == "/") {
      std::lock_guard<std::mutex> lock(mu);
      res.content_type = "text/html; charset=utf-8";
      res.body = page();
    } else if (req.path == "/frame.png") {
      std::lock_guard<std::mutex> lock(mu);  // before the maps are counted: an upload adds one
      auto q = ParseFrameRequest(req.params, session->defaults(), session->maps(), session->sequence_frames(),
                                 session->from_eye());
      if (!q.ok()) return fail(400, q.status().message());
      auto png = session->Render(*q);
      if (!png.ok())
        return fail(png.status().code() == StatusCode::kInvalidArgument ? 400 : 500, png.status().message());
      res.headers.push_back({"X-Ltb-Stats", JsonText(session->stats())});
      res.content_type = "image/png";
      res.body = std::move(*png);
    } else if (req.path == "/frame.exr") {  // the last frame, linear
      std::optional<uint64_t> frame;
      for (const auto& [key, value] : req.params) {
        frame = key == "frame" ? ParseIndex(value, 18) : std::nullopt;
        if (!frame) {
          return fail(400, key.substr(0, 40) + "=" + value.substr(0, 40) +
                               ": /frame.exr takes only frame=N (the number of the frame to save; optional)");
        }
      }
      std::lock_guard<std::mutex> lock(mu);
      auto exr = session->FrameExr(frame);
      if (!exr.ok())
        return fail(exr.status().code() == StatusCode::kFailedPrecondition ? 409 : 500, exr.status().message());
      res.content_type = "image/x-exr";
      res.body = std::move(*exr);
    } else if (req.path == "/stats") {
      std::lock_guard<std::mutex> lock(mu);
      res.content_type = "application/json";
      res.body = JsonText(session->stats());
    } else if (req.path == "/env.png") {
      std::lock_guard<std::mutex> lock(mu);
      res.content_type = "image/png";
      res.body = session->EnvironmentPng(256);
    } else {
      return fail(404, "404 not found");
    }
    return res;
  };
  LTB_ASSIGN_OR_RETURN(HttpServer server, HttpServer::Listen(o.port, http));
  ready("http://127.0.0.1:" + std::to_string(server.port()) + "/");
  return server.Serve(handler, stop);
}

}  // namespace ltb::stages::view
