// Strict reading of TOML tables (scenes, recipes): every unknown key is an error naming
// its line, and every value is checked for type and range, naming file, line and key.
#pragma once

#include <toml++/toml.h>

#include <cstdint>
#include <glm/vec3.hpp>
#include <set>
#include <string>

#include "format/status.h"

namespace ltb::tomlf {

// "path:line" of a node.
std::string Where(const std::string& path, const toml::node& n);

// Lists every key of `table` not in `allowed`, each with its line.
Status CheckKeys(const std::string& path, const toml::table& table, const std::string& what,
                 const std::set<std::string>& allowed);

// A finite number in [lo, hi], or `def` when the key is absent.
Result<double> GetNumber(const std::string& path, const toml::table& t, const char* key, double def, double lo,
                         double hi);
// An integer in [lo, hi], or `def` when the key is absent.
Result<uint64_t> GetUnsigned(const std::string& path, const toml::table& t, const char* key, uint64_t def, uint64_t lo,
                             uint64_t hi);
Result<std::string> GetString(const std::string& path, const toml::table& t, const char* key, std::string def);
Result<bool> GetBool(const std::string& path, const toml::table& t, const char* key, bool def);
// [x, y, z] of finite numbers (or, with allow_scalar, one number for all three), or `def`.
Result<glm::dvec3> GetVec3(const std::string& path, const toml::table& t, const char* key, glm::dvec3 def,
                           bool allow_scalar = false);

// The value of a node as TOML writes it (for messages): 1.5, nan, "text", [1, 2].
std::string ValueText(const toml::node& n);

// Parses a TOML file; a syntax error names path:line:column. A missing path, a directory,
// a FIFO or device, or a file over 16 MiB is refused by name (`what`: "scene file", ...).
Result<toml::table> ParseFile(const std::string& path, const std::string& what = "TOML file");

}  // namespace ltb::tomlf
