#include <draco/compression/decode.h>

#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <glm/geometric.hpp>
#include <glm/gtc/matrix_transform.hpp>
#include <glm/matrix.hpp>

#include "stages/mesh/draco_header.h"
#include "stages/mesh/mesh_reader.h"
#include "stages/mesh/triangle_mesh.h"

namespace ltb::mesh {
namespace {

std::string Lower(std::string s) {
  for (char& c : s) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return s;
}

Status CheckFinite(const std::string& path, const TriangleMesh& m) {
  for (size_t i = 0; i < m.positions.size(); ++i) {
    const glm::dvec3& p = m.positions[i];
    if (!std::isfinite(p.x) || !std::isfinite(p.y) || !std::isfinite(p.z)) {
      return InvalidArgument(path + ": vertex " + std::to_string(i) + " is (" + std::to_string(p.x) + ", " +
                             std::to_string(p.y) + ", " + std::to_string(p.z) + "), not finite; fix or remove it");
    }
  }
  return Status::Ok();
}

// normals = "file": every vertex has a finite, non-zero stored normal; made unit length.
Status CheckFileNormals(const std::string& path, TriangleMesh* m) {
  if (m->file_normals.size() != m->positions.size()) {
    return InvalidArgument(path +
                           ": normals = \"file\", but the file stores no vertex normals (PLY: vertex "
                           "properties nx ny nz; OBJ: vn referenced by f v//vn; Draco: a NORMAL attribute; OFF: "
                           "NOFF); use normals = \"smooth\" or \"auto\"");
  }
  for (size_t i = 0; i < m->file_normals.size(); ++i) {
    glm::dvec3& n = m->file_normals[i];
    const double len = glm::length(n);
    if (!std::isfinite(len) || !(len > 0)) {
      return InvalidArgument(path + ": normals = \"file\": vertex " + std::to_string(i) + " has normal " +
                             FormatVec3(n) + (std::isfinite(len) ? ", which is zero" : ", which is not finite") +
                             " (or none); fix the file or use normals = \"smooth\"");
    }
    n /= len;
  }
  return Status::Ok();
}

// colours = "file": the reader found colours for every vertex.
Status CheckFileColours(const std::string& path, const std::string& ext, const TriangleMesh& m) {
  if (m.colours.size() == m.positions.size()) return Status::Ok();
  const char* what = ext == ".ply"   ? "PLY: add uchar (sRGB) or float (linear) vertex properties red green blue"
                     : ext == ".off" ? "OFF: use a COFF header and r g b after x y z on every vertex line"
                     : ext == ".obj" ? "OBJ: write every vertex as \"v x y z r g b\""
                     : ext == ".drc" ? "Draco: encode the mesh with a COLOR attribute"
                                     : "the format stores none";
  const char* format = ext == ".ply"   ? "PLY"
                       : ext == ".off" ? "OFF"
                       : ext == ".obj" ? "OBJ"
                       : ext == ".drc" ? "Draco"
                                       : "mesh";
  return InvalidArgument(path + ": colours = \"file\", but this " + format + " file stores no vertex colours (" + what +
                         "); or give the object's material a colour instead");
}

// An attribute read as numbers: a bool (or unknown) attribute type would be read through a
// bool lvalue holding any byte (undefined behaviour, found by the fuzzer).
bool IsNumeric(draco::DataType t) {
  switch (t) {
    case draco::DT_FLOAT32:
    case draco::DT_FLOAT64:
    case draco::DT_INT8:
    case draco::DT_UINT8:
    case draco::DT_INT16:
    case draco::DT_UINT16:
    case draco::DT_INT32:
    case draco::DT_UINT32:
      return true;
    default:
      return false;
  }
}

// Draco's NORMAL attribute, per point (the points are the vertices ltbake uses).
Status ReadDracoNormals(const std::string& path, const draco::Mesh& mesh, TriangleMesh* out) {
  const draco::PointAttribute* nrm = mesh.GetNamedAttribute(draco::GeometryAttribute::NORMAL);
  if (nrm == nullptr) return Status::Ok();  // CheckFileNormals reports it
  if (!IsNumeric(nrm->data_type()) || nrm->num_components() < 3) {
    return InvalidArgument(path + ": Draco NORMAL attribute has data type " +
                           std::to_string(static_cast<int>(nrm->data_type())) + " and " +
                           std::to_string(int(nrm->num_components())) + " components; 3 numbers are needed");
  }
  out->file_normals.resize(mesh.num_points());
  for (draco::PointIndex i(0); i < mesh.num_points(); ++i) {
    float v[3] = {0, 0, 0};
    if (!nrm->ConvertValue<float>(nrm->mapped_index(i), 3, v)) {
      return InvalidArgument(path + ": cannot read the normal of point " + std::to_string(i.value()));
    }
    out->file_normals[i.value()] = {v[0], v[1], v[2]};
  }
  return Status::Ok();
}

// The shortest text that reads back to d (for messages: -1e-09, not -0.000000).
std::string Shortest(double d) {
  char buf[32];
  auto [p, ec] = std::to_chars(buf, buf + sizeof buf, d);
  return ec == std::errc() ? std::string(buf, p) : std::to_string(d);
}

// Draco's COLOR attribute, per point, as linear RGB (its first 3 components; an alpha is
// ignored): an integer type is divided by its largest value and sRGB-decoded (8-bit
// colours, as PLY's uchar ones), a float type is linear as stored.
Status ReadDracoColours(const std::string& path, const draco::Mesh& mesh, TriangleMesh* out) {
  const draco::PointAttribute* col = mesh.GetNamedAttribute(draco::GeometryAttribute::COLOR);
  if (col == nullptr) return Status::Ok();  // CheckFileColours reports it
  if (!IsNumeric(col->data_type()) || col->num_components() < 3) {
    return InvalidArgument(path + ": Draco COLOR attribute has data type " +
                           std::to_string(static_cast<int>(col->data_type())) + " and " +
                           std::to_string(int(col->num_components())) + " components; 3 numbers (r g b) are needed");
  }
  const draco::DataType t = col->data_type();
  const bool is_float = t == draco::DT_FLOAT32 || t == draco::DT_FLOAT64;
  const double max = t == draco::DT_INT8     ? 127.0
                     : t == draco::DT_UINT8  ? 255.0
                     : t == draco::DT_INT16  ? 32767.0
                     : t == draco::DT_UINT16 ? 65535.0
                     : t == draco::DT_INT32  ? 2147483647.0
                                             : 4294967295.0;
  static const char* const kNames[3] = {"red", "green", "blue"};
  out->colours.resize(mesh.num_points());
  for (draco::PointIndex i(0); i < mesh.num_points(); ++i) {
    double d[3] = {0, 0, 0};
    int64_t n[3] = {0, 0, 0};
    // Integers as stored (not through double, which would apply the attribute's
    // "normalized" flag): the same rule whatever the encoder set.
    const bool ok = is_float ? col->ConvertValue<double>(col->mapped_index(i), 3, d)
                             : col->ConvertValue<int64_t>(col->mapped_index(i), 3, n);
    if (!ok) return InvalidArgument(path + ": cannot read the colour of point " + std::to_string(i.value()));
    for (int c = 0; c < 3; ++c) {
      const bool bad = is_float ? !std::isfinite(d[c]) || d[c] < 0 : n[c] < 0;
      if (bad) {
        return InvalidArgument(path + ": Draco point " + std::to_string(i.value()) + " colour " + kNames[c] + " is " +
                               (is_float ? Shortest(d[c]) : std::to_string(n[c])) +
                               "; a colour component must be finite and >= 0");
      }
      out->colours[i.value()][c] = is_float ? d[c] : SrgbToLinear(static_cast<double>(n[c]) / max);
    }
  }
  return Status::Ok();
}

Result<TriangleMesh> LoadDraco(const std::string& path, bool file_normals, bool file_colours) {
  std::ifstream f(path, std::ios::binary);
  if (!f) return NotFound(path + ": cannot open mesh file");
  std::vector<char> data((std::istreambuf_iterator<char>(f)), {});
  // libdraco sizes its tables by the header's counts before it decodes anything.
  LTB_RETURN_IF_ERROR(
      CheckDracoCounts(path, std::span(reinterpret_cast<const unsigned char*>(data.data()), data.size())));
  draco::DecoderBuffer buffer;
  buffer.Init(data.data(), data.size());
  draco::Decoder decoder;
  auto decoded = decoder.DecodeMeshFromBuffer(&buffer);
  if (!decoded.ok())
    return InvalidArgument(path + ": not a readable Draco mesh: " + decoded.status().error_msg_string());
  std::unique_ptr<draco::Mesh> mesh = std::move(decoded).value();
  const draco::PointAttribute* pos = mesh->GetNamedAttribute(draco::GeometryAttribute::POSITION);
  if (pos == nullptr) return InvalidArgument(path + ": Draco mesh has no position attribute");
  if (!IsNumeric(pos->data_type())) {
    return InvalidArgument(path + ": Draco mesh position attribute has data type " +
                           std::to_string(static_cast<int>(pos->data_type())) +
                           "; positions must be float or integer (re-encode the mesh with draco_encoder)");
  }
  if (pos->num_components() < 3) {
    return InvalidArgument(path + ": Draco mesh positions have " + std::to_string(int(pos->num_components())) +
                           " components; 3 (x, y, z) are needed");
  }
  TriangleMesh out;
  out.positions.resize(mesh->num_points());
  for (draco::PointIndex i(0); i < mesh->num_points(); ++i) {
    float v[3] = {0, 0, 0};
    if (!pos->ConvertValue<float>(pos->mapped_index(i), 3, v)) {
      return InvalidArgument(path + ": cannot read position of point " + std::to_string(i.value()));
    }
    out.positions[i.value()] = {v[0], v[1], v[2]};
  }
  for (draco::FaceIndex fi(0); fi < mesh->num_faces(); ++fi) {
    const auto& face = mesh->face(fi);
    out.triangles.push_back({face[0].value(), face[1].value(), face[2].value()});
  }
  if (file_normals) LTB_RETURN_IF_ERROR(ReadDracoNormals(path, *mesh, &out));
  if (file_colours) LTB_RETURN_IF_ERROR(ReadDracoColours(path, *mesh, &out));
  return out;
}

}  // namespace

Result<TriangleMesh> LoadMeshFile(const std::string& path, const Progress& progress, bool file_normals,
                                  bool file_colours, bool groups) {
  std::string ext = Lower(std::filesystem::path(path).extension().string());
  // Opening refuses a directory, FIFO or device by name (and never blocks on a FIFO).
  LTB_ASSIGN_OR_RETURN(MeshInput in, MeshInput::Open(path, &progress));
  Result<TriangleMesh> r = InvalidArgument(path + ": unknown mesh format " +
                                           (ext.empty() ? std::string("(no extension)") : "\"" + ext + "\"") +
                                           "; supported: .obj, .ply, .off, .stl, .drc");
  if (groups && ext != ".obj") {
    return InvalidArgument(path + ": usemtl = true: only OBJ files have usemtl statements, and this is " +
                           (ext.empty() ? std::string("a file without an extension") : "a \"" + ext + "\" file") +
                           "; leave usemtl out (the object's material applies) or convert the mesh to OBJ");
  }
  if (ext == ".stl" && file_normals) {
    return InvalidArgument(path +
                           ": normals = \"file\": STL stores only facet normals, no vertex normals; use "
                           "normals = \"flat\" (image mode) or \"smooth\"");
  }
  if (ext == ".stl" && file_colours) {
    return InvalidArgument(path +
                           ": colours = \"file\": STL stores no vertex colours; convert the mesh to PLY (red green "
                           "blue vertex properties) or give the object's material a colour instead");
  }
  if (ext == ".off") {
    r = ReadOff(in, progress, file_normals, file_colours);
  } else if (ext == ".ply") {
    r = ReadPly(in, progress, file_normals, file_colours);
  } else if (ext == ".obj") {
    r = ReadObj(in, progress, file_normals, file_colours, groups);
  } else if (ext == ".stl") {
    r = ReadStl(in, progress);
  } else if (ext == ".drc") {
    try {
      r = LoadDraco(path, file_normals, file_colours);
    } catch (const std::bad_alloc&) {
      return InvalidArgument(path + ": reading the mesh ran out of memory (a corrupt count in the file?)");
    } catch (const std::exception& e) {
      return InvalidArgument(path + ": cannot read the mesh: " + e.what());
    }
  }
  if (!r.ok()) return r;
  TriangleMesh& m = *r;
  LTB_RETURN_IF_ERROR(CheckFinite(path, m));
  if (file_normals) LTB_RETURN_IF_ERROR(CheckFileNormals(path, &m));
  if (file_colours) LTB_RETURN_IF_ERROR(CheckFileColours(path, ext, m));
  Finalize(&m);
  if (m.triangles.empty()) {
    return InvalidArgument(path + ": the mesh holds no triangles" +
                           (m.degenerate_dropped
                                ? " (" + std::to_string(m.degenerate_dropped) + " degenerate ones dropped)"
                                : std::string()));
  }
  return r;
}

std::string FormatVec3(const glm::dvec3& v) {
  char b[96];
  std::snprintf(b, sizeof b, "[%.9g, %.9g, %.9g]", v.x, v.y, v.z);
  return b;
}

TriangleMesh MakePlane(const glm::dvec3& size) {
  TriangleMesh m;
  double x = size.x / 2, y = size.y / 2;
  m.positions = {{-x, -y, 0}, {x, -y, 0}, {x, y, 0}, {-x, y, 0}};
  m.triangles = {{0, 1, 2}, {0, 2, 3}};
  Finalize(&m);
  return m;
}

TriangleMesh MakeBox(const glm::dvec3& size, const glm::dvec3& c) {
  TriangleMesh m;
  glm::dvec3 h = size / 2.0;
  // Each face has its own 4 vertices so vertex normals are the face normals.
  const int faces[6][4][3] = {
      {{-1, -1, -1}, {-1, 1, -1}, {1, 1, -1}, {1, -1, -1}},  // -z
      {{-1, -1, 1}, {1, -1, 1}, {1, 1, 1}, {-1, 1, 1}},      // +z
      {{-1, -1, -1}, {1, -1, -1}, {1, -1, 1}, {-1, -1, 1}},  // -y
      {{-1, 1, -1}, {-1, 1, 1}, {1, 1, 1}, {1, 1, -1}},      // +y
      {{-1, -1, -1}, {-1, -1, 1}, {-1, 1, 1}, {-1, 1, -1}},  // -x
      {{1, -1, -1}, {1, 1, -1}, {1, 1, 1}, {1, -1, 1}},      // +x
  };
  for (const auto& f : faces) {
    unsigned base = static_cast<unsigned>(m.positions.size());
    for (const auto& v : f) m.positions.push_back(c + glm::dvec3(v[0], v[1], v[2]) * h);
    m.triangles.push_back({base, base + 1, base + 2});
    m.triangles.push_back({base, base + 2, base + 3});
  }
  Finalize(&m);
  return m;
}

void ApplyTransform(const glm::dmat4& m, TriangleMesh* mesh) {
  for (auto& p : mesh->positions) p = glm::dvec3(m * glm::dvec4(p, 1.0));
  // A mirroring transform flips the winding; keep outward normals outward.
  if (glm::determinant(glm::dmat3(m)) < 0) {
    for (auto& t : mesh->triangles) std::swap(t[1], t[2]);
  }
  if (!mesh->file_normals.empty()) {
    // Normals are covectors: n' ∝ (M⁻¹)ᵀ n. A singular M (a zero scale) leaves no
    // triangles, which the caller reports; the normals are then left as they are.
    const glm::dmat3 a(m);
    if (glm::determinant(a) != 0) {
      const glm::dmat3 it = glm::transpose(glm::inverse(a));
      for (auto& n : mesh->file_normals) {
        const glm::dvec3 t = it * n;
        const double len = glm::length(t);
        if (len > 0 && std::isfinite(len)) n = t / len;
      }
    }
  }
  Finalize(mesh);  // colours are per vertex, whatever the transform: kept as they are
}

void Finalize(TriangleMesh* m) {
  std::vector<glm::uvec3> kept;
  kept.reserve(m->triangles.size());
  // triangle_group stays aligned with triangles: the kept ones move down in place.
  const bool grouped = m->triangle_group.size() == m->triangles.size() && !m->triangle_group.empty();
  m->normals.assign(m->positions.size(), glm::dvec3(0));
  for (size_t i = 0; i < m->triangles.size(); ++i) {
    const glm::uvec3 t = m->triangles[i];
    if (t[0] >= m->positions.size() || t[1] >= m->positions.size() || t[2] >= m->positions.size()) {
      m->degenerate_dropped++;
      continue;
    }
    glm::dvec3 n = glm::cross(m->positions[t[1]] - m->positions[t[0]], m->positions[t[2]] - m->positions[t[0]]);
    double len = glm::length(n);
    if (!(len > 0) || t[0] == t[1] || t[1] == t[2] || t[0] == t[2]) {
      m->degenerate_dropped++;
      continue;
    }
    for (int k = 0; k < 3; ++k) m->normals[t[k]] += n;  // area-weighted (|n| = 2·area)
    if (grouped) m->triangle_group[kept.size()] = m->triangle_group[i];
    kept.push_back(t);
  }
  m->triangles.swap(kept);
  if (grouped) m->triangle_group.resize(m->triangles.size());
  for (auto& n : m->normals) {
    double len = glm::length(n);
    n = len > 0 ? n / len : glm::dvec3(0, 0, 1);
  }
}

}  // namespace ltb::mesh
