// normals = "file": each reader returns the per-vertex normals a small hand-written file
// stores (PLY ascii and binary, OFF "NOFF", OBJ "f v//vn" with a vertex given two
// different normals, Draco encoded from a PLY by the draco_encoder CLI), normals follow
// the inverse transpose of a non-uniform scale (closed form), and every way of not having
// a normal is an error naming the file and the vertex; the scene key's bad values name
// the line, the value and what is accepted.
#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <glm/geometric.hpp>
#include <glm/gtc/matrix_transform.hpp>
#include <string>
#include <vector>

#include "stages/mesh/mesh_reader.h"
#include "stages/mesh/triangle_mesh.h"
#include "stages/sample/scene.h"
#include "stages/sample/scene_geometry.h"

namespace ltb::sample {
using namespace ::ltb::mesh;  // the readers under test (stages/mesh), placed by the scene code
namespace {

// A triangle with a stored normal per vertex, deliberately not unit length and not all equal.
const double kPos[3][3] = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}};
const double kNrm[3][3] = {{0, 0, 2}, {0, 3, 4}, {-1, 0, 1}};

glm::dvec3 Unit(const double* n) { return glm::normalize(glm::dvec3(n[0], n[1], n[2])); }

std::string Write(const std::string& name, const std::string& bytes) {
  std::string path = ::testing::TempDir() + "normals_" + std::to_string(::getpid()) + "_" + name;
  std::ofstream(path, std::ios::binary) << bytes;
  return path;
}

std::string PlyAscii(bool normals) {
  std::string s = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n";
  if (normals) s += "property float nx\nproperty float ny\nproperty float nz\n";
  s += "element face 1\nproperty list uchar int vertex_indices\nend_header\n";
  for (int i = 0; i < 3; ++i) {
    for (int c = 0; c < 3; ++c) s += std::to_string(kPos[i][c]) + " ";
    if (normals)
      for (int c = 0; c < 3; ++c) s += std::to_string(kNrm[i][c]) + " ";
    s += "\n";
  }
  return s + "3 0 1 2\n";
}

template <typename T>
void PutBinary(std::string* out, T v, bool big) {
  char b[sizeof(T)];
  std::memcpy(b, &v, sizeof(T));
  if (big) std::reverse(b, b + sizeof(T));
  out->append(b, sizeof(T));
}

// Binary: x y z as float, a uchar between, nx ny nz as double, so skipping and types matter.
std::string PlyBinary(bool big) {
  std::string s = std::string("ply\nformat ") + (big ? "binary_big_endian" : "binary_little_endian") +
                  " 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
                  "property uchar flag\nproperty double nx\nproperty double ny\nproperty double nz\n"
                  "element face 1\nproperty list uchar int vertex_indices\nend_header\n";
  for (int i = 0; i < 3; ++i) {
    for (int c = 0; c < 3; ++c) PutBinary(&s, static_cast<float>(kPos[i][c]), big);
    PutBinary(&s, uint8_t{7}, big);
    for (int c = 0; c < 3; ++c) PutBinary(&s, kNrm[i][c], big);
  }
  PutBinary(&s, uint8_t{3}, big);
  for (int32_t k = 0; k < 3; ++k) PutBinary(&s, k, big);
  return s;
}

void ExpectStored(const Result<TriangleMesh>& r, double tol = 0) {
  ASSERT_TRUE(r.ok()) << r.status().message();
  ASSERT_EQ(r->file_normals.size(), 3u);
  for (int i = 0; i < 3; ++i) {
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(r->file_normals[i][c], kNrm[i][c], tol) << "vertex " << i;
  }
}

TEST(FileNormals, PlyAsciiAndBinaryReturnTheStoredNormals) {
  // MeshInput reads bytes it does not own: they live in these strings.
  const std::string ascii = PlyAscii(true);
  {
    MeshInput in(ascii, "a.ply");
    ExpectStored(ReadPly(in, Progress{}, true));
  }
  for (bool big : {false, true}) {
    const std::string bytes = PlyBinary(big);
    MeshInput in(bytes, "b.ply");
    ExpectStored(ReadPly(in, Progress{}, true));
  }
  // Not asked for: not kept (the common path reads positions only).
  MeshInput in(ascii, "a.ply");
  auto r = ReadPly(in, Progress{});
  ASSERT_TRUE(r.ok());
  EXPECT_TRUE(r->file_normals.empty());
  // LoadMeshFile makes them unit length.
  auto f = LoadMeshFile(Write("a.ply", PlyBinary(false)), Progress{}, true);
  ASSERT_TRUE(f.ok()) << f.status().message();
  for (int i = 0; i < 3; ++i) EXPECT_NEAR(glm::length(f->file_normals[i] - Unit(kNrm[i])), 0, 1e-15);
}

