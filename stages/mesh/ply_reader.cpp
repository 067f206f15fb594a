// The PLY reader (mesh_reader.h): ASCII and binary (either byte order) PLY, its header
// walked, every element read in turn, vertex positions (normals, colours) and faces kept.
#include <algorithm>
#include <bit>
#include <charconv>
#include <cmath>
#include <cstring>
#include <limits>

#include "stages/mesh/mesh_reader.h"
#include "stages/mesh/mesh_text.h"

namespace ltb::mesh {

using namespace mesh_text;

static_assert(std::endian::native == std::endian::little, "the PLY reader swaps bytes for big-endian files only");

namespace {

enum class PlyType { kInt8, kUint8, kInt16, kUint16, kInt32, kUint32, kFloat32, kFloat64 };

bool ParsePlyType(std::string_view s, PlyType* t) {
  static const std::pair<const char*, PlyType> kNames[] = {
      {"char", PlyType::kInt8},      {"int8", PlyType::kInt8},       {"uchar", PlyType::kUint8},
      {"uint8", PlyType::kUint8},    {"short", PlyType::kInt16},     {"int16", PlyType::kInt16},
      {"ushort", PlyType::kUint16},  {"uint16", PlyType::kUint16},   {"int", PlyType::kInt32},
      {"int32", PlyType::kInt32},    {"uint", PlyType::kUint32},     {"uint32", PlyType::kUint32},
      {"float", PlyType::kFloat32},  {"float32", PlyType::kFloat32}, {"double", PlyType::kFloat64},
      {"float64", PlyType::kFloat64}};
  for (const auto& [n, v] : kNames) {
    if (s == n) {
      *t = v;
      return true;
    }
  }
  return false;
}

size_t TypeSize(PlyType t) {
  switch (t) {
    case PlyType::kInt8:
    case PlyType::kUint8:
      return 1;
    case PlyType::kInt16:
    case PlyType::kUint16:
      return 2;
    case PlyType::kInt32:
    case PlyType::kUint32:
    case PlyType::kFloat32:
      return 4;
    case PlyType::kFloat64:
      return 8;
  }
  return 8;
}

bool IsFloat(PlyType t) { return t == PlyType::kFloat32 || t == PlyType::kFloat64; }

struct PlyProperty {
  std::string name;
  PlyType type = PlyType::kFloat32;  // a list's item type
  bool list = false;
  PlyType count_type = PlyType::kUint8;
  // vertex: 0..2 = x, y, z, 4..6 = nx, ny, nz, 8..10 = red, green, blue (the last two when
  // asked for); face: 3 = the vertex index list
  int role = -1;
};

struct PlyElement {
  std::string name;
  uint64_t count = 0;
  uint64_t line = 0;
  std::vector<PlyProperty> props;
};

// One value as read: integers exactly, floats as double (a float32 converts exactly).
struct PlyValue {
  int64_t i = 0;
  double d = 0;
};

class PlyBody {
 public:
  PlyBody(MeshInput& in, int format) : in_(in), format_(format) {}

  Status Value(PlyType t, const std::string& what, PlyValue* v) {
    if (format_ == 0) {
      std::string_view tok;
      LTB_RETURN_IF_ERROR(Token(what, &tok));
      bool ok;
      switch (t) {
        case PlyType::kFloat32: {
          float f;
          ok = ParseNumber(tok, &f);
          v->d = f;
          break;
        }
        case PlyType::kFloat64:
          ok = ParseNumber(tok, &v->d);
          break;
        default: {
          ok = ParseNumber(tok, &v->i) && InRange(t, v->i);
          v->d = static_cast<double>(v->i);
        }
      }
      if (!ok) {
        return InvalidArgument(in_.name() + ":" + std::to_string(in_.line()) + ": " + what + " is " + Quote(tok) +
                               ", not a " + TypeName(t) + " value");
      }
      return Status::Ok();
    }
    unsigned char b[8];
    const size_t n = TypeSize(t);
    LTB_RETURN_IF_ERROR(in_.Read(b, n, what));
    if (format_ == 2) std::reverse(b, b + n);  // big endian; this build runs little-endian
    switch (t) {
      case PlyType::kInt8:
        v->i = static_cast<int8_t>(b[0]);
        break;
      case PlyType::kUint8:
        v->i = b[0];
        break;
      case PlyType::kInt16: {
        int16_t x;
        std::memcpy(&x, b, 2);
        v->i = x;
        break;
      }
      case PlyType::kUint16: {
        uint16_t x;
        std::memcpy(&x, b, 2);
        v->i = x;
        break;
      }
      case PlyType::kInt32: {
        int32_t x;
        std::memcpy(&x, b, 4);
        v->i = x;
        break;
      }
      case PlyType::kUint32: {
        uint32_t x;
        std::memcpy(&x, b, 4);
        v->i = x;
        break;
      }
      case PlyType::kFloat32: {
        float x;
        std::memcpy(&x, b, 4);
        v->d = x;
        return Status::Ok();
      }
      case PlyType::kFloat64: {
        std::memcpy(&v->d, b, 8);
        return Status::Ok();
      }
    }
    v->d = static_cast<double>(v->i);
    return Status::Ok();
  }

