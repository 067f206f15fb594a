#include "stages/view/http_server.h"

#include <arpa/inet.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <condition_variable>
#include <cstring>
#include <deque>
#include <mutex>
#include <thread>

namespace ltb::stages::view {

namespace {

using Clock = std::chrono::steady_clock;

// Connections the reading loop holds at most; beyond, a new one is answered 503 at once.
constexpr uint64_t kHardConnectionCap = 1024;

int HexDigit(char c) {
  if (c >= '0' && c <= '9') return c - '0';
  if (c >= 'a' && c <= 'f') return c - 'a' + 10;
  if (c >= 'A' && c <= 'F') return c - 'A' + 10;
  return -1;
}

Result<std::string> PercentDecode(const std::string& s, bool plus_is_space) {
  std::string out;
  out.reserve(s.size());
  for (size_t i = 0; i < s.size(); ++i) {
    if (s[i] == '%') {
      const int hi = i + 2 < s.size() ? HexDigit(s[i + 1]) : -1, lo = i + 2 < s.size() ? HexDigit(s[i + 2]) : -1;
      if (hi < 0 || lo < 0) {
        return InvalidArgument("malformed percent escape \"" + s.substr(i, 3) + "\" in \"" +
                               (s.size() > 60 ? s.substr(0, 60) + "..." : s) + "\"");
      }
      out += static_cast<char>(hi * 16 + lo);
      i += 2;
    } else {
      out += plus_is_space && s[i] == '+' ? ' ' : s[i];
    }
  }
  return out;
}

std::string Clip(const std::string& s) { return s.size() > 40 ? s.substr(0, 40) + "..." : s; }

std::string Serialize(const HttpResponse& r, bool head) {
  std::string out = "HTTP/1.1 " + std::to_string(r.status) + " " + HttpReason(r.status) + "\r\n";
  out += "Content-Type: " + r.content_type + "\r\n";
  out += "Content-Length: " + std::to_string(r.body.size()) + "\r\n";
  out += "Connection: close\r\n";
  for (const auto& [k, v] : r.headers) out += k + ": " + v + "\r\n";
  out += "\r\n";
  if (!head) out += r.body;
  return out;
}

HttpResponse Plain(int status, const std::string& message) {
  HttpResponse r;
  r.status = status;
  r.body = message + "\n";
  return r;
}

// Writes all of `bytes` to a non-blocking socket before `deadline`; false if it could not.
bool WriteAll(int fd, const std::string& bytes, Clock::time_point deadline) {
  size_t done = 0;
  while (done < bytes.size()) {
    const ssize_t n = ::send(fd, bytes.data() + done, bytes.size() - done, MSG_NOSIGNAL);
    if (n > 0) {
      done += static_cast<size_t>(n);
      continue;
    }
    if (n < 0 && errno == EINTR) continue;
    if (n < 0 && (errno == EAGAIN || errno == EWOULDBLOCK)) {
      const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(deadline - Clock::now()).count();
      if (left <= 0) return false;
      pollfd p{fd, POLLOUT, 0};
      if (::poll(&p, 1, static_cast<int>(std::min<int64_t>(left, 1000))) < 0 && errno != EINTR) return false;
      continue;
    }
    return false;
  }
  return true;
}

// Ends a connection after its response: no more writes, then close (the request was read
// whole, so the close does not reset what the client has yet to read).
void Finish(int fd) {
  ::shutdown(fd, SHUT_WR);
  ::close(fd);
}

// A response from the reading loop itself (errors, 503): short, never waits long.
void AnswerNow(int fd, const HttpResponse& r) {
  (void)WriteAll(fd, Serialize(r, false), Clock::now() + std::chrono::milliseconds(200));
  Finish(fd);
}

struct Parsed {
  HttpRequest request;
  int error = 0;  // an HTTP status to answer instead, with `message`
  std::string message;
  uint64_t body_bytes = 0;       // a POST's Content-Length
  bool expect_continue = false;  // "Expect: 100-continue": say so before the body comes
};

Parsed Refuse(int status, const std::string& message) {
  Parsed p;
  p.error = status;
  p.message = message;
  return p;
}

// The head's fields after the request line, names in lower case, values trimmed.
std::map<std::string, std::string> HeadFields(const std::string& head, size_t eol) {
  std::map<std::string, std::string> fields;
  for (size_t at = eol; at != std::string::npos && at + 2 < head.size();) {
    const size_t next = head.find("\r\n", at + 2);
    const std::string h = head.substr(at + 2, (next == std::string::npos ? head.size() : next) - at - 2);
    at = next;
    const size_t colon = h.find(':');
    if (colon == std::string::npos) continue;
    std::string name = h.substr(0, colon);
    std::transform(name.begin(), name.end(), name.begin(), [](unsigned char c) { return std::tolower(c); });
    const size_t v0 = h.find_first_not_of(" \t", colon + 1), v1 = h.find_last_not_of(" \t");
    fields[name] = v0 == std::string::npos ? std::string() : h.substr(v0, v1 - v0 + 1);
  }
  return fields;
}

// Over 60 lines: the request line, then the body rules per method, then the target, in order.
Parsed ParseHead(const std::string& head, uint64_t max_body_bytes) {
  const size_t eol = head.find("\r\n");
  const std::string line = head.substr(0, eol);
  const size_t a = line.find(' '), b = a == std::string::npos ? a : line.find(' ', a + 1);
  if (a == std::string::npos || b == std::string::npos || line.compare(b + 1, 7, "HTTP/1.") != 0) {
    return Refuse(400, "malformed request line \"" + Clip(line) + "\"");
  }
  Parsed p;
  p.request.method = line.substr(0, a);
  const std::string target = line.substr(a + 1, b - a - 1);
  const bool post = p.request.method == "POST" && max_body_bytes > 0;
  if (p.request.method != "GET" && p.request.method != "HEAD" && !post) {
    return Refuse(405, "method " + Clip(p.request.method) + " is not served (" +
                           (max_body_bytes > 0 ? "GET, HEAD and POST" : "GET only") + ")");
  }
  p.request.headers = HeadFields(head, eol);
  const auto& fields = p.request.headers;
  const auto length = fields.find("content-length");
  if (fields.count("transfer-encoding") != 0) {
    return post ? Refuse(411, "a chunked body is not taken: send its Content-Length")
                : Refuse(413, "a request body is not accepted");
  }
  if (!post) {  // GET and HEAD: no body (a Content-Length of 0 is fine)
    if (length != fields.end() && length->second.find_first_not_of("0") != std::string::npos)
      return Refuse(413, "a request body is not accepted");
  } else {
    if (length == fields.end()) return Refuse(411, "a POST needs a Content-Length");
    const std::string& v = length->second;
    if (v.empty() || v.size() > 18 || v.find_first_not_of("0123456789") != std::string::npos)
      return Refuse(400, "Content-Length \"" + Clip(v) + "\" is not a number of bytes");
    p.body_bytes = std::stoull(v);
    if (p.body_bytes > max_body_bytes) {
      return Refuse(413, "the body is " + v + " bytes; at most " + std::to_string(max_body_bytes) +
                             " are taken (ltbake view --mem-limit sets it)");
    }
    const auto expect = fields.find("expect");
    p.expect_continue = expect != fields.end() && expect->second == "100-continue";
  }
  const size_t q = target.find('?');
  auto path = PercentDecode(target.substr(0, q), false);
  if (!path.ok()) return Refuse(400, path.status().message());
  p.request.path = *path;
  if (q != std::string::npos) {
    auto params = ParseQuery(target.substr(q + 1));
    if (!params.ok()) return Refuse(400, params.status().message());
    p.request.params = std::move(params).value();
  }
  return p;
}

struct Job {
  int fd;
  HttpRequest request;
};

}  // namespace

std::string HttpReason(int status) {
  switch (status) {
    case 200:
      return "OK";
    case 400:
      return "Bad Request";
    case 403:
      return "Forbidden";
    case 404:
      return "Not Found";
    case 405:
      return "Method Not Allowed";
    case 408:
      return "Request Timeout";
    case 409:
      return "Conflict";
    case 411:
      return "Length Required";
    case 413:
      return "Payload Too Large";
    case 431:
      return "Request Header Fields Too Large";
    case 500:
      return "Internal Server Error";
    case 503:
      return "Service Unavailable";
  }
  return "Status";
}

Result<std::map<std::string, std::string>> ParseQuery(const std::string& query) {
  std::map<std::string, std::string> out;
  size_t at = 0;
  while (at <= query.size()) {
    const size_t amp = std::min(query.find('&', at), query.size());
    const std::string part = query.substr(at, amp - at);
    at = amp + 1;
    if (part.empty()) continue;
    const size_t eq = part.find('=');
    LTB_ASSIGN_OR_RETURN(std::string key, PercentDecode(part.substr(0, eq), true));
    LTB_ASSIGN_OR_RETURN(std::string value,
                         PercentDecode(eq == std::string::npos ? std::string() : part.substr(eq + 1), true));
    if (!out.emplace(key, value).second) return InvalidArgument("parameter \"" + Clip(key) + "\" is given twice");
  }
  return out;
}

Result<HttpServer> HttpServer::Listen(int port, const HttpServerOptions& options) {
  if (options.workers < 1 || options.max_connections < 1) return InvalidArgument("HttpServer: no workers");
  HttpServer s;
  s.options_ = options;
  s.fd_ = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC | SOCK_NONBLOCK, 0);
  if (s.fd_ < 0) return IoError("view: socket", errno);
  const int one = 1;
  ::setsockopt(s.fd_, SOL_SOCKET, SO_REUSEADDR, &one, sizeof one);
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_port = htons(static_cast<uint16_t>(port));
  addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  if (::bind(s.fd_, reinterpret_cast<sockaddr*>(&addr), sizeof addr) != 0) {
    return IoError("view: cannot listen on 127.0.0.1:" + std::to_string(port) + " (in use? pick another --port)",
                   errno);
  }
  if (::listen(s.fd_, 128) != 0) return IoError("view: listen", errno);
  socklen_t len = sizeof addr;
  if (::getsockname(s.fd_, reinterpret_cast<sockaddr*>(&addr), &len) != 0) return IoError("view: getsockname", errno);
  s.port_ = ntohs(addr.sin_port);
  return s;
}

