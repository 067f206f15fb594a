#include "format/npy.h"

#include <cctype>
#include <cstring>

namespace ltb::format {
namespace {

constexpr char kMagic[] = "\x93NUMPY";

// Finds the value text after 'key': in a Python dict literal.
bool FindValue(const std::string& dict, const std::string& key, size_t* pos) {
  for (const char* q : {"'", "\""}) {
    std::string k = std::string(q) + key + q;
    size_t p = dict.find(k);
    if (p == std::string::npos) continue;
    p += k.size();
    while (p < dict.size() && std::isspace(static_cast<unsigned char>(dict[p]))) ++p;
    if (p >= dict.size() || dict[p] != ':') return false;
    ++p;
    while (p < dict.size() && std::isspace(static_cast<unsigned char>(dict[p]))) ++p;
    *pos = p;
    return true;
  }
  return false;
}

}  // namespace

Result<uint64_t> NpyHeaderLength(ByteSpan b) {
  if (b.size() < 10 || std::memcmp(b.data(), kMagic, 6) != 0) return InvalidArgument("not a .npy file (bad magic)");
  uint8_t major = static_cast<uint8_t>(b[6]);
  if (major == 1) return 10 + uint64_t{LoadU16(&b[8])};
  if (major == 2 || major == 3) {
    if (b.size() < 12) return InvalidArgument(".npy header truncated");
    uint64_t len = LoadU32(&b[8]);
    if (len > kMaxNpyHeaderBytes) {
      return InvalidArgument(".npy header claims " + std::to_string(len) + " bytes (cap " +
                             std::to_string(kMaxNpyHeaderBytes) + ")");
    }
    return 12 + len;
  }
  return InvalidArgument(".npy format version " + std::to_string(major) + ".x is not supported (1.0-3.0 are)");
}

Result<NpyHeader> ParseNpyHeader(ByteSpan b) {
  LTB_ASSIGN_OR_RETURN(uint64_t total, NpyHeaderLength(b));
  if (b.size() < total) {
    return InvalidArgument(".npy header needs " + std::to_string(total) + " bytes, the file has " +
                           std::to_string(b.size()));
  }
  uint64_t text_start = static_cast<uint8_t>(b[6]) == 1 ? 10 : 12;
  std::string dict(reinterpret_cast<const char*>(b.data() + text_start), total - text_start);
  NpyHeader h;
  h.data_offset = total;
  size_t p;
  // descr
  if (!FindValue(dict, "descr", &p) || p >= dict.size() || (dict[p] != '\'' && dict[p] != '"')) {
    return InvalidArgument(".npy header lacks a 'descr' string: " + dict);
  }
  size_t q = dict.find(dict[p], p + 1);
  if (q == std::string::npos) return InvalidArgument(".npy header: unterminated 'descr'");
  h.descr = dict.substr(p + 1, q - p - 1);
  // fortran_order
  if (!FindValue(dict, "fortran_order", &p)) return InvalidArgument(".npy header lacks 'fortran_order'");
  if (dict.compare(p, 4, "True") == 0) h.fortran_order = true;
  else if (dict.compare(p, 5, "False") == 0) h.fortran_order = false;
  else return InvalidArgument(".npy header: 'fortran_order' is neither True nor False");
  // shape
  if (!FindValue(dict, "shape", &p) || p >= dict.size() || dict[p] != '(') {
    return InvalidArgument(".npy header lacks a 'shape' tuple");
  }
  size_t close = dict.find(')', p);
  if (close == std::string::npos) return InvalidArgument(".npy header: unterminated 'shape'");
  std::string tuple = dict.substr(p + 1, close - p - 1);
  size_t i = 0;
  while (i < tuple.size()) {
    while (i < tuple.size() && (std::isspace(static_cast<unsigned char>(tuple[i])) || tuple[i] == ',')) ++i;
    if (i >= tuple.size()) break;
    if (!std::isdigit(static_cast<unsigned char>(tuple[i]))) {
      return InvalidArgument(".npy header: bad shape entry in (" + tuple + ")");
    }
    uint64_t v = 0;
    while (i < tuple.size() && std::isdigit(static_cast<unsigned char>(tuple[i]))) {
      if (MulOverflows(v, 10, &v) || AddOverflows(v, static_cast<uint64_t>(tuple[i] - '0'), &v)) {
        return InvalidArgument(".npy header: shape entry overflows in (" + tuple + ")");
      }
      ++i;
    }
    h.shape.push_back(v);
    if (h.shape.size() > 32) return InvalidArgument(".npy header: more than 32 dimensions");
  }
  if (h.descr.size() == 3 && (h.descr[0] == '<' || h.descr[0] == '|' || h.descr[0] == '=') && h.descr[1] == 'f' &&
      (h.descr[2] == '4' || h.descr[2] == '8')) {
    h.itemsize = h.descr[2] == '4' ? 4 : 8;
  }
  return h;
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
  if (v2) StoreU32(&out[8], static_cast<uint32_t>(s.size()));
  else StoreU16(&out[8], static_cast<uint16_t>(s.size()));
  std::memcpy(out.data() + prefix, s.data(), s.size());
  return out;
}

}  // namespace ltb::format
