#include "stages/sample/geometry.h"

#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <sstream>

#include <OpenMesh/Core/IO/MeshIO.hh>
#include <OpenMesh/Core/Mesh/TriMesh_ArrayKernelT.hh>
#include <draco/compression/decode.h>
#include <glm/geometric.hpp>
#include <glm/gtc/matrix_transform.hpp>

#include "stages/sample/mesh_reader.h"

namespace ltb::sample {
namespace {

using OmMesh = OpenMesh::TriMesh_ArrayKernelT<>;

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

Result<TriangleMesh> LoadDraco(const std::string& path) {
  std::ifstream f(path, std::ios::binary);
  if (!f) return NotFound(path + ": cannot open mesh file");
  std::vector<char> data((std::istreambuf_iterator<char>(f)), {});
  draco::DecoderBuffer buffer;
  buffer.Init(data.data(), data.size());
  draco::Decoder decoder;
  auto decoded = decoder.DecodeMeshFromBuffer(&buffer);
  if (!decoded.ok()) return InvalidArgument(path + ": not a readable Draco mesh: " + decoded.status().error_msg_string());
  std::unique_ptr<draco::Mesh> mesh = std::move(decoded).value();
  const draco::PointAttribute* pos = mesh->GetNamedAttribute(draco::GeometryAttribute::POSITION);
  if (pos == nullptr) return InvalidArgument(path + ": Draco mesh has no position attribute");
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
  return out;
}

Result<TriangleMesh> LoadOpenMesh(const std::string& path) {
  OmMesh mesh;
  OpenMesh::IO::Options opt;
  // OpenMesh reports on omerr, which writes to std::cerr; a library must not print, so
  // capture that into a string (and count what it says) while the mesh is read. (Its
  // connect/disconnect would leak a wrapper per call.) Meshes are read before any worker
  // thread starts.
  std::ostringstream log;
  std::streambuf* saved = std::cerr.rdbuf(log.rdbuf());
  bool ok = OpenMesh::IO::read_mesh(mesh, path, opt);
  omerr().flush();
  std::cerr.rdbuf(saved);
  if (!ok) {
    std::string why = log.str();
    while (!why.empty() && (why.back() == '\n' || why.back() == ' ')) why.pop_back();
    if (!std::ifstream(path)) return NotFound(path + ": cannot open mesh file");
    return InvalidArgument(path + ": OpenMesh cannot read it" + (why.empty() ? "" : " (" + why + ")") +
                           "; supported: OBJ, PLY (ASCII or binary), OFF, STL, and Draco .drc");
  }
  TriangleMesh out;
  std::string messages = log.str();
  for (size_t p = 0; (p = messages.find("equal vertices", p)) != std::string::npos; ++p) out.degenerate_dropped++;
  out.positions.reserve(mesh.n_vertices());
  for (auto v : mesh.vertices()) {
    auto p = mesh.point(v);
    out.positions.push_back({p[0], p[1], p[2]});
  }
  for (auto f : mesh.faces()) {
    glm::uvec3 t;
    int k = 0;
    for (auto v : mesh.fv_range(f)) {
      if (k < 3) t[k] = static_cast<unsigned>(v.idx());
      ++k;
    }
    if (k == 3) out.triangles.push_back(t);
  }
  // Non-manifold faces are kept: OpenMesh's importer gives them their own vertex copies.
  return out;
}

}  // namespace

// OpenMesh's OBJ reader turns a coordinate it cannot parse ("nan", "inf", "1e999", "x")
// into a number silently, and drops a face with an out-of-range index without a word:
// check the `v` lines' coordinates and the `f` lines' indices first, naming the line.
// (OpenMesh resolves an index against all the file's vertices, so this does too.)
Status CheckObjFile(const std::string& path, const Progress& progress) {
  uint64_t vertices = 0;
  for (int pass = 0; pass < 2; ++pass) {
    std::ifstream f(path);
    if (!f) return NotFound(path + ": cannot open mesh file");
    std::string line;
    uint64_t face = 0;
    for (uint64_t n = 1; std::getline(f, line); ++n) {
      if ((n & 0xFFFF) == 0 && progress.Cancelled()) return Cancelled(path + ": interrupted while checking the mesh");
      if (line.size() < 2 || (line[1] != ' ' && line[1] != '\t')) continue;
      if (line[0] == 'v' && pass == 0) {
        vertices++;
        const char* p = line.c_str() + 2;
        for (int k = 0; k < 3; ++k) {
          while (*p == ' ' || *p == '\t') ++p;
          const char* start = p;
          while (*p && *p != ' ' && *p != '\t' && *p != '\r') ++p;
          std::string token(start, p);
          char* end = nullptr;
          double v = std::strtod(token.c_str(), &end);
          if (token.empty() || end != token.c_str() + token.size() || !std::isfinite(v)) {
            return InvalidArgument(path + ":" + std::to_string(n) + ": vertex coordinate " + std::to_string(k + 1) +
                                   " is \"" + token + "\", not a finite number; fix or remove the vertex");
          }
        }
      } else if (line[0] == 'f' && pass == 1) {
        std::istringstream in(line.substr(2));
        std::string token;
        while (in >> token) {
          std::string index = token.substr(0, token.find('/'));
          char* end = nullptr;
          errno = 0;
          long long v = std::strtoll(index.c_str(), &end, 10);
          const long long nv = static_cast<long long>(vertices);
          if (index.empty() || *end != '\0' || errno == ERANGE || v == 0 || v > nv || v < -nv) {
            return InvalidArgument(path + ":" + std::to_string(n) + ": face " + std::to_string(face) + ": vertex index \"" +
                                   index + "\" is out of range (the file has " + std::to_string(vertices) +
                                   " vertices: 1.." + std::to_string(vertices) + ", or -1..-" + std::to_string(vertices) +
                                   " counting back); fix the face");
          }
        }
        face++;
      }
    }
  }
  return Status::Ok();
}

// A binary STL holds 84 + 50·n bytes for the n triangles its header declares; OpenMesh
// reads any other file as ASCII STL, which turns a binary file with a wrong count into
// an empty mesh without a word. ASCII `vertex` lines are checked for finite coordinates
// (OpenMesh would read "nan" as a number).
Status CheckStlFile(const std::string& path, const Progress& progress) {
  std::ifstream f(path, std::ios::binary);
  if (!f) return NotFound(path + ": cannot open mesh file");
  char head[84] = {};
  f.read(head, sizeof head);
  const uint64_t got = static_cast<uint64_t>(f.gcount());
  std::error_code ec;
  const uint64_t size = std::filesystem::file_size(path, ec);
  if (got == sizeof head) {
    uint32_t n;
    std::memcpy(&n, head + 80, 4);
    if (84 + 50 * uint64_t{n} == size) return Status::Ok();  // binary, and consistent
  }
  std::string_view start(head, got);
  size_t i = start.find_first_not_of(" \t\r\n");
  if (i == std::string_view::npos || start.substr(i, 5) != "solid") {
    uint32_t n = 0;
    if (got == sizeof head) std::memcpy(&n, head + 80, 4);
    return InvalidArgument(path + ": not an ASCII STL (no \"solid\") and not a binary one: its header declares " +
                           std::to_string(n) + " triangles, which take " + std::to_string(84 + 50 * uint64_t{n}) +
                           " bytes, but the file has " + std::to_string(size) + " (truncated, or a wrong count)");
  }
  f.clear();
  f.seekg(0);
  std::string line;
  for (uint64_t n = 1; std::getline(f, line); ++n) {
    if ((n & 0xFFFF) == 0 && progress.Cancelled()) return Cancelled(path + ": interrupted while checking the mesh");
    std::istringstream in(line);
    std::string kw;
    if (!(in >> kw) || kw != "vertex") continue;
    for (int k = 0; k < 3; ++k) {
      std::string token;
      in >> token;
      char* end = nullptr;
      double v = std::strtod(token.c_str(), &end);
      if (token.empty() || end != token.c_str() + token.size() || !std::isfinite(v)) {
        return InvalidArgument(path + ":" + std::to_string(n) + ": vertex coordinate " + std::to_string(k + 1) +
                               " is \"" + token + "\", not a finite number; fix or remove the vertex");
      }
    }
  }
  return Status::Ok();
}

Result<TriangleMesh> LoadMeshFile(const std::string& path, const Progress& progress) {
  std::string ext = Lower(std::filesystem::path(path).extension().string());
  // Opening refuses a directory, FIFO or device by name (and never blocks on a FIFO).
  LTB_ASSIGN_OR_RETURN(MeshInput in, MeshInput::Open(path, &progress));
  Result<TriangleMesh> r = InvalidArgument(path + ": unknown mesh format");
  if (ext == ".off") {
    r = ReadOff(in, progress);
  } else if (ext == ".ply") {
    r = ReadPly(in, progress);
  } else {
    if (ext == ".obj") LTB_RETURN_IF_ERROR(CheckObjFile(path, progress));
    if (ext == ".stl") LTB_RETURN_IF_ERROR(CheckStlFile(path, progress));
    try {
      r = ext == ".drc" ? LoadDraco(path) : LoadOpenMesh(path);
    } catch (const std::bad_alloc&) {
      return InvalidArgument(path + ": reading the mesh ran out of memory (a corrupt count in the file?)");
    } catch (const std::exception& e) {
      return InvalidArgument(path + ": cannot read the mesh: " + e.what());
    }
  }
  if (!r.ok()) return r;
  TriangleMesh& m = *r;
  LTB_RETURN_IF_ERROR(CheckFinite(path, m));
  Finalize(&m);
  if (m.triangles.empty()) {
    return InvalidArgument(path + ": the mesh holds no triangles" +
                           (m.degenerate_dropped ? " (" + std::to_string(m.degenerate_dropped) + " degenerate ones dropped)"
                                                 : std::string()));
  }
  return r;
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

glm::dmat4 ObjectTransform(const Object& o) {
  glm::dmat4 m(1.0);
  m = glm::translate(m, o.translate);
  m = glm::rotate(m, glm::radians(o.rotate_degrees.z), glm::dvec3(0, 0, 1));
  m = glm::rotate(m, glm::radians(o.rotate_degrees.y), glm::dvec3(0, 1, 0));
  m = glm::rotate(m, glm::radians(o.rotate_degrees.x), glm::dvec3(1, 0, 0));
  m = glm::scale(m, o.scale);
  return m;
}

void ApplyTransform(const glm::dmat4& m, TriangleMesh* mesh) {
  for (auto& p : mesh->positions) p = glm::dvec3(m * glm::dvec4(p, 1.0));
  // A mirroring transform flips the winding; keep outward normals outward.
  if (glm::determinant(glm::dmat3(m)) < 0) {
    for (auto& t : mesh->triangles) std::swap(t[1], t[2]);
  }
  Finalize(mesh);
}

void Finalize(TriangleMesh* m) {
  std::vector<glm::uvec3> kept;
  kept.reserve(m->triangles.size());
  m->normals.assign(m->positions.size(), glm::dvec3(0));
  for (const auto& t : m->triangles) {
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
    kept.push_back(t);
  }
  m->triangles.swap(kept);
  for (auto& n : m->normals) {
    double len = glm::length(n);
    n = len > 0 ? n / len : glm::dvec3(0, 0, 1);
  }
}

}  // namespace ltb::sample
