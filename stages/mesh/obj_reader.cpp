// Wavefront OBJ: `v` and `f` statements (and, when asked, `vn`, vertex colours and
// `usemtl`), everything else skipped. One pass; a face may name a vertex defined further
// down (OpenMesh, which read OBJ before, allowed that), so such an index is checked when
// the file ends, and it must be one the rest of the file could still define (what bounds
// the memory a forward index can cost). docs/SCENE.md
// "Mesh files" states the rules.
#include <algorithm>
#include <cmath>
#include <glm/geometric.hpp>
#include <glm/vec3.hpp>
#include <limits>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include "stages/mesh/mesh_reader.h"
#include "stages/mesh/mesh_text.h"

namespace ltb::mesh {

using namespace mesh_text;

namespace {

constexpr uint64_t kMinVertexLine = 7;  // "v 0 0 0" is the shortest statement defining a vertex

std::string_view TrimEnd(std::string_view s) {
  while (!s.empty() && IsBlank(s.back())) s.remove_suffix(1);
  return s;
}

// Removes later repeats of a vertex from a polygon, keeping the first (what OpenMesh's
// OBJ reader did before triangulating: "f 1 2 2 3" is the triangle 1 2 3). Linear:
// `stamp` (grown to the largest index) remembers the last face that used each vertex.
void RemoveRepeats(std::vector<uint32_t>* f, uint64_t face, std::vector<uint64_t>* stamp) {
  const size_t k = f->size();
  if (k == 3) {
    const uint32_t a = (*f)[0], b = (*f)[1], c = (*f)[2];
    if (a == b || a == c || b == c) f->resize(2);  // fewer than 3 distinct vertices
    return;
  }
  uint32_t top = *std::max_element(f->begin(), f->end());
  if (stamp->size() <= top) stamp->resize(size_t{top} + 1, std::numeric_limits<uint64_t>::max());
  size_t out = 0;
  for (size_t i = 0; i < k; ++i) {
    uint32_t v = (*f)[i];
    if ((*stamp)[v] == face) continue;
    (*stamp)[v] = face;
    (*f)[out++] = v;
  }
  f->resize(out);
}

// "file:line" of a statement, for messages (built only when one is needed).
struct ObjWhere {
  const std::string& name;
  uint64_t line_no;
  std::string operator()() const { return name + ":" + std::to_string(line_no); }
};

// The next statement into *line: a comment runs from '#' to the end of the line; a '\'
// ending what is left joins the next line to this statement (held in *joined). *line_no:
// the statement's first line. false at the end of the file.
Result<bool> NextStatement(MeshInput& in, std::string* joined, std::string_view* line, uint64_t* line_no) {
  LTB_ASSIGN_OR_RETURN(bool have, in.NextLine(line));
  if (!have) return false;
  *line_no = in.line();
  const ObjWhere at{in.name(), *line_no};
  auto strip = [](std::string_view l) {
    size_t hash = l.find('#');
    return TrimEnd(hash == std::string_view::npos ? l : l.substr(0, hash));
  };
  *line = strip(*line);
  if (!line->empty() && line->back() == '\\') {
    joined->assign(line->substr(0, line->size() - 1));
    for (;;) {
      LTB_ASSIGN_OR_RETURN(have, in.NextLine(line));
      if (!have) break;
      *line = strip(*line);
      const bool more = !line->empty() && line->back() == '\\';
      if (more) line->remove_suffix(1);
      if (joined->size() + line->size() + 1 > kMaxLine) {
        return InvalidArgument(at() + ": statement continued ('\\') past " + std::to_string(kMaxLine >> 20) +
                               " MiB; not an OBJ file?");
      }
      *joined += ' ';
      *joined += *line;
      if (!more) break;
    }
    *line = *joined;
  }
  return true;
}

// colours = "file": whether a vertex had a colour (`v x y z r g b`) yet, and the first
// that had none (every vertex must have one once any has).
struct ObjColours {
  bool any = false;
  uint64_t first_without = 0, first_without_line = 0;  // 1-based vertex; line 0: none yet
};

// A vertex with a colour, or one without, when `col` says whether any had one so far:
// a mix is an error naming the line of the first vertex without.
Status CheckColourMix(const ObjWhere& at, bool has, uint64_t vertex, ObjColours* col) {
  if (!has && col->first_without_line == 0) {
    col->first_without = vertex;
    col->first_without_line = at.line_no;
  }
  col->any = col->any || has;
  if (!col->any || col->first_without_line == 0) return Status::Ok();
  const std::string without = at.name + ":" + std::to_string(col->first_without_line) + ": vertex " +
                              std::to_string(col->first_without) + " has no colour";
  return InvalidArgument(without + " (\"v x y z r g b\"), but " +
                         (has ? "vertex " + std::to_string(vertex) + " (line " + std::to_string(at.line_no) + ")"
                              : std::string("an earlier vertex")) +
                         " has one; with colours = \"file\" every vertex needs r g b");
}

// The r g b of a `v x y z r g b` statement: linear, as stored (finite, >= 0).
Status ParseColour(const std::string_view* tok, const ObjWhere& at, uint64_t vertex, glm::dvec3* out) {
  for (int c = 0; c < 3; ++c) {
    double d;
    if (!ParseNumber(tok[c], &d) || !std::isfinite(d) || d < 0) {
      return InvalidArgument(at() + ": vertex " + std::to_string(vertex) + " colour component " +
                             std::to_string(c + 1) + " is " + Quote(tok[c]) +
                             "; a colour component must be a finite number >= 0 (\"v x y z r g b\")");
    }
    (*out)[c] = d;
  }
  return Status::Ok();
}

// A `v x y z [w]` statement (after the keyword) appended to m->positions; with `col`
// (colours = "file"), a `v x y z r g b` one's colour to m->colours.
Status ParseVertex(Tokens& t, const ObjWhere& at, TriangleMesh* m, ObjColours* col = nullptr) {
  std::string_view tok;
  if (m->positions.size() >= kMaxVertices) {
    return InvalidArgument(at() + ": more than " + std::to_string(kMaxVertices) + " vertices; not supported");
  }
  float p[3];
  for (int c = 0; c < 3; ++c) {
    if (!t.Next(&tok)) {
      return InvalidArgument(at() + ": vertex " + std::to_string(m->positions.size() + 1) +
                             " has fewer than 3 coordinates (expected \"v x y z [w]\")");
    }
    if (!ParseNumber(tok, &p[c]) || !std::isfinite(p[c])) {
      return InvalidArgument(at() + ": vertex coordinate " + std::to_string(c + 1) + " is " + Quote(tok) +
                             ", not a finite number (vertex " + std::to_string(m->positions.size() + 1) +
                             "); fix or remove the vertex");
    }
  }
  m->positions.push_back({p[0], p[1], p[2]});  // a w (or, unless asked for, a colour) is ignored
  if (col == nullptr) return Status::Ok();
  // Exactly 6 numbers are x y z r g b; 3, 4 (x y z w) or any other count: no colour.
  std::string_view rest[4];
  size_t k = 0;
  while (k < 4 && t.Next(&rest[k])) ++k;
  const uint64_t vertex = m->positions.size();
  LTB_RETURN_IF_ERROR(CheckColourMix(at, k == 3, vertex, col));
  if (k != 3) return Status::Ok();
  glm::dvec3 rgb;
  LTB_RETURN_IF_ERROR(ParseColour(rest, at, vertex, &rgb));
  m->colours.push_back(rgb);
  return Status::Ok();
}

// The largest index that named a vertex not yet defined where it was used (1-based),
// and where it first appeared: it must be defined by the end of the file.
struct ForwardRef {
  uint64_t index = 0, line = 0, face = 0;
  std::string token;
};

// A `vn x y z` statement (after the keyword) appended to *normals.
Status ParseNormal(Tokens& t, const ObjWhere& at, std::vector<glm::vec3>* normals) {
  std::string_view tok;
  if (normals->size() >= kMaxVertices) {
    return InvalidArgument(at() + ": more than " + std::to_string(kMaxVertices) + " normals; not supported");
  }
  float n[3];
  for (int c = 0; c < 3; ++c) {
    if (!t.Next(&tok) || !ParseNumber(tok, &n[c])) {
      return InvalidArgument(at() + ": normal " + std::to_string(normals->size() + 1) + " component " +
                             std::to_string(c + 1) + " is " + (tok.empty() ? std::string("missing") : Quote(tok)) +
                             " (expected \"vn x y z\")");
    }
  }
  normals->push_back({n[0], n[1], n[2]});
  return Status::Ok();
}

// The normal of a face's vertex reference (the n of i//n or i/t/n), as a 0-based index
// into the nn normals defined so far; UINT32_MAX when the reference names none.
Result<uint32_t> NormalIndex(std::string_view part, std::string_view tok, const ObjWhere& at, uint64_t faces,
                             uint64_t nn) {
  if (part.empty()) return std::numeric_limits<uint32_t>::max();
  int64_t k = 0;
  ParseNumber(part, &k);  // checked to be an integer by the caller
  const uint64_t back = k < 0 ? uint64_t{0} - static_cast<uint64_t>(k) : 0;
  if (k == 0 || (k < 0 && back > nn) || (k > 0 && static_cast<uint64_t>(k) > nn)) {
    return InvalidArgument(at() + ": face " + std::to_string(faces) + ": normal index " + Quote(part) + " (in " +
                           Quote(tok) + ") is out of range (" + std::to_string(nn) +
                           " vn so far; a normal must be defined before the face that uses it)");
  }
  return static_cast<uint32_t>(k < 0 ? nn - back : static_cast<uint64_t>(k) - 1);
}

// The vertex references of an `f` statement (after the keyword), face number `faces`,
// as 0-based indices into *face; nv vertices are defined so far. With `normal_refs`, the
// normal index of each reference (NormalIndex) into it; nn normals are defined so far.
Status ParseFace(Tokens& t, const ObjWhere& at, const MeshInput& in, uint64_t faces, uint64_t nv, ForwardRef* forward,
                 std::vector<uint32_t>* face, uint64_t nn = 0, std::vector<uint32_t>* normal_refs = nullptr) {
  std::string_view tok;
  auto which = [&] { return "face " + std::to_string(faces); };
  face->clear();
  if (normal_refs != nullptr) normal_refs->clear();
  while (t.Next(&tok)) {
    // i, i/t, i//n or i/t/n: only i is used; t and n, when present, must be integers.
    std::string_view parts[3];
    size_t used = 0;
    bool too_many = false;
    for (std::string_view rest = tok;;) {
      if (used == 3) {
        too_many = true;
        break;
      }
      const size_t slash = rest.find('/');
      parts[used++] = rest.substr(0, slash);
      if (slash == std::string_view::npos) break;
      rest.remove_prefix(slash + 1);
    }
    int64_t v = 0, unused = 0;
    if (too_many || parts[0].empty() || (!parts[1].empty() && !ParseNumber(parts[1], &unused)) ||
        (!parts[2].empty() && !ParseNumber(parts[2], &unused))) {
      return InvalidArgument(at() + ": " + which() + ": vertex reference " + Quote(tok) +
                             " is malformed (expected i, i/t, i//n or i/t/n with integer i, t, n)");
    }
    if (!ParseNumber(parts[0], &v)) {
      return InvalidArgument(at() + ": " + which() + ": vertex index " + Quote(parts[0]) + " is not an integer (in " +
                             Quote(tok) + ")");
    }
    // Positive: 1-based; negative: counted back from the last vertex read so far.
    const uint64_t back = v < 0 ? uint64_t{0} - static_cast<uint64_t>(v) : 0;
    if (v == 0 || (v < 0 && back > nv)) {
      return InvalidArgument(at() + ": " + which() + ": vertex index " + Quote(parts[0]) + " is out of range (" +
                             std::to_string(nv) + " vertices so far: 1.." + std::to_string(nv) + ", or -1..-" +
                             std::to_string(nv) + " counting back; 0 is never valid); fix the face");
    }
    uint64_t index = v < 0 ? nv - back : static_cast<uint64_t>(v) - 1;
    if (index >= nv) {
      // A forward reference: the rest of the file must be able to hold the vertices
      // up to it, else it can never become valid (and it would cost memory).
      const uint64_t could = nv + in.remaining() / kMinVertexLine + 1;
      if (index >= could || index >= kMaxVertices) {
        return InvalidArgument(at() + ": " + which() + ": vertex index " + Quote(parts[0]) + " is out of range (" +
                               std::to_string(nv) + " vertices so far, and the " + std::to_string(in.remaining()) +
                               " bytes left in the file cannot define " + std::to_string(index + 1 - nv) +
                               " more); fix the face");
      }
      if (index + 1 > forward->index) {
        forward->index = index + 1;
        forward->line = at.line_no;
        forward->face = faces;
        forward->token = std::string(parts[0]);
      }
    }
    face->push_back(static_cast<uint32_t>(index));
    if (normal_refs != nullptr) {
      LTB_ASSIGN_OR_RETURN(uint32_t k, NormalIndex(parts[2], tok, at, faces, nn));
      normal_refs->push_back(k);
    }
  }
  if (face->size() < 3) {
    return InvalidArgument(at() + ": " + which() + " lists " + std::to_string(face->size()) +
                           " vertices; a face needs at least 3");
  }
  return Status::Ok();
}

// normals = "file": each vertex's distinct normal indices, summed (normalised) at the end.
// A vertex's first index is kept per vertex; only a second, different one costs an entry
// in `extra` (sorted and deduplicated at the end), so memory stays bounded by the file.
struct ObjNormals {
  std::vector<glm::vec3> vn;
  std::vector<uint32_t> refs;   // per reference of the current face
  std::vector<uint32_t> first;  // per vertex, UINT32_MAX: none yet
  std::vector<std::pair<uint32_t, uint32_t>> extra;