TEST(FileNormals, NoffReturnsTheStoredNormals) {
  std::string s = "NOFF\n3 1 0\n";
  for (int i = 0; i < 3; ++i) {
    for (int c = 0; c < 3; ++c) s += std::to_string(kPos[i][c]) + " ";
    for (int c = 0; c < 3; ++c) s += std::to_string(kNrm[i][c]) + " ";
    s += "\n";
  }
  s += "3 0 1 2\n";
  MeshInput in(s, "n.off");
  ExpectStored(ReadOff(in, Progress{}, true));
  // A NOFF vertex line without its normal names the line and the vertex.
  MeshInput cut("NOFF\n3 1 0\n0 0 0 0 0 1\n1 0 0 0 0\n0 1 0 0 0 1\n3 0 1 2\n", "cut.off");
  auto r = ReadOff(cut, Progress{}, true);
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("cut.off:4: vertex 1 normal component 3 is missing"), std::string::npos)
      << r.status().message();
  // Plain OFF has none: LoadMeshFile says so.
  auto off = LoadMeshFile(Write("plain.off", "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n"), Progress{}, true);
  ASSERT_FALSE(off.ok());
  EXPECT_NE(off.status().message().find("stores no vertex normals"), std::string::npos) << off.status().message();
}

// A quad as two triangles; vertex 2 (1-based 3) is given normal a in the first face and b in
// the second; vertex 1 is given a in both faces (a normal repeated counts once).
TEST(FileNormals, ObjSumsTheDistinctNormalsOfAVertex) {
  const glm::dvec3 a(0, 0, 1), b(0, 3, 4), c(1, 0, 1);
  const std::string obj =
      "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n"
      "vn 0 0 1\nvn 0 3 4\nvn 1 0 1\n"
      "f 1//1 2//1 3//1\n"
      "f 1/5/1 3/6/2 4/7/-1\n";  // t indices need not exist; -1 counts back from the last vn
  MeshInput in(obj, "q.obj");
  auto r = ReadObj(in, Progress{}, true);
  ASSERT_TRUE(r.ok()) << r.status().message();
  ASSERT_EQ(r->file_normals.size(), 4u);
  const glm::dvec3 want[4] = {a, a, a + glm::normalize(b), glm::normalize(c)};
  for (int i = 0; i < 4; ++i) EXPECT_NEAR(glm::length(r->file_normals[i] - want[i]), 0, 1e-7) << "vertex " << i;
  auto f = LoadMeshFile(Write("q.obj", obj), Progress{}, true);
  ASSERT_TRUE(f.ok()) << f.status().message();
  EXPECT_NEAR(glm::length(f->file_normals[2] - glm::normalize(a + glm::normalize(b))), 0, 1e-7);
  // Without normals = "file", vn is skipped as before.
  MeshInput plain(obj, "q.obj");
  auto p = ReadObj(plain, Progress{});
  ASSERT_TRUE(p.ok());
  EXPECT_TRUE(p->file_normals.empty());
}

TEST(FileNormals, ObjErrorsNameTheFaceOrTheVertex) {
  MeshInput ahead("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1//1 2//1 3//1\nvn 0 0 1\n", "ahead.obj");
  auto r = ReadObj(ahead, Progress{}, true);
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("ahead.obj:4: face 0: normal index \"1\" (in \"1//1\") is out of range (0 vn"),
            std::string::npos)
      << r.status().message();
  MeshInput bad("v 0 0 0\nvn 0 zero 1\n", "bad.obj");
  r = ReadObj(bad, Progress{}, true);
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("bad.obj:2: normal 1 component 2 is \"zero\""), std::string::npos)
      << r.status().message();
  // Vertex 3 (0-based 3) is used by a face without a normal.
  auto f = LoadMeshFile(Write("part.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nvn 0 0 1\nf 1//1 2//1 3//1\nf 2 4 3\n"),
                        Progress{}, true);
  ASSERT_FALSE(f.ok());
  EXPECT_NE(f.status().message().find("part.obj: normals = \"file\": vertex 3 has normal [0, 0, 0], which is zero"),
            std::string::npos)
      << f.status().message();
}

