// A small HTTP/1.1 server for `ltbake view`, made to stay answerable under load:
//   - one thread reads every connection (poll), so a client that sends its request a byte at
//     a time holds no worker; each request has a whole-request deadline (408 when it passes);
//   - complete requests go to a fixed pool of workers through a queue no longer than the
//     pool: a request that finds it full is answered 503 at once, as is a connection beyond
//     max_connections, so a busy server answers rather than leaving clients waiting;
//   - every response closes its connection (no keep-alive: nothing idles on a worker).
// GET (and HEAD) with a query string; POST with a body of at most max_body_bytes (given by
// Content-Length; 0 turns POST off), bodies of other methods refused (413). Bound to 127.0.0.1.
#pragma once

#include <cstdint>
#include <functional>
#include <map>
#include <string>
#include <utility>
#include <vector>

#include "format/status.h"

namespace ltb::stages::view {

struct HttpRequest {
  std::string method;  // GET, HEAD or POST
  std::string path;    // decoded, without the query
  // The query's parameters, percent-decoded ('+' is a space). A key given twice is refused
  // before the handler is called (400).
  std::map<std::string, std::string> params;
  // The head's fields, names in lower case (a field given twice: the last).
  std::map<std::string, std::string> headers;
  std::string body;  // a POST's (Content-Length bytes)
};

struct HttpResponse {
  int status = 200;
  std::string content_type = "text/plain; charset=utf-8";
  std::vector<std::pair<std::string, std::string>> headers;
  std::string body;
};

struct HttpServerOptions {
  int workers = 4;                        // handler threads
  uint64_t max_connections = 256;         // connections being read at once; more get 503
  double request_seconds = 5.0;           // from accept to the end of the request's head
  double write_seconds = 10.0;            // to write a response
  uint64_t max_request_bytes = 16 << 10;  // request line and headers
  // A POST's body: at most this many bytes (larger: 413 before it is read; 0: no POST, 405),
  // and at most this many held by the reading loop at once over every connection (503 past it).
  uint64_t max_body_bytes = 0;
  double body_seconds = 60.0;  // from the end of the head to the end of the body (408 past it)
};

// The reason phrase of a status code ("Not Found").
std::string HttpReason(int status);
// "a=1&b=x%20y" -> {a: "1", b: "x y"}; kInvalidArgument for a malformed escape or a key
// given twice (naming it).
Result<std::map<std::string, std::string>> ParseQuery(const std::string& query);

class HttpServer {
 public:
  using Handler = std::function<HttpResponse(const HttpRequest&)>;

  // Listens on 127.0.0.1:port (0: any free port).
  static Result<HttpServer> Listen(int port, const HttpServerOptions& options);
  HttpServer() = default;
  HttpServer(HttpServer&& other) noexcept;
  HttpServer& operator=(HttpServer&& other) noexcept;
  HttpServer(const HttpServer&) = delete;
  HttpServer& operator=(const HttpServer&) = delete;
  ~HttpServer();

  int port() const { return port_; }
  // Serves until stop() returns true (asked every 100 ms); the handler runs on the workers,
  // several at once (it does its own locking). A handler that throws gives a 500.
  Status Serve(const Handler& handler, const std::function<bool()>& stop);

 private:
  int fd_ = -1;
  int port_ = 0;
  HttpServerOptions options_;
};

}  // namespace ltb::stages::view