  void Add(const std::vector<uint32_t>& face) {
    for (size_t j = 0; j < face.size(); ++j) {
      const uint32_t v = face[j], k = refs[j];
      if (k == std::numeric_limits<uint32_t>::max()) continue;
      if (first.size() <= v) first.resize(size_t{v} + 1, std::numeric_limits<uint32_t>::max());
      if (first[v] == std::numeric_limits<uint32_t>::max())
        first[v] = k;
      else if (first[v] != k)
        extra.emplace_back(v, k);
    }
  }
  void Sum(TriangleMesh* m) {
    m->file_normals.assign(m->positions.size(), glm::dvec3(0));
    auto add = [&](uint32_t v, uint32_t k) {
      const glm::dvec3 n(vn[k]);
      const double len = glm::length(n);
      m->file_normals[v] += len > 0 ? n / len : n;  // a zero or non-finite one is reported by LoadMeshFile
    };
    for (size_t v = 0; v < first.size() && v < m->positions.size(); ++v)
      if (first[v] != std::numeric_limits<uint32_t>::max()) add(static_cast<uint32_t>(v), first[v]);
    std::sort(extra.begin(), extra.end());
    extra.erase(std::unique(extra.begin(), extra.end()), extra.end());
    for (const auto& [v, k] : extra) add(v, k);
  }
};

// groups: the usemtl group of the faces being read (TriangleMesh::group_names).
struct ObjGroups {
  uint32_t current = 0;
  uint64_t current_line = 0;                           // the line of the usemtl in effect
  std::vector<bool> has_triangle;                      // per group
  std::map<std::string, uint32_t, std::less<>> index;  // name -> group