HttpServer::HttpServer(HttpServer&& other) noexcept { *this = std::move(other); }

HttpServer& HttpServer::operator=(HttpServer&& other) noexcept {
  if (this != &other) {
    if (fd_ >= 0) ::close(fd_);
    fd_ = std::exchange(other.fd_, -1);
    port_ = other.port_;
    options_ = other.options_;
  }
  return *this;
}

HttpServer::~HttpServer() {
  if (fd_ >= 0) ::close(fd_);
}

// Over 120 lines: one poll loop whose deadline, read, hand-off and accept steps share the
// connection list and the work queue.
Status HttpServer::Serve(const Handler& handler, const std::function<bool()>& stop) {
  std::mutex mu;
  std::condition_variable cv;
  std::deque<Job> queue;
  bool quit = false;
  const auto write_time =
      std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(options_.write_seconds));
  auto work = [&] {
    for (;;) {
      Job job;
      {
        std::unique_lock<std::mutex> lock(mu);
        cv.wait(lock, [&] { return quit || !queue.empty(); });
        if (queue.empty()) return;
        job = std::move(queue.front());
        queue.pop_front();
      }
      HttpResponse r;
      try {
        r = handler(job.request);
      } catch (const std::exception& e) {
        r = Plain(500, std::string("internal error: ") + e.what());
      } catch (...) {
        r = Plain(500, "internal error");
      }
      (void)WriteAll(job.fd, Serialize(r, job.request.method == "HEAD"), Clock::now() + write_time);
      Finish(job.fd);
    }
  };
  std::vector<std::thread> workers;
  for (int i = 0; i < options_.workers; ++i) workers.emplace_back(work);

  struct Conn {
    int fd;
    std::string buf;
    Clock::time_point deadline;
    bool head_done = false;  // parsed: a POST's body is being read from body_at on
    Parsed parsed;
    size_t body_at = 0;
  };
  std::vector<Conn> conns;
  const auto request_time =
      std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(options_.request_seconds));
  const auto body_time =
      std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(options_.body_seconds));
  uint64_t held_body = 0;  // body bytes the connections being read have announced
  auto drop = [&](const Conn& c) { held_body -= c.head_done ? c.parsed.body_bytes : 0; };
  Status status;
  std::vector<pollfd> fds;
  std::vector<char> chunk(64 << 10);
  while (!stop()) {
    // Deadlines first: a request not whole by now is answered 408.
    const auto now = Clock::now();
    auto nearest = now + std::chrono::milliseconds(100);
    for (size_t i = 0; i < conns.size();) {
      if (conns[i].deadline <= now) {
        const bool body = conns[i].head_done;
        AnswerNow(
            conns[i].fd,
            Plain(408, std::string(body ? "the body" : "the request") + " did not arrive within " +
                           std::to_string(static_cast<int>(body ? options_.body_seconds : options_.request_seconds)) +
                           " s"));
        drop(conns[i]);
        conns[i] = std::move(conns.back());
        conns.pop_back();
      } else {
        nearest = std::min(nearest, conns[i].deadline);
        ++i;
      }
    }
    fds.assign(1, pollfd{fd_, POLLIN, 0});
    for (const Conn& c : conns) fds.push_back(pollfd{c.fd, POLLIN, 0});
    const auto wait = std::chrono::duration_cast<std::chrono::milliseconds>(nearest - now).count();
    const int n = ::poll(fds.data(), fds.size(), static_cast<int>(std::max<int64_t>(1, wait)));
    if (n < 0) {
      if (errno == EINTR) continue;
      status = IoError("view: poll", errno);
      break;
    }
    // Reading: fds[i + 1] is conns[i] (both in the order of this round).
    std::vector<size_t> gone;
    for (size_t i = 0; i < conns.size(); ++i) {
      if (fds[i + 1].revents == 0) continue;
      Conn& c = conns[i];
      const ssize_t got = ::recv(c.fd, chunk.data(), chunk.size(), 0);
      if (got < 0 && (errno == EAGAIN || errno == EINTR)) continue;
      if (got <= 0) {
        ::close(c.fd);
        drop(c);
        gone.push_back(i);
        continue;
      }
      c.buf.append(chunk.data(), static_cast<size_t>(got));
      if (!c.head_done) {
        const size_t end = c.buf.find("\r\n\r\n");
        if (end == std::string::npos) {
          if (c.buf.size() > options_.max_request_bytes) {
            AnswerNow(c.fd, Plain(431, "the request's head is over " + std::to_string(options_.max_request_bytes) +
                                           " bytes"));
            gone.push_back(i);
          }
          continue;
        }
        c.parsed = ParseHead(c.buf.substr(0, end), options_.max_body_bytes);
        if (c.parsed.error != 0) {
          AnswerNow(c.fd, Plain(c.parsed.error, c.parsed.message));
          gone.push_back(i);
          continue;
        }
        if (c.parsed.body_bytes > 0) {  // a POST: its body next, within the bytes held at once
          if (held_body + c.parsed.body_bytes > options_.max_body_bytes) {
            HttpResponse busy = Plain(503, "busy: another upload is being read; try again shortly");
            busy.headers.push_back({"Retry-After", "1"});
            AnswerNow(c.fd, busy);
            gone.push_back(i);
            continue;
          }
          held_body += c.parsed.body_bytes;
          c.head_done = true;
          c.body_at = end + 4;
          c.deadline = Clock::now() + body_time;
          c.buf.reserve(c.body_at + c.parsed.body_bytes);
          if (c.parsed.expect_continue)
            (void)WriteAll(c.fd, "HTTP/1.1 100 Continue\r\n\r\n", Clock::now() + std::chrono::milliseconds(200));
        }
      }
      if (c.head_done) {
        if (c.buf.size() - c.body_at < c.parsed.body_bytes) continue;
        c.parsed.request.body = c.buf.substr(c.body_at, c.parsed.body_bytes);
        drop(c);
      }
      gone.push_back(i);
      std::unique_lock<std::mutex> lock(mu);
      if (queue.size() >= static_cast<size_t>(options_.workers)) {
        lock.unlock();
        HttpResponse busy = Plain(
            503, "busy: " + std::to_string(options_.workers) + " requests are waiting already; try again shortly");
        busy.headers.push_back({"Retry-After", "1"});
        AnswerNow(c.fd, busy);
        continue;
      }
      queue.push_back(Job{c.fd, std::move(c.parsed.request)});
      lock.unlock();
      cv.notify_one();
    }
    for (auto it = gone.rbegin(); it != gone.rend(); ++it) {
      conns[*it] = std::move(conns.back());
      conns.pop_back();
    }
    // New connections: each gets the whole-request deadline; past the caps, 503 at once.
    if (fds[0].revents != 0) {
      for (;;) {
        const int c = ::accept4(fd_, nullptr, nullptr, SOCK_NONBLOCK | SOCK_CLOEXEC);
        if (c < 0) break;  // EAGAIN: none left (or a transient error: the next round retries)
        if (conns.size() >= std::min(options_.max_connections, kHardConnectionCap)) {
          HttpResponse busy = Plain(503, "busy: too many connections; try again shortly");
          busy.headers.push_back({"Retry-After", "1"});
          AnswerNow(c, busy);
          continue;
        }
        conns.push_back(Conn{c, {}, Clock::now() + request_time});
      }
    }
  }
  for (const Conn& c : conns) ::close(c.fd);
  {
    std::lock_guard<std::mutex> lock(mu);
    quit = true;
  }
  cv.notify_all();
  for (auto& t : workers) t.join();
  return status;
}

}  // namespace ltb::stages::view