TEST(FileNormals, ZeroOrNonFiniteNormalsAndStlAreErrorsNamingTheFile) {
  std::string zero = PlyAscii(true);
  zero.replace(zero.find("0.000000 3.000000 4.000000"), 26, "0 0 0");
  auto r = LoadMeshFile(Write("zero.ply", zero), Progress{}, true);
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("zero.ply: normals = \"file\": vertex 1 has normal [0, 0, 0], which is zero"),
            std::string::npos)
      << r.status().message();
  std::string nan = PlyAscii(true);
  nan.replace(nan.find("-1.000000"), 9, "nan");
  r = LoadMeshFile(Write("nan.ply", nan), Progress{}, true);
  ASSERT_FALSE(r.ok());
  EXPECT_NE(
      r.status().message().find("nan.ply: normals = \"file\": vertex 2 has normal [nan, 0, 1], which is not finite"),
      std::string::npos)
      << r.status().message();
  r = LoadMeshFile(Write("none.ply", PlyAscii(false)), Progress{}, true);
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("none.ply: normals = \"file\", but the file stores no vertex normals"),
            std::string::npos)
      << r.status().message();
  r = LoadMeshFile(Write("t.stl",
                         "solid t\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\nvertex 0 1 0\n"
                         "endloop\nendfacet\nendsolid t\n"),
                   Progress{}, true);
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("STL stores only facet normals"), std::string::npos) << r.status().message();
  EXPECT_NE(r.status().message().find("\"flat\""), std::string::npos);
  // Without normals = "file" every one of these loads.
  EXPECT_TRUE(LoadMeshFile(Write("zero.ply", zero)).ok());
  EXPECT_TRUE(LoadMeshFile(Write("none.ply", PlyAscii(false))).ok());
}

TEST(FileNormals, DracoNormalAttributeEncodedFromPly) {
  if (std::system("command -v draco_encoder >/dev/null 2>&1") != 0) {
    GTEST_SKIP() << "draco_encoder is not installed (Debian: draco-tools); the Draco normals case is not run";
  }
  const std::string ply = Write("d.ply", PlyAscii(true));
  const std::string drc = ::testing::TempDir() + "normals_" + std::to_string(::getpid()) + "_d.drc";
  std::remove(drc.c_str());
  // -cl 0 and default quantisation (11 bits positions, 8 bits normals): the decoder's
  // normals are octahedrally quantised, within ~1e-2 of the unit normals.
  const std::string cmd = "draco_encoder -i '" + ply + "' -o '" + drc + "' -cl 0 >/dev/null 2>&1";
  ASSERT_EQ(std::system(cmd.c_str()), 0) << cmd;
  auto r = LoadMeshFile(drc, Progress{}, true);
  ASSERT_TRUE(r.ok()) << r.status().message();
  ASSERT_EQ(r->file_normals.size(), 3u);
  // Draco may reorder the points: match each by its position.
  for (size_t i = 0; i < 3; ++i) {
    int k = -1;
    for (int j = 0; j < 3; ++j)
      if (glm::length(r->positions[i] - glm::dvec3(kPos[j][0], kPos[j][1], kPos[j][2])) < 1e-3) k = j;
    ASSERT_GE(k, 0) << "point " << i;
    EXPECT_NEAR(glm::length(r->file_normals[i] - Unit(kNrm[k])), 0, 2e-2) << "point " << i;
  }
  // Encoded without the normals: "file" is an error.
  const std::string bare = ::testing::TempDir() + "normals_" + std::to_string(::getpid()) + "_bare.drc";
  ASSERT_EQ(std::system(("draco_encoder -i '" + ply + "' -o '" + bare + "' -qn -1 >/dev/null 2>&1").c_str()), 0);
  auto b = LoadMeshFile(bare, Progress{}, true);
  ASSERT_FALSE(b.ok());
  EXPECT_NE(b.status().message().find("stores no vertex normals"), std::string::npos) << b.status().message();
}