  explicit ObjGroups(TriangleMesh* m) {
    m->group_names.assign(1, std::string());
    m->group_lines.assign(1, 0);
    has_triangle.assign(1, false);
  }
  // A `usemtl NAME` statement (after the keyword): NAME, the rest trimmed, selects its group.
  Status Select(std::string_view rest, const ObjWhere& at, TriangleMesh* m) {
    while (!rest.empty() && IsBlank(rest.front())) rest.remove_prefix(1);
    rest = TrimEnd(rest);
    if (rest.empty()) return InvalidArgument(at() + ": usemtl without a material name (expected \"usemtl NAME\")");
    auto it = index.find(rest);
    if (it == index.end()) {
      if (m->group_names.size() >= std::numeric_limits<uint32_t>::max()) {
        return InvalidArgument(at() + ": more than " + std::to_string(std::numeric_limits<uint32_t>::max()) +
                               " usemtl names; not supported");
      }
      it = index.emplace(std::string(rest), static_cast<uint32_t>(m->group_names.size())).first;
      m->group_names.emplace_back(rest);
      m->group_lines.push_back(at.line_no);
      has_triangle.push_back(false);
    }
    current = it->second;
    current_line = at.line_no;
    return Status::Ok();
  }
  // The n triangles just appended to m->triangles are the current group's.
  void Add(size_t n, TriangleMesh* m) {
    if (n == 0) return;
    if (!has_triangle[current]) {
      has_triangle[current] = true;
      if (current != 0) m->group_lines[current] = current_line;
    }
    m->triangle_group.insert(m->triangle_group.end(), n, current);
  }
};

}  // namespace

Result<TriangleMesh> ReadObj(MeshInput& in, const Progress& progress, bool normals, bool colours, bool groups) {
  const std::string& name = in.name();
  TriangleMesh m;
  std::optional<ObjGroups> grp;
  if (groups) grp.emplace(&m);
  ObjNormals nrm;
  ObjColours col;
  std::string joined;  // a statement continued over lines ('\' at a line's end)
  std::vector<uint32_t> face;
  std::vector<uint64_t> stamp;
  uint64_t faces = 0;
  ForwardRef forward;
  for (uint64_t n = 0;; ++n) {
    if ((n & 0xFFFF) == 0xFFFF && progress.Cancelled()) return Cancelled(name + ": interrupted while reading the mesh");
    std::string_view line;
    uint64_t line_no = 0;
    LTB_ASSIGN_OR_RETURN(bool have, NextStatement(in, &joined, &line, &line_no));
    if (!have) break;
    const ObjWhere at{name, line_no};
    Tokens t{line};
    std::string_view kw;
    if (!t.Next(&kw)) continue;
    if (kw == "v") {
      LTB_RETURN_IF_ERROR(ParseVertex(t, at, &m, colours ? &col : nullptr));
      continue;
    }
    if (normals && kw == "vn") {
      LTB_RETURN_IF_ERROR(ParseNormal(t, at, &nrm.vn));
      continue;
    }
    if (groups && kw == "usemtl") {
      LTB_RETURN_IF_ERROR(grp->Select(t.rest, at, &m));
      continue;
    }
    if (kw != "f") continue;  // vt, vn, vp, l, p, o, g, s, usemtl, mtllib, ...: not geometry we trace
    LTB_RETURN_IF_ERROR(
        ParseFace(t, at, in, faces, m.positions.size(), &forward, &face, nrm.vn.size(), normals ? &nrm.refs : nullptr));
    if (normals) nrm.Add(face);  // before repeats are removed: every reference names a normal
    RemoveRepeats(&face, faces, &stamp);
    if (face.size() < 3) {
      m.degenerate_dropped++;  // fewer than 3 distinct vertices
    } else {
      for (size_t i = 1; i + 1 < face.size(); ++i) m.triangles.push_back({face[0], face[i], face[i + 1]});
      if (groups) grp->Add(face.size() - 2, &m);
    }
    faces++;
  }
  if (forward.index > m.positions.size()) {
    const uint64_t nv = m.positions.size();
    return InvalidArgument(name + ":" + std::to_string(forward.line) + ": face " + std::to_string(forward.face) +
                           ": vertex index " + Quote(forward.token) + " is out of range (the file has " +
                           std::to_string(nv) + " vertices: 1.." + std::to_string(nv) + "); fix the face");
  }
  if (normals && !nrm.vn.empty()) nrm.Sum(&m);
  return m;
}

}  // namespace ltb::mesh