  // Skips `n` values of type t.
  Status Skip(PlyType t, uint64_t n, const std::string& what) {
    if (format_ != 0) {
      uint64_t bytes;
      if (!MulAdd(n, TypeSize(t), 0, &bytes) || bytes > in_.remaining()) {
        return DataLoss(in_.name() + ": " + what + " needs " + std::to_string(n) + " values, more than the " +
                        std::to_string(in_.remaining()) + " bytes left in the file (truncated, or a wrong count)");
      }
      return in_.Read(nullptr, bytes, what);
    }
    PlyValue v;
    for (uint64_t k = 0; k < n; ++k) LTB_RETURN_IF_ERROR(Value(t, what, &v));
    return Status::Ok();
  }

  std::string Where() const {
    return format_ == 0 ? in_.name() + ":" + std::to_string(in_.line())
                        : in_.name() + " (byte " + std::to_string(in_.consumed()) + ")";
  }

  static const char* TypeName(PlyType t) {
    switch (t) {
      case PlyType::kInt8:
        return "char";
      case PlyType::kUint8:
        return "uchar";
      case PlyType::kInt16:
        return "short";
      case PlyType::kUint16:
        return "ushort";
      case PlyType::kInt32:
        return "int";
      case PlyType::kUint32:
        return "uint";
      case PlyType::kFloat32:
        return "float";
      case PlyType::kFloat64:
        return "double";
    }
    return "?";
  }

 private:
  static bool InRange(PlyType t, int64_t v) {
    switch (t) {
      case PlyType::kInt8:
        return v >= -128 && v <= 127;
      case PlyType::kUint8:
        return v >= 0 && v <= 255;
      case PlyType::kInt16:
        return v >= -32768 && v <= 32767;
      case PlyType::kUint16:
        return v >= 0 && v <= 65535;
      case PlyType::kInt32:
        return v >= INT32_MIN && v <= INT32_MAX;
      case PlyType::kUint32:
        return v >= 0 && v <= int64_t{UINT32_MAX};
      default:
        return true;
    }
  }

  Status Token(const std::string& what, std::string_view* tok) {
    while (!tokens_.Next(tok)) {
      std::string_view line;
      LTB_ASSIGN_OR_RETURN(bool have, in_.NextLine(&line));
      if (!have) {
        return DataLoss(in_.name() + ": the file ends before " + what +
                        " (truncated, or a count in the header is wrong)");
      }
      tokens_ = Tokens{line};
    }
    return Status::Ok();
  }

