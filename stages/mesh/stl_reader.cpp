// STL, binary and ASCII. A file whose length is exactly 84 + 50·n bytes for the n its
// header declares is binary (even when its header starts with "solid", as many binary
// writers' do); otherwise it must be ASCII (start with "solid"). Vertices equal in all
// three coordinates (-0 = +0) are merged, in order of first appearance, as OpenMesh, which
// read STL before, merged them; a triangle whose corners merge is dropped and counted.
#include <bit>
#include <cmath>
#include <cstring>
#include <string>
#include <vector>

#include "stages/mesh/mesh_reader.h"
#include "stages/mesh/mesh_text.h"

namespace ltb::mesh {

using namespace mesh_text;

namespace {

constexpr uint64_t kBinaryHeader = 84, kBinaryTriangle = 50;

// Positions seen so far → vertex id: open addressing over the float bit patterns, the
// table at most half full. Memory: 4 bytes a slot, 2–4 slots a vertex.
class VertexMerger {
 public:
  // The id of p (x, y, z as float), adding it to m->positions when new.
  // At most kMaxVertices - 1 vertices (the caller checks Full() first).
  bool Full(const TriangleMesh& m) const { return m.positions.size() + 1 >= kMaxVertices; }
  uint32_t Id(const float p[3], TriangleMesh* m) {
    uint32_t key[3];
    for (int c = 0; c < 3; ++c) key[c] = std::bit_cast<uint32_t>(p[c] == 0.0f ? 0.0f : p[c]);  // -0 is +0
    if (2 * (m->positions.size() + 1) > slots_.size()) Grow(*m);
    const size_t mask = slots_.size() - 1;
    for (size_t i = Hash(key) & mask;; i = (i + 1) & mask) {
      const uint32_t s = slots_[i];
      if (s == kEmpty) {
        const uint32_t id = static_cast<uint32_t>(m->positions.size());
        m->positions.push_back({p[0], p[1], p[2]});
        keys_.insert(keys_.end(), key, key + 3);
        slots_[i] = id;
        return id;
      }
      if (std::memcmp(&keys_[3 * size_t{s}], key, sizeof key) == 0) return s;
    }
  }

 private:
  static constexpr uint32_t kEmpty = 0xFFFFFFFFu;

  static uint64_t Hash(const uint32_t k[3]) {
    uint64_t h = (uint64_t{k[0]} << 32 | k[1]) * 0x9E3779B97F4A7C15ull ^ (uint64_t{k[2]} * 0xC2B2AE3D27D4EB4Full);
    h ^= h >> 31;
    h *= 0xBF58476D1CE4E5B9ull;
    return h ^ (h >> 29);
  }

  void Grow(const TriangleMesh& m) {
    slots_.assign(slots_.empty() ? 1024 : 2 * slots_.size(), kEmpty);
    const size_t mask = slots_.size() - 1;
    for (uint32_t id = 0; id < m.positions.size(); ++id) {
      size_t i = Hash(&keys_[3 * size_t{id}]) & mask;
      while (slots_[i] != kEmpty) i = (i + 1) & mask;
      slots_[i] = id;
    }
  }

  std::vector<uint32_t> slots_;
  std::vector<uint32_t> keys_;  // 3 per vertex: the bit patterns hashed
};

void AddTriangle(const uint32_t v[3], TriangleMesh* m) {
  if (v[0] == v[1] || v[1] == v[2] || v[0] == v[2]) {
    m->degenerate_dropped++;
    return;
  }
  m->triangles.push_back({v[0], v[1], v[2]});
}

bool SameWord(std::string_view a, std::string_view b) {
  if (a.size() != b.size()) return false;
  for (size_t i = 0; i < a.size(); ++i) {
    if ((a[i] | 0x20) != b[i]) return false;  // b is lower case letters
  }
  return true;
}

// ASCII STL as a stream of tokens over lines.
class StlText {
 public:
  explicit StlText(MeshInput& in) : in_(in) {}