// The plane z = x (unit normal (−1, 0, 1)/√2) scaled by (2, 1, 1) becomes z = x/2, whose
// unit normal is (−1, 0, 2)/√5; then rotated 90° about z and moved, (0, −1, 2)/√5.
TEST(FileNormals, TransformUsesTheInverseTranspose) {
  TriangleMesh m;
  m.positions = {{0, 0, 0}, {1, 0, 1}, {0, 1, 0}};
  m.triangles = {{0, 1, 2}};
  m.file_normals.assign(3, glm::normalize(glm::dvec3(-1, 0, 1)));
  Object o;
  o.scale = {2, 1, 1};
  ApplyTransform(ObjectTransform(o), &m);
  for (const auto& n : m.file_normals) EXPECT_NEAR(glm::length(n - glm::dvec3(-1, 0, 2) / std::sqrt(5.0)), 0, 1e-15);
  // Perpendicular to the transformed surface, unlike the naively scaled (−2, 0, 1).
  const glm::dvec3 e1 = m.positions[1] - m.positions[0], e2 = m.positions[2] - m.positions[0];
  EXPECT_NEAR(glm::dot(m.file_normals[0], e1), 0, 1e-15);
  EXPECT_NEAR(glm::dot(m.file_normals[0], e2), 0, 1e-15);

  TriangleMesh r;
  r.positions = {{0, 0, 0}, {1, 0, 1}, {0, 1, 0}};
  r.triangles = {{0, 1, 2}};
  r.file_normals.assign(3, glm::normalize(glm::dvec3(-1, 0, 1)));
  o.rotate_degrees = {0, 0, 90};
  o.translate = {5, 6, 7};
  ApplyTransform(ObjectTransform(o), &r);
  for (const auto& n : r.file_normals) EXPECT_NEAR(glm::length(n - glm::dvec3(0, -1, 2) / std::sqrt(5.0)), 0, 1e-15);
  // A mirror flips the stored normal with the surface: scale (−1, 1, 1) on +z stays +z,
  // on (1, 0, 0) gives (−1, 0, 0).
  TriangleMesh s;
  s.positions = {{0, 0, 0}, {0, 1, 0}, {0, 0, 1}};
  s.triangles = {{0, 1, 2}};
  s.file_normals.assign(3, glm::dvec3(1, 0, 0));
  Object mirror;
  mirror.scale = {-1, 1, 1};
  ApplyTransform(ObjectTransform(mirror), &s);
  for (const auto& n : s.file_normals) EXPECT_EQ(n, glm::dvec3(-1, 0, 0));
}

Result<SceneDesc> Scene(const std::string& name, const std::string& body) { return ParseScene(Write(name, body)); }

TEST(FileNormals, SceneKeyValuesAndErrors) {
  const std::string cam = "[camera]\neye = [0.0, 0.0, 5.0]\nup = [0.0, 1.0, 0.0]\n";
  const std::string mesh = "[[object]]\ntype = \"mesh\"\nfile = \"x.ply\"\n";
  auto s = Scene("ok.toml", cam + mesh + "normals = \"file\"\n" + "[[object]]\ntype = \"plane\"\nnormals = \"auto\"\n");
  ASSERT_TRUE(s.ok()) << s.status().message();
  EXPECT_EQ(s->objects[0].normals, Object::Normals::kFile);
  EXPECT_EQ(s->objects[1].normals, Object::Normals::kAuto);
  for (const auto& [v, want] :
       {std::pair{"smooth", Object::Normals::kSmooth}, std::pair{"flat", Object::Normals::kFlat}}) {
    auto t = Scene("v.toml", cam + mesh + "normals = \"" + v + "\"\n");
    ASSERT_TRUE(t.ok()) << t.status().message();
    EXPECT_EQ(t->objects[0].normals, want);
  }
  auto bad = Scene("bad.toml", cam + mesh + "normals = \"phong\"\n");
  ASSERT_FALSE(bad.ok());
  EXPECT_NE(bad.status().message().find("bad.toml:7"), std::string::npos) << bad.status().message();
  EXPECT_NE(bad.status().message().find("normals is \"phong\" (expected \"auto\", \"file\", \"smooth\" or \"flat\")"),
            std::string::npos)
      << bad.status().message();
  auto prim = Scene("prim.toml", cam + "[[object]]\ntype = \"box\"\nname = \"crate\"\nnormals = \"smooth\"\n");
  ASSERT_FALSE(prim.ok());
  EXPECT_NE(prim.status().message().find("prim.toml:7"), std::string::npos) << prim.status().message();
  EXPECT_NE(prim.status().message().find("object \"crate\": normals is \"smooth\"; a box takes only \"auto\""),
            std::string::npos)
      << prim.status().message();
  auto flat = Scene("flat.toml",
                    "[output]\nmode = \"vertex\"\n[[object]]\ntype = \"mesh\"\nname = \"bunny\"\n"
                    "file = \"x.ply\"\nnormals = \"flat\"\n");
  ASSERT_FALSE(flat.ok());
  EXPECT_NE(flat.status().message().find("object \"bunny\": normals is \"flat\": vertex mode has no single flat normal "
                                         "per vertex; use \"smooth\" or \"file\""),
            std::string::npos)
      << flat.status().message();
  auto type = Scene("type.toml", cam + mesh + "normals = 1\n");
  ASSERT_FALSE(type.ok());
  EXPECT_NE(type.status().message().find("\"normals\" is 1; it must be a string"), std::string::npos)
      << type.status().message();
}

}  // namespace
}  // namespace ltb::sample
