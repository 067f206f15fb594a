// Internal to the mesh readers (mesh_reader.cpp, ply_reader.cpp, obj_reader.cpp, stl_reader.cpp): the
// small text and arithmetic helpers they share. Not part of the mesh library's API.
#pragma once

#include <charconv>
#include <cstdint>
#include <limits>
#include <string>
#include <string_view>
#include <vector>

#include "stages/mesh/triangle_mesh.h"

namespace ltb::mesh::mesh_text {

inline constexpr size_t kPiece = size_t{1} << 20;     // bytes read at a time
inline constexpr size_t kMaxLine = size_t{64} << 20;  // a longer line (or statement) is refused
inline constexpr uint64_t kMaxVertices = std::numeric_limits<uint32_t>::max();  // indices are 32-bit

// A token for a message: at most 40 characters, control bytes shown as '?', in quotes.
inline std::string Quote(std::string_view s) {
  std::string out = "\"";
  for (char c : s.substr(0, 40)) out += (static_cast<unsigned char>(c) < 32 || c == 127) ? '?' : c;
  return out + (s.size() > 40 ? "...\"" : "\"");
}

inline bool IsBlank(char c) { return c == ' ' || c == '\t' || c == '\r' || c == '\f' || c == '\v'; }

// Whitespace-separated tokens of one line.
struct Tokens {
  std::string_view rest;
  bool Next(std::string_view* t) {
    size_t i = 0;
    while (i < rest.size() && IsBlank(rest[i])) ++i;
    size_t j = i;
    while (j < rest.size() && !IsBlank(rest[j])) ++j;
    *t = rest.substr(i, j - i);
    rest.remove_prefix(j);
    return !t->empty();
  }
};

// The whole token as a number (an optional leading '+' allowed); false otherwise, and for
// a value out of the type's range.
template <typename T>
bool ParseNumber(std::string_view t, T* out) {
  if (!t.empty() && t[0] == '+') t.remove_prefix(1);
  if (t.empty()) return false;
  auto [p, ec] = std::from_chars(t.data(), t.data() + t.size(), *out);
  return ec == std::errc() && p == t.data() + t.size();
}

// *out = a·b + c; false (and *out = 2^64 - 1) when that does not fit in 64 bits.
inline bool MulAdd(uint64_t a, uint64_t b, uint64_t c, uint64_t* out) {
  uint64_t m;
  if (__builtin_mul_overflow(a, b, &m) || __builtin_add_overflow(m, c, out)) {
    *out = std::numeric_limits<uint64_t>::max();
    return false;
  }
  return true;
}

inline std::string Bytes(uint64_t n) {
  return n == std::numeric_limits<uint64_t>::max() ? std::string("more than 2^64") : std::to_string(n);
}

// Defined in mesh_reader.cpp, shared by the OFF and PLY readers.
// Appends the polygon's fan triangles, or counts it as degenerate (fewer than 3 vertices, or
// a vertex repeated). `stamp[v]` holds the last polygon that used v.
void AddPolygon(const std::vector<uint32_t>& f, uint64_t face, std::vector<uint64_t>* stamp, TriangleMesh* m);
// A colour component must be finite and >= 0 (a float one may exceed 1: it scales an albedo).
bool ValidColour(double c);
// A value for a message: the shortest text that reads back to it (-0.25, 1e-09, nan).
std::string Number(double d);
// "the file declares N vertices: 0..N-1" (or none), for an index out of range.
std::string VertexRange(uint64_t nv);

}  // namespace ltb::mesh::mesh_text