  // The next token; false at the end of the file.
  Result<bool> Next(std::string_view* tok) {
    while (!tokens_.Next(tok)) {
      std::string_view line;
      LTB_ASSIGN_OR_RETURN(bool have, in_.NextLine(&line));
      if (!have) return false;
      tokens_ = Tokens{line};
    }
    return true;
  }
  void SkipRestOfLine() { tokens_ = Tokens{}; }

  // The next token must be `word` (any case).
  Status Expect(std::string_view word, const std::string& where) {
    std::string_view tok;
    LTB_ASSIGN_OR_RETURN(bool have, Next(&tok));
    if (!have) {
      return DataLoss(in_.name() + ": the file ends " + where + ", before \"" + std::string(word) + "\" (truncated?)");
    }
    if (!SameWord(tok, word)) {
      return InvalidArgument(At() + ": expected \"" + std::string(word) + "\" " + where + ", found " + Quote(tok));
    }
    return Status::Ok();
  }
  std::string At() const { return in_.name() + ":" + std::to_string(in_.line()); }

 private:
  MeshInput& in_;
  Tokens tokens_{};
};

Result<TriangleMesh> ReadStlBinary(MeshInput& in, uint64_t n, const Progress& progress) {
  const std::string& name = in.name();
  LTB_RETURN_IF_ERROR(in.Read(nullptr, kBinaryHeader, "the binary STL header"));
  TriangleMesh m;
  m.triangles.reserve(n);
  VertexMerger merge;
  unsigned char t[kBinaryTriangle];
  for (uint64_t i = 0; i < n; ++i) {
    if ((i & 0xFFFF) == 0xFFFF && progress.Cancelled()) return Cancelled(name + ": interrupted while reading the mesh");
    const uint64_t offset = in.consumed();
    LTB_RETURN_IF_ERROR(in.Read(t, kBinaryTriangle, "triangle " + std::to_string(i)));
    uint32_t v[3];
    for (int k = 0; k < 3; ++k) {
      float p[3];
      std::memcpy(p, t + 12 + 12 * k, 12);  // after the facet normal; little endian
      for (int c = 0; c < 3; ++c) {
        if (!std::isfinite(p[c])) {
          return InvalidArgument(name + " (byte " + std::to_string(offset + 12 + 12 * k + 4 * c) + "): triangle " +
                                 std::to_string(i) + " vertex " + std::to_string(k) + " " +
                                 std::string(1, static_cast<char>('x' + c)) + " is " + std::to_string(p[c]) +
                                 ", not a finite number; fix or remove the triangle");
        }
      }
      if (merge.Full(m))
        return InvalidArgument(name + ": more than " + std::to_string(kMaxVertices - 1) + " vertices; not supported");
      v[k] = merge.Id(p, &m);
    }
    AddTriangle(v, &m);
  }
  return m;
}

Result<TriangleMesh> ReadStlText(MeshInput& in, const Progress& progress) {
  const std::string& name = in.name();
  StlText s(in);
  LTB_RETURN_IF_ERROR(s.Expect("solid", "at the start"));
  s.SkipRestOfLine();  // the solid's name
  TriangleMesh m;
  VertexMerger merge;
  std::string_view tok;
  for (uint64_t facet = 0;;) {
    if ((facet & 0xFFFF) == 0xFFFF && progress.Cancelled())
      return Cancelled(name + ": interrupted while reading the mesh");
    LTB_ASSIGN_OR_RETURN(bool have, s.Next(&tok));
    if (!have)
      return DataLoss(name + ": the file ends after " + std::to_string(facet) +
                      " facets, before \"endsolid\" (truncated?)");
    if (SameWord(tok, "endsolid")) {
      s.SkipRestOfLine();
      LTB_ASSIGN_OR_RETURN(have, s.Next(&tok));
      if (!have) break;
      if (!SameWord(tok, "solid")) {
        return InvalidArgument(s.At() + ": expected \"solid\" or the end of the file after \"endsolid\", found " +
                               Quote(tok));
      }
      s.SkipRestOfLine();  // another solid follows
      continue;
    }
    const std::string where = "in facet " + std::to_string(facet);
    if (!SameWord(tok, "facet")) {
      return InvalidArgument(s.At() + ": expected \"facet\" or \"endsolid\", found " + Quote(tok));
    }
    LTB_RETURN_IF_ERROR(s.Expect("normal", where));
    for (int c = 0; c < 3; ++c) {  // the normal is not used (often zero); it must be there
      LTB_ASSIGN_OR_RETURN(have, s.Next(&tok));
      if (!have) return DataLoss(name + ": the file ends " + where + " (truncated?)");
    }
    LTB_RETURN_IF_ERROR(s.Expect("outer", where));
    LTB_RETURN_IF_ERROR(s.Expect("loop", where));
    uint32_t v[3];
    for (int k = 0; k < 3; ++k) {
      LTB_RETURN_IF_ERROR(s.Expect("vertex", where));
      float p[3];
      for (int c = 0; c < 3; ++c) {
        LTB_ASSIGN_OR_RETURN(have, s.Next(&tok));
        if (!have) return DataLoss(name + ": the file ends " + where + " (truncated?)");
        if (!ParseNumber(tok, &p[c]) || !std::isfinite(p[c])) {
          return InvalidArgument(s.At() + ": facet " + std::to_string(facet) + " vertex " + std::to_string(k) +
                                 " coordinate " + std::to_string(c + 1) + " is " + Quote(tok) +
                                 ", not a finite number; fix or remove the facet");
        }
      }
      if (merge.Full(m))
        return InvalidArgument(s.At() + ": more than " + std::to_string(kMaxVertices - 1) + " vertices; not supported");
      v[k] = merge.Id(p, &m);
    }
    LTB_RETURN_IF_ERROR(s.Expect("endloop", where + " (a facet has exactly 3 vertices)"));
    LTB_RETURN_IF_ERROR(s.Expect("endfacet", where));
    AddTriangle(v, &m);
    facet++;
  }
  return m;
}

}  // namespace

Result<TriangleMesh> ReadStl(MeshInput& in, const Progress& progress) {
  LTB_ASSIGN_OR_RETURN(std::string_view head, in.Peek(kBinaryHeader));
  uint32_t n = 0;
  if (head.size() == kBinaryHeader) {
    std::memcpy(&n, head.data() + 80, 4);  // little endian
    if (kBinaryHeader + kBinaryTriangle * uint64_t{n} == in.size()) return ReadStlBinary(in, n, progress);
  }
  size_t i = 0;
  while (i < head.size() && (IsBlank(head[i]) || head[i] == '\n')) ++i;
  if (!SameWord(head.substr(i, 5), "solid")) {
    if (head.size() < kBinaryHeader) {
      return InvalidArgument(in.name() + ": not an ASCII STL (no \"solid\") and, at " + std::to_string(in.size()) +
                             " bytes, too short for a binary one (an 84-byte header)");
    }
    return InvalidArgument(in.name() + ": not an ASCII STL (no \"solid\") and not a binary one: its header declares " +
                           std::to_string(n) + " triangles, which take " +
                           std::to_string(kBinaryHeader + kBinaryTriangle * uint64_t{n}) + " bytes, but the file has " +
                           std::to_string(in.size()) + " (truncated, or a wrong count)");
  }
  Result<TriangleMesh> r = ReadStlText(in, progress);
  if (!r.ok() && r.status().code() != StatusCode::kCancelled && head.size() == kBinaryHeader) {
    // Perhaps a binary STL whose header starts with "solid" and whose count is wrong.
    return Status(r.status().code(), r.status().message() + " (read as ASCII STL because it starts with \"solid\"; " +
                                         "read as binary, its header declares " + std::to_string(n) +
                                         " triangles, which take " +
                                         std::to_string(kBinaryHeader + kBinaryTriangle * uint64_t{n}) +
                                         " bytes, but the file has " + std::to_string(in.size()) + ")");
  }
  return r;
}

}  // namespace ltb::mesh
