#include "stages/common/toml_fields.h"

#include <cmath>
#include <filesystem>

namespace ltb::tomlf {

std::string Where(const std::string& path, const toml::node& n) {
  return path + ":" + std::to_string(n.source().begin.line);
}

Status CheckKeys(const std::string& path, const toml::table& table, const std::string& what,
                 const std::set<std::string>& allowed) {
  std::string bad;
  for (const auto& [key, node] : table) {
    if (allowed.count(std::string(key.str())) == 0) {
      bad += (bad.empty() ? "" : ", ") + std::string("\"") + std::string(key.str()) + "\" (line " +
             std::to_string(node.source().begin.line) + ")";
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
  if (!v || !std::isfinite(*v)) return InvalidArgument(Where(path, *n) + ": \"" + key + "\" must be a number");
  if (*v < lo || *v > hi) {
    return InvalidArgument(Where(path, *n) + ": \"" + key + "\" is " + std::to_string(*v) + ", outside [" +
                           std::to_string(lo) + ", " + std::to_string(hi) + "]");
  }
  return *v;
}

Result<uint64_t> GetUnsigned(const std::string& path, const toml::table& t, const char* key, uint64_t def, uint64_t lo,
                             uint64_t hi) {
  const toml::node* n = t.get(key);
  if (n == nullptr) return def;
  std::optional<int64_t> v = n->value<int64_t>();
  if (!v || *v < static_cast<int64_t>(lo) || static_cast<uint64_t>(*v) > hi) {
    return InvalidArgument(Where(path, *n) + ": \"" + key + "\" must be an integer in [" + std::to_string(lo) + ", " +
                           std::to_string(hi) + "]");
  }
  return static_cast<uint64_t>(*v);
}

Result<std::string> GetString(const std::string& path, const toml::table& t, const char* key, std::string def) {
  const toml::node* n = t.get(key);
  if (n == nullptr) return def;
  auto v = n->value<std::string>();
  if (!v) return InvalidArgument(Where(path, *n) + ": \"" + key + "\" must be a string");
  return *v;
}

Result<bool> GetBool(const std::string& path, const toml::table& t, const char* key, bool def) {
  const toml::node* n = t.get(key);
  if (n == nullptr) return def;
  auto v = n->value<bool>();
  if (!v) return InvalidArgument(Where(path, *n) + ": \"" + key + "\" must be true or false");
  return *v;
}

Result<toml::table> ParseFile(const std::string& path) {
  std::error_code ec;
  if (!std::filesystem::is_regular_file(path, ec)) return NotFound(path + ": file not found");
  try {
    return toml::parse_file(path);
  } catch (const toml::parse_error& e) {
    return InvalidArgument(path + ":" + std::to_string(e.source().begin.line) + ":" +
                           std::to_string(e.source().begin.column) + ": " + std::string(e.description()));
  }
}

}  // namespace ltb::tomlf
