#include "stages/view/server.h"

#include <httplib.h>

#include <atomic>
#include <chrono>
#include <mutex>
#include <thread>

namespace ltb::stages::view {

Status Serve(const ViewOptions& o, const std::function<void(const std::string& url)>& ready,
             const std::function<bool()>& stop) {
  LTB_ASSIGN_OR_RETURN(std::unique_ptr<ViewSession> session, ViewSession::Open(o));
  std::mutex mu;  // one frame at a time: the approximation carries from frame to frame
  httplib::Server server;
  // A browser keeps up to six connections open to a host; with fewer workers a new request
  // waits for an idle one to time out. Frames still render one at a time (the mutex).
  server.new_task_queue = [] { return new httplib::ThreadPool(8); };
  server.set_keep_alive_timeout(1);
  server.set_payload_max_length(1 << 16);
  server.set_read_timeout(5, 0);
  server.set_write_timeout(5, 0);
  auto params = [](const httplib::Request& req) -> Result<std::map<std::string, std::string>> {
    std::map<std::string, std::string> p;
    for (const auto& [k, v] : req.params) {
      if (!p.emplace(k, v).second) {
        return InvalidArgument("parameter \"" + (k.size() > 40 ? k.substr(0, 40) + "..." : k) + "\" is given twice");
      }
    }
    return p;
  };
  auto fail = [](httplib::Response& res, int code, const std::string& message) {
    res.status = code;
    res.set_content(message + "\n", "text/plain; charset=utf-8");
  };
  const FrameRequest& d = session->defaults();
  const std::string page =
      PageHtml(nlohmann::json{{"terms", TermsJson(d.terms)}, {"method", SequenceMethodName(d.method)}}.dump());
  server.Get("/", [&page](const httplib::Request&, httplib::Response& res) {
    res.set_header("Cache-Control", "no-store");
    res.set_content(page, "text/html; charset=utf-8");
  });
  server.Get("/frame.png", [&](const httplib::Request& req, httplib::Response& res) {
    auto p = params(req);
    if (!p.ok()) return fail(res, 400, p.status().message());
    auto q = ParseFrameRequest(*p, session->defaults());
    if (!q.ok()) return fail(res, 400, q.status().message());
    std::lock_guard<std::mutex> lock(mu);
    auto png = session->Render(*q);
    if (!png.ok()) return fail(res, 500, png.status().message());
    res.set_header("Cache-Control", "no-store");
    res.set_header("X-Ltb-Stats", session->stats().dump());
    res.set_content(std::move(*png), "image/png");
  });
  server.Get("/stats", [&](const httplib::Request&, httplib::Response& res) {
    std::lock_guard<std::mutex> lock(mu);
    res.set_header("Cache-Control", "no-store");
    res.set_content(session->stats().dump(), "application/json");
  });
  server.Get("/env.png", [&](const httplib::Request&, httplib::Response& res) {
    std::lock_guard<std::mutex> lock(mu);
    res.set_header("Cache-Control", "no-store");
    res.set_content(session->EnvironmentPng(256), "image/png");
  });
  server.set_error_handler([](const httplib::Request&, httplib::Response& res) {
    if (res.body.empty()) {
      res.set_content(std::to_string(res.status) + (res.status == 404 ? " not found" : " error") + "\n",
                      "text/plain; charset=utf-8");
    }
  });
  server.set_exception_handler([](const httplib::Request&, httplib::Response& res, std::exception_ptr) {
    res.status = 500;
    res.set_content("internal error\n", "text/plain; charset=utf-8");
  });

  int port = o.port;
  if (port == 0) {
    port = server.bind_to_any_port("127.0.0.1");
    if (port < 0) return IoError("view: cannot bind a port on 127.0.0.1", errno);
  } else if (!server.bind_to_port("127.0.0.1", port)) {
    return IoError("view: cannot listen on 127.0.0.1:" + std::to_string(port) + " (in use? pick another --port)",
                   errno);
  }
  std::atomic<bool> done{false};
  std::thread watcher([&] {
    while (!done.load()) {
      if (stop()) {
        server.stop();
        return;
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(100));
    }
  });
  ready("http://127.0.0.1:" + std::to_string(port) + "/");
  const bool ok = server.listen_after_bind();
  done = true;
  watcher.join();
  if (!ok && !stop()) return IoError("view: the server stopped listening", errno);
  return Status::Ok();
}

}  // namespace ltb::stages::view
