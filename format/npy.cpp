#include "format/npy.h"

#include <cstring>
#include <optional>

namespace ltb::format {
namespace {

constexpr char kMagic[] = "\x93NUMPY";
// Nesting deeper than this is refused (NumPy's own headers nest two levels).
constexpr int kMaxDepth = 32;
// NumPy's NPY_MAXDIMS.
constexpr size_t kMaxDims = 32;

// A Python literal as ast.literal_eval reads it, as far as .npy headers use them: str and
// bytes (prefixes, escapes, implicit concatenation), int (any base, '_' separators, one
// sign), float (recognised, never used), True/False/None, tuple, list, dict.
struct PyValue {
  enum class Kind { kStr, kBytes, kInt, kFloat, kBool, kNone, kTuple, kList, kDict };
  Kind kind = Kind::kNone;
  std::string str;             // kStr (UTF-8), kBytes
  bool negative = false;       // kInt
  bool too_big = false;        // kInt beyond 2^64 - 1 in magnitude
  uint64_t magnitude = 0;      // kInt
  bool truth = false;          // kBool
  std::vector<PyValue> items;  // kTuple, kList; kDict: key, value, key, value, ...
  size_t begin = 0, end = 0;   // source text, for messages
};

class PyLiteralParser {
 public:
  PyLiteralParser(const std::string& text, bool python2_longs) : s_(text), python2_longs_(python2_longs) {}

  Result<PyValue> ParseWhole() {
    SkipSpace();
    LTB_ASSIGN_OR_RETURN(PyValue v, Value(0));
    SkipSpace();
    if (p_ != s_.size()) return Error("unexpected text after the dictionary");
    return v;
  }

