#include "stages/common/base64.h"

#include <cstring>

namespace ltb::stages {

namespace {
constexpr char kAlphabet[] = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";

int Value(char c) {
  if (c >= 'A' && c <= 'Z') return c - 'A';
  if (c >= 'a' && c <= 'z') return c - 'a' + 26;
  if (c >= '0' && c <= '9') return c - '0' + 52;
  if (c == '+') return 62;
  if (c == '/') return 63;
  return -1;
}
}  // namespace

std::string Base64Encode(const void* data, size_t bytes) {
  const auto* p = static_cast<const uint8_t*>(data);
  std::string out;
  out.reserve((bytes + 2) / 3 * 4);
  for (size_t i = 0; i < bytes; i += 3) {
    const uint32_t n = (uint32_t{p[i]} << 16) | (i + 1 < bytes ? uint32_t{p[i + 1]} << 8 : 0u) |
                       (i + 2 < bytes ? uint32_t{p[i + 2]} : 0u);
    out += kAlphabet[(n >> 18) & 63];
    out += kAlphabet[(n >> 12) & 63];
    out += i + 1 < bytes ? kAlphabet[(n >> 6) & 63] : '=';
    out += i + 2 < bytes ? kAlphabet[n & 63] : '=';
  }
  return out;
}

Result<std::vector<uint8_t>> Base64Decode(const std::string& text) {
  if (text.size() % 4 != 0) return InvalidArgument("base64 text of " + std::to_string(text.size()) + " characters");
  std::vector<uint8_t> out;
  out.reserve(text.size() / 4 * 3);
  for (size_t i = 0; i < text.size(); i += 4) {
    int v[4];
    int pad = 0;
    for (int k = 0; k < 4; ++k) {
      const char c = text[i + k];
      if (c == '=' && i + 4 == text.size() && k >= 2) {
        v[k] = 0;
        ++pad;
        continue;
      }
      if (pad > 0 || (v[k] = Value(c)) < 0) {
        return InvalidArgument("base64 text has '" + std::string(1, c) + "' at character " + std::to_string(i + k));
      }
    }
    const uint32_t n = (uint32_t(v[0]) << 18) | (uint32_t(v[1]) << 12) | (uint32_t(v[2]) << 6) | uint32_t(v[3]);
    out.push_back(static_cast<uint8_t>(n >> 16));
    if (pad < 2) out.push_back(static_cast<uint8_t>(n >> 8));
    if (pad < 1) out.push_back(static_cast<uint8_t>(n));
  }
  return out;
}

std::string FloatsToBase64(const std::vector<float>& v) { return Base64Encode(v.data(), v.size() * sizeof(float)); }

Result<std::vector<float>> FloatsFromBase64(const std::string& text) {
  LTB_ASSIGN_OR_RETURN(std::vector<uint8_t> bytes, Base64Decode(text));
  if (bytes.size() % sizeof(float) != 0) {
    return InvalidArgument("base64 table of " + std::to_string(bytes.size()) + " bytes, not whole float32 values");
  }
  std::vector<float> v(bytes.size() / sizeof(float));
  std::memcpy(v.data(), bytes.data(), bytes.size());
  return v;
}

}  // namespace ltb::stages
