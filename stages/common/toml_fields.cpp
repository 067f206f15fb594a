#include "stages/common/toml_fields.h"

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <sstream>

#include "stages/common/suggest.h"

namespace ltb::tomlf {

namespace {
std::string Num(double v) {
  char b[32];
  std::snprintf(b, sizeof b, "%.10g", v);
  return b;
}
}  // namespace

std::string ValueText(const toml::node& n) {
  std::ostringstream out;
  n.visit([&](const auto& v) {
    if constexpr (toml::is_string<decltype(v)>) {
      out << '"' << v.get().substr(0, 60) << (v.get().size() > 60 ? "..." : "") << '"';
    } else if constexpr (toml::is_table<decltype(v)>) {
      out << "a table";
    } else {
      out << toml::toml_formatter(v, toml::format_flags::none);
    }
  });
  std::string s = out.str();
  return s.size() > 80 ? s.substr(0, 80) + "..." : s;
}

std::string Where(const std::string& path, const toml::node& n) {
  return path + ":" + std::to_string(n.source().begin.line);
}

Status CheckKeys(const std::string& path, const toml::table& table, const std::string& what,
                 const std::set<std::string>& allowed) {
  const std::vector<std::string> known_keys(allowed.begin(), allowed.end());
  std::string bad;
  for (const auto& [key, node] : table) {
    if (allowed.count(std::string(key.str())) == 0) {
      const std::string nearest = Nearest(key.str(), known_keys);
      bad += (bad.empty() ? "" : ", ") + std::string("\"") + std::string(key.str()) + "\" (line " +
             std::to_string(node.source().begin.line) + (nearest.empty() ? "" : "; did you mean \"" + nearest + "\"?") +
             ")";
    }
  }
  if (bad.empty()) return Status::Ok();
  std::string known;
  for (const auto& k : allowed) known += (known.empty() ? "" : ", ") + k;
  return InvalidArgument(path + ": unknown key(s) in " + what + ": " + bad + "; known keys: " + known);
}

Result<double> GetNumber(const std::string& path, const toml::table& t, const char* key, double def, double lo,
                         double hi) {
  const toml::node* n = t.get(key);
  if (n == nullptr) return def;
  std::optional<double> v = n->value<double>();
  if (!v || !std::isfinite(*v)) {
    return InvalidArgument(Where(path, *n) + ": \"" + key + "\" is " + ValueText(*n) +
                           "; it must be a finite number in [" + Num(lo) + ", " + Num(hi) + "]");
  }
  if (*v < lo || *v > hi) {
    return InvalidArgument(Where(path, *n) + ": \"" + key + "\" is " + Num(*v) + ", outside [" + Num(lo) + ", " +
                           Num(hi) + "]");
  }
  return *v;
}

Result<uint64_t> GetUnsigned(const std::string& path, const toml::table& t, const char* key, uint64_t def, uint64_t lo,
                             uint64_t hi) {
  const toml::node* n = t.get(key);
  if (n == nullptr) return def;
  // Only an integer node is asked for its integer: toml++ converts a float node to int64_t
  // by a plain cast, undefined beyond its range (a seed of 1e30: found by UBSan).
  const std::optional<int64_t> v = n->is_integer() ? n->value<int64_t>() : std::nullopt;
  if (!v || *v < 0 || static_cast<uint64_t>(*v) < lo || static_cast<uint64_t>(*v) > hi) {
    return InvalidArgument(Where(path, *n) + ": \"" + key + "\" is " + ValueText(*n) + "; it must be an integer in [" +
                           std::to_string(lo) + ", " + std::to_string(hi) + "]");
  }
  return static_cast<uint64_t>(*v);
}

Result<std::string> GetString(const std::string& path, const toml::table& t, const char* key, std::string def) {
  const toml::node* n = t.get(key);
  if (n == nullptr) return def;
  auto v = n->value<std::string>();
  if (!v) return InvalidArgument(Where(path, *n) + ": \"" + key + "\" is " + ValueText(*n) + "; it must be a string");
  return *v;
}

Result<bool> GetBool(const std::string& path, const toml::table& t, const char* key, bool def) {
  const toml::node* n = t.get(key);
  if (n == nullptr) return def;
  auto v = n->value<bool>();
  if (!v)
    return InvalidArgument(Where(path, *n) + ": \"" + key + "\" is " + ValueText(*n) + "; it must be true or false");
  return *v;
}

Result<toml::table> ParseFile(const std::string& path, const std::string& what) {
  namespace fs = std::filesystem;
  std::error_code ec;
  fs::file_status st = fs::status(path, ec);
  if (st.type() == fs::file_type::not_found) return NotFound(path + ": " + what + " not found");
  if (ec) return InvalidArgument(path + ": cannot read the " + what + ": " + ec.message());
  if (st.type() == fs::file_type::directory) {
    return InvalidArgument(path + ": is a directory, not a " + what + "; give the path of the TOML file");
  }
  if (st.type() != fs::file_type::regular) {
    return InvalidArgument(path + ": is not a regular file (a FIFO, socket or device), not a " + what);
  }
  constexpr uintmax_t kMaxBytes = uintmax_t{16} << 20;
  uintmax_t size = fs::file_size(path, ec);
  if (!ec && size > kMaxBytes) {
    return InvalidArgument(path + ": the " + what + " is " + std::to_string(size) +
                           " bytes; TOML files here are small (at most 16 MiB): is it the right file?");
  }
  try {
    return toml::parse_file(path);
  } catch (const toml::parse_error& e) {
    return InvalidArgument(path + ":" + std::to_string(e.source().begin.line) + ":" +
                           std::to_string(e.source().begin.column) + ": " + std::string(e.description()));
  } catch (const std::exception& e) {
    return InvalidArgument(path + ": cannot read the " + what + ": " + e.what());
  }
}

Result<glm::dvec3> GetVec3(const std::string& path, const toml::table& t, const char* key, glm::dvec3 def,
                           bool allow_scalar) {
  const toml::node* n = t.get(key);
  if (n == nullptr) return def;
  if (allow_scalar) {
    if (auto s = n->value<double>()) {
      if (!std::isfinite(*s)) {
        return InvalidArgument(Where(path, *n) + ": \"" + key + "\" is " + ValueText(*n) +
                               "; it must be a finite number or [x, y, z]");
      }
      return glm::dvec3(*s);
    }
  }
  const toml::array* a = n->as_array();
  if (a == nullptr || a->size() != 3) {
    return InvalidArgument(Where(path, *n) + ": \"" + key + "\" must be [x, y, z]" +
                           (allow_scalar ? " or a number" : ""));
  }
  glm::dvec3 v;
  for (int i = 0; i < 3; ++i) {
    auto x = (*a)[i].value<double>();
    if (!x) return InvalidArgument(Where(path, *n) + ": \"" + key + "\" must hold 3 numbers");
    if (!std::isfinite(*x)) {
      return InvalidArgument(Where(path, *n) + ": \"" + key + "\" element " + std::to_string(i + 1) + " is " +
                             (std::isnan(*x) ? "nan"
                              : *x > 0       ? "inf"
                                             : "-inf") +
                             "; it must hold 3 finite numbers");
    }
    v[i] = *x;
  }
  return v;
}

}  // namespace ltb::tomlf
