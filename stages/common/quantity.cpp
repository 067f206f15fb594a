#include "stages/common/quantity.h"

#include <cctype>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <utility>

namespace ltb::stages {
namespace {

// The number at the start of text and what follows it; false when there is no number or
// the text does not start with a digit (strtod would take "inf", "nan", "+1", " 1").
bool SplitNumber(const std::string& text, double* value, std::string* unit) {
  if (text.empty() || !std::isdigit(static_cast<unsigned char>(text[0]))) return false;
  const char* begin = text.c_str();
  char* end = nullptr;
  *value = std::strtod(begin, &end);
  if (end == begin) return false;
  *unit = std::string(end);
  return true;
}

// Bytes per unit of ParseByteSize; 0 for an unknown unit.
double UnitBytes(const std::string& unit) {
  static const std::pair<const char*, double> kUnits[] = {{"", 1},
                                                          {"B", 1},
                                                          {"k", 1024.0},
                                                          {"K", 1024.0},
                                                          {"KiB", 1024.0},
                                                          {"M", 1048576.0},
                                                          {"MiB", 1048576.0},
                                                          {"G", 1073741824.0},
                                                          {"GiB", 1073741824.0},
                                                          {"T", 1099511627776.0},
                                                          {"TiB", 1099511627776.0},
                                                          {"KB", 1e3},
                                                          {"MB", 1e6},
                                                          {"GB", 1e9},
                                                          {"TB", 1e12}};
  for (const auto& [name, bytes] : kUnits) {
    if (unit == name) return bytes;
  }
  return 0;
}

// The text as a message shows it: quoted, at most 40 bytes, bytes outside printable ASCII
// as \xNN (a query's "%00" is a NUL byte).
std::string Quoted(const std::string& text) {
  std::string out = "\"";
  for (size_t i = 0; i < text.size() && i < 40; ++i) {
    const unsigned char c = static_cast<unsigned char>(text[i]);
    if (c >= 0x20 && c < 0x7f && c != '"' && c != '\\') {
      out += static_cast<char>(c);
    } else {
      char buf[8];
      std::snprintf(buf, sizeof buf, "\\x%02X", c);
      out += buf;
    }
  }
  if (text.size() > 40) out += "...";
  return out + "\"";
}

std::string Shortest(double v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%g", v);
  return buf;
}

// Whether text is exactly [+-] digits [. digits] [(e|E) [+-] digits], with a digit before
// or after the point.
bool IsDecimal(const std::string& text) {
  size_t i = 0, n = text.size();
  auto digits = [&] {
    const size_t start = i;
    while (i < n && text[i] >= '0' && text[i] <= '9') ++i;
    return i - start;
  };
  if (i < n && (text[i] == '+' || text[i] == '-')) ++i;
  size_t mantissa = digits();
  if (i < n && text[i] == '.') {
    ++i;
    mantissa += digits();
  }
  if (mantissa == 0) return false;
  if (i < n && (text[i] == 'e' || text[i] == 'E')) {
    ++i;
    if (i < n && (text[i] == '+' || text[i] == '-')) ++i;
    if (digits() == 0) return false;
  }
  return i == n;
}

}  // namespace

std::string MessageNumber(double v) {
  char buf[48];
  std::snprintf(buf, sizeof buf, "%.9g", v);
  return buf;
}

Result<double> ParseDecimal(const std::string& text, double min, double max) {
  const std::string range = "[" + Shortest(min) + ", " + Shortest(max) + "]";
  if (!IsDecimal(text)) {
    return InvalidArgument(Quoted(text) + " is not a decimal number (expected one in " + range +
                           ", written like 12, 0.5, -3 or 2.5e3)");
  }
  // The syntax is checked, so strtod reads all of it (and, for this syntax, only decimal).
  const double v = std::strtod(text.c_str(), nullptr);
  if (!std::isfinite(v) || !(v >= min && v <= max)) {
    return InvalidArgument(Quoted(text) + " is outside " + range);
  }
  return v;
}

Result<uint64_t> ParseByteSize(const std::string& text) {
  double v = 0;
  std::string unit;
  if (!SplitNumber(text, &v, &unit)) {
    return InvalidArgument("size \"" + text + "\" does not start with a number (e.g. 512MiB, 4GiB)");
  }
  const double mult = UnitBytes(unit);
  if (mult == 0) {
    return InvalidArgument("size \"" + text + "\" has unknown unit \"" + unit +
                           "\" (use B; K, M, G, T or KiB, MiB, GiB, TiB for powers of 1024; KB, MB, GB, TB for "
                           "powers of 1000)");
  }
  const double bytes = v * mult;
  if (!(bytes >= 1)) return InvalidArgument("size \"" + text + "\" is less than 1 byte (e.g. 512MiB, 4GiB)");
  if (bytes > 9.0e18) return InvalidArgument("size \"" + text + "\" is out of range (at most 8EiB)");
  return static_cast<uint64_t>(bytes);
}

Result<double> ParseFraction(const std::string& text) {
  double v = 0;
  std::string unit;
  const bool number = SplitNumber(text, &v, &unit);
  if (number && unit == "%") v /= 100;
  if (!number || (!unit.empty() && unit != "%") || !(v > 0 && v <= 1)) {
    return InvalidArgument("\"" + text + "\" is not a fraction in (0, 1] (e.g. 0.05 or 5%)");
  }
  return v;
}

Result<Budget> ParseBudget(const std::string& text) {
  auto bad = [&] {
    return InvalidArgument("budget \"" + text +
                           "\": expected a fraction of the matrix (0.02 or 2%), a count of nonzeros (150000) or a "
                           "size (64MiB or 64M, at 8 bytes per nonzero)");
  };
  double v = 0;
  std::string unit;
  if (!SplitNumber(text, &v, &unit) || !std::isfinite(v) || v <= 0) return bad();
  Budget b;
  if (unit == "%") {
    if (v > 100) return bad();
    b.kind = Budget::Kind::kFraction;
    b.value = v / 100;
  } else if (unit.empty() && text.find_first_of(".eE") != std::string::npos) {
    if (v > 1) return bad();
    b.kind = Budget::Kind::kFraction;
    b.value = v;
  } else if (unit.empty()) {
    b.kind = Budget::Kind::kCount;
    b.value = v;
  } else {
    auto bytes = ParseByteSize(text);
    if (!bytes.ok()) return bad();
    b.kind = Budget::Kind::kBytes;
    b.value = static_cast<double>(*bytes);
  }
  return b;
}

uint64_t BudgetNonzeros(const Budget& budget, uint64_t rows, uint64_t cols) {
  const double elements = static_cast<double>(rows) * static_cast<double>(cols);
  double count = budget.value;
  if (budget.kind == Budget::Kind::kFraction) count = budget.value * elements;
  if (budget.kind == Budget::Kind::kBytes) count = budget.value / 8;
  return static_cast<uint64_t>(std::min(std::floor(count), elements));
}

}  // namespace ltb::stages