 private:
  Status Error(const std::string& what) const {
    std::string near = s_.substr(p_, 24);
    for (char& c : near) {
      if (static_cast<unsigned char>(c) < 0x20 || static_cast<unsigned char>(c) >= 0x7f) c = '?';
    }
    return InvalidArgument(".npy header is not a Python literal NumPy reads: " + what + " at character " +
                           std::to_string(p_) + (near.empty() ? " (end of the header)" : " (\"" + near + "\")"));
  }
  bool At(char c) const { return p_ < s_.size() && s_[p_] == c; }
  static bool IsDigit(char c) { return c >= '0' && c <= '9'; }
  static bool IsIdent(char c) { return (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || IsDigit(c) || c == '_'; }
  // Whitespace and comments; inside brackets Python also joins lines, and the header's
  // only top-level newline is the padding at its end.
  void SkipSpace() {
    while (p_ < s_.size()) {
      const char c = s_[p_];
      if (c == ' ' || c == '\t' || c == '\n' || c == '\r' || c == '\f') {
        ++p_;
      } else if (c == '#') {
        while (p_ < s_.size() && s_[p_] != '\n') ++p_;
      } else if (c == '\\' && (s_.compare(p_ + 1, 1, "\n") == 0 || s_.compare(p_ + 1, 2, "\r\n") == 0)) {
        p_ += s_[p_ + 1] == '\n' ? 2 : 3;  // an explicit line join
      } else {
        break;
      }
    }
  }

  Result<PyValue> Value(int depth) {
    if (depth > kMaxDepth) return Error("nesting deeper than " + std::to_string(kMaxDepth));
    if (p_ >= s_.size()) return Error("a value is missing");
    const size_t begin = p_;
    const char c = s_[p_];
    Result<PyValue> v = InvalidArgument("");
    if (c == '{' || c == '(' || c == '[') {
      v = Container(depth);
    } else if (c == '\'' || c == '"') {
      v = Strings();
    } else if (IsDigit(c) || c == '.' || c == '-' || c == '+') {
      v = Number();
    } else if (IsIdent(c)) {
      size_t e = p_;
      while (e < s_.size() && IsIdent(s_[e])) ++e;
      const std::string word = s_.substr(p_, e - p_);
      if (e < s_.size() && (s_[e] == '\'' || s_[e] == '"')) {
        v = Strings();  // a prefixed string: b'..', r'..', u'..'
      } else if (word == "True" || word == "False") {
        PyValue b;
        b.kind = PyValue::Kind::kBool;
        b.truth = word == "True";
        p_ = e;
        v = b;
      } else if (word == "None") {
        p_ = e;
        v = PyValue{};
      } else {
        return Error("the name \"" + word + "\" (only True, False and None are literals)");
      }
    } else {
      return Error("unexpected character");
    }
    if (!v.ok()) return v;
    v->begin = begin;
    v->end = p_;
    return v;
  }

  // '{...}' (a dict; a set is refused), '[...]', '(...)': a tuple, or a parenthesised value.
  Result<PyValue> Container(int depth) {
    const char open = s_[p_++];
    const char close = open == '{' ? '}' : open == '(' ? ')' : ']';
    PyValue out;
    out.kind = open == '{' ? PyValue::Kind::kDict : open == '(' ? PyValue::Kind::kTuple : PyValue::Kind::kList;
    bool comma = false;  // a comma seen: '(x,)' is a tuple, '(x)' is x
    SkipSpace();
    while (!At(close)) {
      if (p_ >= s_.size()) return Error(std::string("unterminated '") + open + "'");
      if (!out.items.empty() && !comma) return Error(std::string("expected ',' or '") + close + "'");
      LTB_ASSIGN_OR_RETURN(PyValue item, Value(depth + 1));
      SkipSpace();
      if (out.kind == PyValue::Kind::kDict) {
        if (!At(':')) return Error("expected ':' after a dictionary key (the header must be a dictionary)");
        ++p_;
        SkipSpace();
        LTB_ASSIGN_OR_RETURN(PyValue value, Value(depth + 1));
        SkipSpace();
        out.items.push_back(std::move(item));
        out.items.push_back(std::move(value));
      } else {
        out.items.push_back(std::move(item));
      }
      comma = At(',');
      if (comma) {
        ++p_;
        SkipSpace();
      }
    }
    ++p_;
    if (open == '(' && out.items.size() == 1 && !comma) return std::move(out.items[0]);
    return out;
  }

  // One or more adjacent string literals (concatenated, as Python does).
  Result<PyValue> Strings() {
    PyValue out;
    bool first = true;
    while (true) {
      size_t e = p_;
      while (e < s_.size() && IsIdent(s_[e])) ++e;
      if (e >= s_.size() || (s_[e] != '\'' && s_[e] != '"')) break;
      std::string prefix = s_.substr(p_, e - p_);
      for (char& c : prefix) c = static_cast<char>(c | 0x20);
      const bool bytes = prefix == "b" || prefix == "br" || prefix == "rb";
      const bool raw = prefix == "r" || prefix == "br" || prefix == "rb";
      if (!(prefix.empty() || prefix == "u" || bytes || raw)) {
        return Error("string prefix \"" + s_.substr(p_, e - p_) + "\" (f-strings are not literals)");
      }
      const PyValue::Kind kind = bytes ? PyValue::Kind::kBytes : PyValue::Kind::kStr;
      if (!first && kind != out.kind) return Error("bytes and str literals side by side");
      out.kind = kind;
      first = false;
      p_ = e;
      LTB_RETURN_IF_ERROR(OneString(bytes, raw, &out.str));
      SkipSpace();
    }
    return out;
  }

  static void AppendUtf8(uint32_t cp, std::string* out) {
    if (cp < 0x80) {
      *out += static_cast<char>(cp);
    } else if (cp < 0x800) {
      *out += static_cast<char>(0xC0 | (cp >> 6));
      *out += static_cast<char>(0x80 | (cp & 0x3F));
    } else if (cp < 0x10000) {
      *out += static_cast<char>(0xE0 | (cp >> 12));
      *out += static_cast<char>(0x80 | ((cp >> 6) & 0x3F));
      *out += static_cast<char>(0x80 | (cp & 0x3F));
    } else {
      *out += static_cast<char>(0xF0 | (cp >> 18));
      *out += static_cast<char>(0x80 | ((cp >> 12) & 0x3F));
      *out += static_cast<char>(0x80 | ((cp >> 6) & 0x3F));
      *out += static_cast<char>(0x80 | (cp & 0x3F));
    }
  }

  // One quoted literal ('..', "..", '''..''', """..""") at p_, appended to *out.
  Status OneString(bool bytes, bool raw, std::string* out) {
    const char q = s_[p_];
    const bool triple = s_.compare(p_, 3, std::string(3, q)) == 0;
    p_ += triple ? 3 : 1;
    while (true) {
      if (p_ >= s_.size()) return Error("unterminated string");
      const char c = s_[p_];
      if (c == q && (!triple || s_.compare(p_, 3, std::string(3, q)) == 0)) {
        p_ += triple ? 3 : 1;
        return Status::Ok();
      }
      if (c == '\n' && !triple) return Error("a newline inside a string");
      if (bytes && static_cast<unsigned char>(c) >= 0x80) return Error("a non-ASCII character in a bytes literal");
      if (c != '\\') {
        *out += c;
        ++p_;
        continue;
      }
      if (p_ + 1 >= s_.size()) return Error("unterminated string");
      const char e = s_[p_ + 1];
      if (raw) {  // the backslash stays; it still keeps the next character from ending the string
        *out += c;
        *out += e;
        p_ += 2;
        continue;
      }
      p_ += 2;
      auto hex = [&](int n, uint32_t* v) {
        *v = 0;
        for (int i = 0; i < n; ++i, ++p_) {
          if (p_ >= s_.size()) return false;
          const char h = s_[p_];
          const int d = IsDigit(h)               ? h - '0'
                        : (h >= 'a' && h <= 'f') ? h - 'a' + 10
                        : (h >= 'A' && h <= 'F') ? h - 'A' + 10
                                                 : -1;
          if (d < 0) return false;
          *v = *v * 16 + uint32_t(d);
        }
        return true;
      };
      uint32_t v = 0;
      switch (e) {
        case '\n':
          break;  // line continuation
        case '\\':
        case '\'':
        case '"':
          *out += e;
          break;
        case 'a':
          *out += '\a';
          break;
        case 'b':
          *out += '\b';
          break;
        case 'f':
          *out += '\f';
          break;
        case 'n':
          *out += '\n';
          break;
        case 'r':
          *out += '\r';
          break;
        case 't':
          *out += '\t';
          break;
        case 'v':
          *out += '\v';
          break;
        case 'x':
          if (!hex(2, &v)) return Error("a bad \\x escape");
          if (bytes)
            *out += static_cast<char>(v);
          else
            AppendUtf8(v, out);
          break;
        case 'u':
        case 'U':
          if (bytes) {
            *out += '\\';
            *out += e;
            break;
          }
          if (!hex(e == 'u' ? 4 : 8, &v) || v > 0x10FFFF) return Error("a bad \\u or \\U escape");
          AppendUtf8(v, out);
          break;
        case 'N':
          if (!bytes) return Error("a \\N{...} escape (not supported in .npy headers)");
          *out += "\\N";
          break;
        default:
          if (e >= '0' && e <= '7') {  // up to three octal digits
            v = uint32_t(e - '0');
            for (int i = 0; i < 2 && p_ < s_.size() && s_[p_] >= '0' && s_[p_] <= '7'; ++i, ++p_) {
              v = v * 8 + uint32_t(s_[p_] - '0');
            }
            if (bytes)
              *out += static_cast<char>(v & 0xFF);
            else
              AppendUtf8(v, out);
          } else {  // unknown escapes keep their backslash
            *out += '\\';
            *out += e;
          }
      }
    }
  }

  // [+|-] integer (decimal, 0x, 0o, 0b; '_' between digits; 'L' after it in Python 2
  // headers), or a float / complex (recognised so that it can be refused by kind).
  Result<PyValue> Number() {
    PyValue out;
    out.kind = PyValue::Kind::kInt;
    if (At('-') || At('+')) {
      out.negative = s_[p_] == '-';
      ++p_;
      SkipSpace();
      if (!(p_ < s_.size() && (IsDigit(s_[p_]) || s_[p_] == '.'))) return Error("a sign without a number");
    }
    const size_t start = p_;
    unsigned base = 10;
    if (At('0') && p_ + 1 < s_.size()) {
      const char b = static_cast<char>(s_[p_ + 1] | 0x20);
      if (b == 'x' || b == 'o' || b == 'b') {
        base = b == 'x' ? 16 : b == 'o' ? 8 : 2;
        p_ += 2;
        if (At('_')) ++p_;
      }
    }
    size_t digits = 0;
    bool nonzero_lead = false, underscore_ok = false;
    while (p_ < s_.size()) {
      const char c = s_[p_];
      if (c == '_') {
        if (!underscore_ok) return Error("a misplaced '_' in a number");
        underscore_ok = false;
        ++p_;
        continue;
      }
      int d = IsDigit(c) ? c - '0' : (c >= 'a' && c <= 'f') ? c - 'a' + 10 : (c >= 'A' && c <= 'F') ? c - 'A' + 10 : -1;
      if (base == 10 && (c == 'e' || c == 'E')) d = -1;
      if (d < 0 || unsigned(d) >= base) break;
      if (digits == 0 && d != 0) nonzero_lead = true;
      if (MulOverflows(out.magnitude, base, &out.magnitude) ||
          AddOverflows(out.magnitude, uint64_t(d), &out.magnitude)) {
        out.too_big = true;
      }
      ++digits;
      underscore_ok = true;
      ++p_;
    }
    if (p_ > start && s_[p_ - 1] == '_') return Error("a misplaced '_' in a number");
    if (base == 10 && (At('.') || At('e') || At('E') || At('j') || At('J'))) {
      // A float or complex literal: consume it and report it as such.
      while (p_ < s_.size() &&
             (IsDigit(s_[p_]) || s_[p_] == '.' || s_[p_] == '_' || s_[p_] == 'e' || s_[p_] == 'E' || s_[p_] == 'j' ||
              s_[p_] == 'J' || ((s_[p_] == '+' || s_[p_] == '-') && (s_[p_ - 1] == 'e' || s_[p_ - 1] == 'E')))) {
        ++p_;
      }
      out.kind = PyValue::Kind::kFloat;
      return out;
    }
    if (digits == 0) return Error("a number without digits");
    if (base == 10 && !nonzero_lead && digits > 1 && out.magnitude != 0) {  // "00" is 0, "01" no literal
      return Error("leading zeros in a decimal integer");
    }
    if (python2_longs_ && (At('L') || At('l'))) ++p_;
    if (p_ < s_.size() && IsIdent(s_[p_])) return Error("a malformed number");
    return out;
  }

  const std::string& s_;
  bool python2_longs_;
  size_t p_ = 0;
};

// The Python repr-like text of a parsed value, for messages.
std::string Source(const std::string& text, const PyValue& v) {
  std::string s = text.substr(v.begin, std::min<size_t>(v.end - v.begin, 80));
  if (v.end - v.begin > 80) s += "...";
  for (char& c : s) {
    if (static_cast<unsigned char>(c) < 0x20) c = ' ';
  }
  return s;
}

bool ValidUtf8(const std::string& s) {
  for (size_t i = 0; i < s.size();) {
    const unsigned char c = static_cast<unsigned char>(s[i]);
    size_t n = c < 0x80 ? 1 : (c >> 5) == 0x6 ? 2 : (c >> 4) == 0xE ? 3 : (c >> 3) == 0x1E ? 4 : 0;
    if (n == 0 || i + n > s.size()) return false;
    uint32_t cp = n == 1 ? c : n == 2 ? (c & 0x1F) : n == 3 ? (c & 0x0F) : (c & 0x07);
    for (size_t k = 1; k < n; ++k) {
      const unsigned char d = static_cast<unsigned char>(s[i + k]);
      if ((d >> 6) != 0x2) return false;
      cp = (cp << 6) | (d & 0x3F);
    }
    if ((n == 2 && cp < 0x80) || (n == 3 && cp < 0x800) || (n == 4 && (cp < 0x10000 || cp > 0x10FFFF)) ||
        (cp >= 0xD800 && cp <= 0xDFFF)) {
      return false;
    }
    i += n;
  }
  return true;
}

}  // namespace

Result<uint64_t> NpyHeaderLength(ByteSpan b) {
  if (b.size() < 10 || std::memcmp(b.data(), kMagic, 6) != 0) {
    return InvalidArgument("not a .npy file (the magic \\x93NUMPY is missing)");
  }
  const uint8_t major = static_cast<uint8_t>(b[6]), minor = static_cast<uint8_t>(b[7]);
  if (major < 1 || major > 3 || minor != 0) {
    return InvalidArgument(".npy format version " + std::to_string(major) + "." + std::to_string(minor) +
                           " is not supported (NumPy writes and ltbake reads 1.0, 2.0 and 3.0)");
  }
  if (major == 1) return 10 + uint64_t{LoadU16(&b[8])};
  if (b.size() < 12) return InvalidArgument(".npy header truncated: " + std::to_string(b.size()) + " bytes");
  uint64_t len = LoadU32(&b[8]);
  if (len > kMaxNpyHeaderBytes) {
    return InvalidArgument(".npy header length field says " + std::to_string(len) + " bytes (ltbake reads up to " +
                           std::to_string(kMaxNpyHeaderBytes) + ")");
  }
  return 12 + len;
}

Result<NpyHeader> ParseNpyHeader(ByteSpan b) {
  LTB_ASSIGN_OR_RETURN(uint64_t total, NpyHeaderLength(b));
  if (b.size() < total) {
    return InvalidArgument(".npy header needs " + std::to_string(total) + " bytes, the file has " +
                           std::to_string(b.size()));
  }
  const uint8_t major = static_cast<uint8_t>(b[6]);
  const uint64_t text_start = major == 1 ? 10 : 12;
  const std::string text(reinterpret_cast<const char*>(b.data() + text_start), total - text_start);
  // Python refuses source text with NUL bytes; format 3.0 headers are UTF-8, 1.0 and 2.0
  // Latin-1 (any byte; non-ASCII only has a meaning inside strings).
  if (const size_t nul = text.find('\0'); nul != std::string::npos) {
    return InvalidArgument(".npy header has a NUL byte at character " + std::to_string(nul) +
                           " (NumPy pads headers with spaces and a newline)");
  }
  if (major == 3 && !ValidUtf8(text)) return InvalidArgument(".npy format 3.0 header is not valid UTF-8");
  PyLiteralParser parser(text, /*python2_longs=*/major <= 2);
  LTB_ASSIGN_OR_RETURN(PyValue dict, parser.ParseWhole());
  if (dict.kind != PyValue::Kind::kDict) {
    return InvalidArgument(".npy header is not a dictionary: " + Source(text, dict));
  }
  const PyValue* descr = nullptr;
  const PyValue* fortran = nullptr;
  const PyValue* shape = nullptr;
  std::string keys;
  for (size_t i = 0; i < dict.items.size(); i += 2) {
    const PyValue& k = dict.items[i];
    keys += (keys.empty() ? "" : ", ") + Source(text, k);
    const PyValue** slot = nullptr;
    if (k.kind == PyValue::Kind::kStr) {
      slot = k.str == "descr" ? &descr : k.str == "fortran_order" ? &fortran : k.str == "shape" ? &shape : nullptr;
    }
    if (slot == nullptr) {
      return InvalidArgument(".npy header has the key " + Source(text, k) +
                             "; a .npy header holds exactly 'descr', 'fortran_order' and 'shape'");
    }
    if (*slot != nullptr) {
      return InvalidArgument(".npy header names the key " + Source(text, k) + " twice");
    }
    *slot = &dict.items[i + 1];
  }
  if (descr == nullptr || fortran == nullptr || shape == nullptr) {
    return InvalidArgument(".npy header has the keys {" + keys +
                           "}; it needs exactly 'descr', 'fortran_order' and 'shape'");
  }
  NpyHeader h;
  h.data_offset = total;
  // descr: a dtype string, or (structured types) a list NumPy reads and ltbake reports.
  if (descr->kind == PyValue::Kind::kStr) {
    h.descr = descr->str;
  } else if (descr->kind == PyValue::Kind::kList || descr->kind == PyValue::Kind::kTuple) {
    h.descr = Source(text, *descr);
  } else {
    return InvalidArgument(".npy header: 'descr' is " + Source(text, *descr) + ", not a dtype descriptor");
  }
  if (fortran->kind != PyValue::Kind::kBool) {
    return InvalidArgument(".npy header: 'fortran_order' is " + Source(text, *fortran) + ", not True or False");
  }
  h.fortran_order = fortran->truth;
  if (shape->kind != PyValue::Kind::kTuple) {
    return InvalidArgument(".npy header: 'shape' is " + Source(text, *shape) + ", not a tuple of integers");
  }
  if (shape->items.size() > kMaxDims) {
    return InvalidArgument(".npy header: 'shape' has " + std::to_string(shape->items.size()) +
                           " dimensions (NumPy allows up to " + std::to_string(kMaxDims) + ")");
  }
  for (const PyValue& d : shape->items) {
    if (d.kind != PyValue::Kind::kInt || (d.negative && d.magnitude != 0) || d.too_big) {
      const char* why = d.kind != PyValue::Kind::kInt ? "not an integer" : d.too_big ? "beyond 2^64" : "negative";
      return InvalidArgument(".npy header: 'shape' " + Source(text, *shape) + " has the entry " + Source(text, d) +
                             ", " + why);
    }
    h.shape.push_back(d.magnitude);
  }
  if (h.descr.size() == 3 && (h.descr[0] == '<' || h.descr[0] == '|' || h.descr[0] == '=') && h.descr[1] == 'f' &&
      (h.descr[2] == '4' || h.descr[2] == '8')) {
    h.itemsize = h.descr[2] == '4' ? 4 : 8;
  }
  return h;
}

Result<uint64_t> NpyDataBytes(const NpyHeader& h) {
  std::string shape;
  for (uint64_t d : h.shape) shape += (shape.empty() ? "" : ", ") + std::to_string(d);
  if (h.shape.size() == 1) shape += ",";
  if (h.itemsize == 0) {
    return InvalidArgument(".npy dtype '" + h.descr + "' has no known item size");
  }
  uint64_t bytes = h.itemsize;
  for (uint64_t d : h.shape) {
    if (MulOverflows(bytes, d, &bytes)) {
      return InvalidArgument(".npy header: shape (" + shape + ") of '" + h.descr +
                             "' is more than 2^64 bytes (damaged or not a real array)");
    }
  }
  return bytes;
}

std::vector<std::byte> EncodeNpyHeader(const std::string& descr, const std::vector<uint64_t>& shape) {
  std::string s = "{'descr': '" + descr + "', 'fortran_order': False, 'shape': (";
  for (size_t i = 0; i < shape.size(); ++i) s += (i > 0 ? ", " : "") + std::to_string(shape[i]);
  s += shape.size() == 1 ? ",), }" : "), }";
  // Pad with spaces so data starts on a 64-byte boundary; the text ends with '\n'.
  bool v2 = s.size() + 1 + 10 > 65535;
  uint64_t prefix = v2 ? 12 : 10;
  uint64_t total = AlignUp(prefix + s.size() + 1, 64);
  s.append(total - prefix - s.size() - 1, ' ');
  s += '\n';
  std::vector<std::byte> out(total);
  std::memcpy(out.data(), kMagic, 6);
  out[6] = std::byte{static_cast<unsigned char>(v2 ? 2 : 1)};
  out[7] = std::byte{0};
  if (v2)
    StoreU32(&out[8], static_cast<uint32_t>(s.size()));
  else
    StoreU16(&out[8], static_cast<uint16_t>(s.size()));
  std::memcpy(out.data() + prefix, s.data(), s.size());
  return out;
}

}  // namespace ltb::format