  MeshInput& in_;
  int format_;  // 0 ascii, 1 binary little endian, 2 binary big endian
  Tokens tokens_{};
};

}  // namespace

namespace {

// What the header declares: the body's format (0 ascii, 1 binary little endian, 2 binary
// big endian) and the elements with their properties, in file order.
struct PlyHeader {
  int format = -1;
  std::vector<PlyElement> elements;
};

Result<PlyHeader> ReadPlyHeader(MeshInput& in) {
  const std::string& name = in.name();
  auto at = [&] { return name + ":" + std::to_string(in.line()); };
  std::string_view line;
  LTB_ASSIGN_OR_RETURN(bool have, in.NextLine(&line));
  if (!have || line != "ply") return InvalidArgument(name + ": does not start with \"ply\"; not a PLY file");
  PlyHeader h;
  int& format = h.format;
  std::vector<PlyElement>& elements = h.elements;
  for (;;) {
    LTB_ASSIGN_OR_RETURN(have, in.NextLine(&line));
    if (!have) return DataLoss(name + ": the header has no \"end_header\" line (truncated?)");
    Tokens t{line};
    std::string_view kw, a, b, c, d;
    if (!t.Next(&kw)) continue;
    if (kw == "end_header") break;
    if (kw == "comment" || kw == "obj_info") continue;
    if (kw == "format") {
      t.Next(&a);
      if (a == "ascii")
        format = 0;
      else if (a == "binary_little_endian")
        format = 1;
      else if (a == "binary_big_endian")
        format = 2;
      else {
        return InvalidArgument(at() + ": format " + Quote(a) +
                               " (expected ascii, binary_little_endian or binary_big_endian)");
      }
    } else if (kw == "element") {
      PlyElement e;
      uint64_t n;
      if (!t.Next(&a) || !t.Next(&b) || !ParseNumber(b, &n)) {
        return InvalidArgument(at() + ": expected \"element NAME COUNT\", found " + Quote(line));
      }
      e.name = std::string(a);
      e.count = n;
      e.line = in.line();
      elements.push_back(std::move(e));
    } else if (kw == "property") {
      if (elements.empty()) return InvalidArgument(at() + ": \"property\" before any \"element\"");
      PlyProperty p;
      if (!t.Next(&a)) return InvalidArgument(at() + ": expected \"property TYPE NAME\"");
      if (a == "list") {
        p.list = true;
        if (!t.Next(&b) || !t.Next(&c) || !t.Next(&d) || !ParsePlyType(b, &p.count_type) || !ParsePlyType(c, &p.type)) {
          return InvalidArgument(
              at() + ": expected \"property list COUNT_TYPE ITEM_TYPE NAME\" with PLY types, found " + Quote(line));
        }
        if (IsFloat(p.count_type))
          return InvalidArgument(at() + ": a list count must have an integer type, not " + Quote(b));
        p.name = std::string(d);
      } else {
        if (!ParsePlyType(a, &p.type) || !t.Next(&b)) {
          return InvalidArgument(at() +
                                 ": expected \"property TYPE NAME\" with a PLY type (char, uchar, short, ushort, "
                                 "int, uint, float, double), found " +
                                 Quote(line));
        }
        p.name = std::string(b);
      }
      elements.back().props.push_back(std::move(p));
    } else {
      return InvalidArgument(at() + ": unknown header line " + Quote(line) +
                             " (expected format, element, property, comment, obj_info or end_header)");
    }
  }
  if (format < 0) return InvalidArgument(name + ": the header has no \"format\" line");
  return h;
}

// The vertex colour properties, the first set the element has all three of.
constexpr const char* kPlyColourNames[3][3] = {
    {"red", "green", "blue"}, {"diffuse_red", "diffuse_green", "diffuse_blue"}, {"r", "g", "b"}};

// The largest value of an integer type (what an integer colour component is divided by).
double PlyTypeMax(PlyType t) {
  switch (t) {
    case PlyType::kInt8:
      return 127;
    case PlyType::kUint8:
      return 255;
    case PlyType::kInt16:
      return 32767;
    case PlyType::kUint16:
      return 65535;
    case PlyType::kInt32:
      return 2147483647.0;
    case PlyType::kUint32:
      return 4294967295.0;
    default:
      return 1;
  }
}

// Which element holds what (the first "vertex" with x, y, z, nx, ny, nz when `normals`
// asks for them and the colour properties when `colours` does; the first "face" with its
// index list), marked in the properties' roles, and the least bytes the elements need,
// checked against what follows the header.
Status ResolvePlyElements(MeshInput& in, bool normals, bool colours, PlyHeader* h, PlyElement** vertex_out,
                          PlyElement** face_out) {
  const std::string& name = in.name();
  const int format = h->format;
  std::vector<PlyElement>& elements = h->elements;
  PlyElement* vertex = nullptr;
  PlyElement* face = nullptr;
  uint64_t need = 0;
  for (PlyElement& e : elements) {
    if (e.name == "vertex" && vertex == nullptr) {
      vertex = &e;
      for (PlyProperty& p : e.props) {
        if (!p.list && (p.name == "x" || p.name == "y" || p.name == "z")) p.role = p.name[0] - 'x';
        if (normals && !p.list && (p.name == "nx" || p.name == "ny" || p.name == "nz")) p.role = 4 + p.name[1] - 'x';
      }
      for (const auto& set : kPlyColourNames) {
        if (!colours) break;
        PlyProperty* found[3] = {nullptr, nullptr, nullptr};
        for (PlyProperty& p : e.props) {
          for (int c = 0; c < 3; ++c)
            if (!p.list && p.role < 0 && found[c] == nullptr && p.name == set[c]) found[c] = &p;
        }
        if (found[0] == nullptr || found[1] == nullptr || found[2] == nullptr) continue;
        for (int c = 0; c < 3; ++c) found[c]->role = 8 + c;
        break;
      }
    } else if (e.name == "face" && face == nullptr) {
      face = &e;
      for (PlyProperty& p : e.props) {
        if (p.list && (p.name == "vertex_indices" || p.name == "vertex_index") && p.role < 0) {
          if (IsFloat(p.type)) {
            return InvalidArgument(name + ":" + std::to_string(e.line) + ": face list \"" + p.name +
                                   "\" must have an integer item type, not " + PlyBody::TypeName(p.type));
          }
          p.role = 3;
          break;
        }
      }
    }
    uint64_t per = 0;
    for (const PlyProperty& p : e.props) per += format == 0 ? 2 : (p.list ? TypeSize(p.count_type) : TypeSize(p.type));
    MulAdd(e.count, per, need, &need);
  }
  if (vertex == nullptr) return InvalidArgument(name + ": the header declares no \"element vertex\"");
  for (int r = 0; r < 3; ++r) {
    bool found = false;
    for (const PlyProperty& p : vertex->props) found |= p.role == r;
    if (!found) {
      return InvalidArgument(name + ":" + std::to_string(vertex->line) + ": element vertex has no \"" +
                             std::string(1, static_cast<char>('x' + r)) + "\" property");
    }
  }
  if (face != nullptr) {
    bool found = false;
    for (const PlyProperty& p : face->props) found |= p.role == 3;
    if (!found) {
      return InvalidArgument(name + ":" + std::to_string(face->line) +
                             ": element face has no \"vertex_indices\" (or \"vertex_index\") list property");
    }
  }
  const uint64_t nv = vertex->count;
  if (nv > kMaxVertices) {
    return InvalidArgument(name + ":" + std::to_string(vertex->line) + ": the header declares " + std::to_string(nv) +
                           " vertices; at most " + std::to_string(kMaxVertices) + " are supported");
  }
  if (need > in.remaining() + (format == 0 ? 1 : 0)) {
    std::string list;
    for (const PlyElement& e : elements) list += (list.empty() ? "" : ", ") + std::to_string(e.count) + " " + e.name;
    return DataLoss(name + ": the header declares " + list + " elements, which need at least " + Bytes(need) +
                    " bytes, but only " + std::to_string(in.remaining()) +
                    " follow the header (truncated, or a wrong count)");
  }
  *vertex_out = vertex;
  *face_out = face;
  return Status::Ok();
}

// The body: every element's items in file order; the vertex positions into m->positions
// (sized), their normals into m->file_normals and their colours into m->colours when
// those are sized, the face polygons fanned into m->triangles, everything else skipped.
Status ReadPlyBody(MeshInput& in, const PlyHeader& h, const PlyElement* vertex, const PlyElement* face,
                   const Progress& progress, TriangleMesh* m) {
  const std::string& name = in.name();
  const int format = h.format;
  const uint64_t nv = vertex->count;
  PlyBody body(in, format);
  std::vector<uint32_t> indices;
  std::vector<uint64_t> stamp;
  PlyValue v;
  PlyType colour_type[3] = {PlyType::kFloat32, PlyType::kFloat32, PlyType::kFloat32};
  const char* colour_name[3] = {"", "", ""};
  for (const PlyProperty& p : vertex->props) {
    if (p.role >= 8) {
      colour_type[p.role - 8] = p.type;
      colour_name[p.role - 8] = p.name.c_str();
    }
  }
  for (const PlyElement& e : h.elements) {
    if (e.props.empty()) continue;  // nothing to read, however many it declares
    const bool is_vertex = &e == vertex, is_face = &e == face;
    for (uint64_t i = 0; i < e.count; ++i) {
      if ((i & 0xFFFF) == 0xFFFF && progress.Cancelled())
        return Cancelled(name + ": interrupted while reading the mesh");
      double xyz[11] = {0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0};  // by role: x y z, -, nx ny nz, -, r g b
      int64_t ints[3] = {0, 0, 0};                         // the colour components as read
      for (const PlyProperty& p : e.props) {
        if (!p.list) {
          if (p.role >= 0 || format == 0) {
            LTB_RETURN_IF_ERROR(
                body.Value(p.type, e.name + " " + std::to_string(i) + " property \"" + p.name + "\"", &v));
            if (p.role >= 0) xyz[p.role] = v.d;
            if (p.role >= 8) ints[p.role - 8] = v.i;
          } else {
            LTB_RETURN_IF_ERROR(in.Read(nullptr, TypeSize(p.type), e.name + " " + std::to_string(i)));
          }
          continue;
        }
        const std::string what = e.name + " " + std::to_string(i) + " list \"" + p.name + "\"";
        LTB_RETURN_IF_ERROR(body.Value(p.count_type, what + " count", &v));
        if (v.i < 0) return InvalidArgument(body.Where() + ": " + what + " count is " + std::to_string(v.i));
        const uint64_t n = static_cast<uint64_t>(v.i);
        if (p.role != 3 || !is_face) {
          LTB_RETURN_IF_ERROR(body.Skip(p.type, n, what));
          continue;
        }
        // Binary: the declared indices must still be in the file before any is read.
        uint64_t bytes = 0;
        if (format != 0 && (!MulAdd(n, TypeSize(p.type), 0, &bytes) || bytes > in.remaining())) {
          return DataLoss(body.Where() + ": face " + std::to_string(i) + " declares " + std::to_string(n) +
                          " vertices, more than the " + std::to_string(in.remaining()) +
                          " bytes left in the file hold (truncated, or a wrong count)");
        }
        indices.clear();
        for (uint64_t j = 0; j < n; ++j) {
          LTB_RETURN_IF_ERROR(
              body.Value(p.type, "face " + std::to_string(i) + " vertex index " + std::to_string(j), &v));
          if (v.i < 0 || static_cast<uint64_t>(v.i) >= nv) {
            return InvalidArgument(body.Where() + ": face " + std::to_string(i) + ": vertex index " +
                                   std::to_string(v.i) + " is out of range (" + VertexRange(nv) +
                                   "); fix the face or the vertex count");
          }
          indices.push_back(static_cast<uint32_t>(v.i));
        }
      }
      if (is_vertex) {
        for (int c = 0; c < 3; ++c) {
          const float f = static_cast<float>(xyz[c]);
          if (!std::isfinite(f)) {
            return InvalidArgument(body.Where() + ": vertex " + std::to_string(i) + " " +
                                   std::string(1, static_cast<char>('x' + c)) + " is " + std::to_string(xyz[c]) +
                                   ", not a finite number; fix or remove the vertex");
          }
          m->positions[i][c] = f;
        }
        if (!m->file_normals.empty()) m->file_normals[i] = {xyz[4], xyz[5], xyz[6]};
        for (int c = 0; c < 3 && !m->colours.empty(); ++c) {
          const bool is_float = IsFloat(colour_type[c]);
          if (is_float ? !ValidColour(xyz[8 + c]) : ints[c] < 0) {
            return InvalidArgument(body.Where() + ": vertex " + std::to_string(i) + " " + colour_name[c] + " is " +
                                   (is_float ? Number(xyz[8 + c]) : std::to_string(ints[c])) +
                                   "; a colour component must be finite and >= 0");
          }
          m->colours[i][c] =
              is_float ? xyz[8 + c] : SrgbToLinear(static_cast<double>(ints[c]) / PlyTypeMax(colour_type[c]));
        }
      } else if (is_face) {
        AddPolygon(indices, i, &stamp, m);
      }
    }
  }
  return Status::Ok();
}

}  // namespace

Result<TriangleMesh> ReadPly(MeshInput& in, const Progress& progress, bool normals, bool colours) {
  LTB_ASSIGN_OR_RETURN(PlyHeader h, ReadPlyHeader(in));
  PlyElement* vertex = nullptr;
  PlyElement* face = nullptr;
  LTB_RETURN_IF_ERROR(ResolvePlyElements(in, normals, colours, &h, &vertex, &face));
  TriangleMesh m;
  m.positions.resize(vertex->count);
  int roles = 0, colour_roles = 0;  // nx, ny, nz found: all three or no normals
  for (const PlyProperty& p : vertex->props) {
    roles += p.role >= 4 && p.role <= 6;
    colour_roles += p.role >= 8;
  }
  if (roles == 3) m.file_normals.resize(vertex->count);
  if (colour_roles == 3) m.colours.resize(vertex->count);
  if (face != nullptr) m.triangles.reserve(face->count);
  LTB_RETURN_IF_ERROR(ReadPlyBody(in, h, vertex, face, progress, &m));
  return m;
}

}  // namespace ltb::mesh
