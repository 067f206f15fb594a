// Our OFF, PLY, OBJ and STL readers against meshes known in closed form: the unit cube
// written as OFF, as PLY in every encoding (ascii, binary little and big endian) with
// extra properties and assorted integer types, as OBJ (quads, negative indices, i/t/n
// references) and as ASCII and binary STL loads to the same 8 vertices and the same 12
// fan triangles, whose areas sum to 6 and whose signed volume is 1; hostile headers,
// lying counts, out-of-range indices and truncated bodies are errors naming the field.
// OBJ and STL are also compared with OpenMesh, which read them before (an independent
// reader): the same float positions and the same triangles in the same order.
// Vertex colours (colours = "file"): PLY uchar colours in every encoding and COFF / CNOFF
// colours against OpenMesh's vertex colours with the sRGB decode written out here; float
// PLY, ushort / char PLY, big-endian PLY, OBJ "v x y z r g b" and Draco COLOR attributes
// (encoded by libdraco here) against values known in closed form; and every way of lacking
// a colour or having a bad one is an error naming the file, the line or byte and the value.
#include "stages/mesh/mesh_reader.h"

#include <draco/compression/encode.h>
#include <draco/mesh/triangle_soup_mesh_builder.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <OpenMesh/Core/IO/MeshIO.hh>
#include <OpenMesh/Core/Mesh/TriMesh_ArrayKernelT.hh>
#include <array>
#include <bit>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <glm/geometric.hpp>
#include <string>
#include <vector>

#include "stages/mesh/triangle_mesh.h"
#include "stages/sample/scene_geometry.h"

namespace ltb::sample {
using namespace ::ltb::mesh;  // the readers under test (stages/mesh), placed by the scene code
namespace {

// The unit cube [0,1]³: vertex v has coordinates (v&1, v>>1&1, v>>2&1); six outward quads.
const int kQuads[6][4] = {{0, 2, 3, 1}, {4, 5, 7, 6}, {0, 1, 5, 4}, {2, 6, 7, 3}, {0, 4, 6, 2}, {1, 3, 7, 5}};

glm::dvec3 CubeVertex(int v) { return {double(v & 1), double((v >> 1) & 1), double((v >> 2) & 1)}; }

std::string CubeOff(const std::string& header = "OFF\n8 6 12\n") {
  std::string s = header;
  for (int v = 0; v < 8; ++v) {
    glm::dvec3 p = CubeVertex(v);
    s += std::to_string(int(p.x)) + " " + std::to_string(int(p.y)) + " " + std::to_string(int(p.z)) + "\n";
  }
  for (const auto& q : kQuads)
    s += "4 " + std::to_string(q[0]) + " " + std::to_string(q[1]) + " " + std::to_string(q[2]) + " " +
         std::to_string(q[3]) + "\n";
  return s;
}

template <typename T>
void Put(std::string* out, T v, bool big) {
  char b[sizeof(T)];
  std::memcpy(b, &v, sizeof(T));
  if (big) std::reverse(b, b + sizeof(T));
  out->append(b, sizeof(T));
}

// The cube as PLY: vertex (x y z as float, nx ny nz, a uchar colour), face (a float list
// "texcoord" before the index list, then a short flag); count/index types as given.
std::string CubePly(const std::string& format, const std::string& count_type, const std::string& index_type) {
  std::string s = "ply\nformat " + format +
                  " 1.0\ncomment the unit cube\nelement vertex 8\nproperty float x\n"
                  "property float y\nproperty float z\nproperty double nx\nproperty double ny\nproperty double nz\n"
                  "property uchar red\nelement face 6\nproperty list uchar float texcoord\nproperty list " +
                  count_type + " " + index_type + " vertex_indices\nproperty short flags\nend_header\n";
  const bool big = format == "binary_big_endian";
  for (int v = 0; v < 8; ++v) {
    glm::dvec3 p = CubeVertex(v);
    if (format == "ascii") {
      s += std::to_string(p.x) + " " + std::to_string(p.y) + " " + std::to_string(p.z) + " 0.5 0.5 0.5 200\n";
    } else {
      for (int c = 0; c < 3; ++c) Put(&s, float(p[c]), big);
      for (int c = 0; c < 3; ++c) Put(&s, 0.5, big);
      Put(&s, uint8_t{200}, big);
    }
  }
  for (const auto& q : kQuads) {
    if (format == "ascii") {
      s += "2 0.25 0.75 4 " + std::to_string(q[0]) + " " + std::to_string(q[1]) + " " + std::to_string(q[2]) + " " +
           std::to_string(q[3]) + " -7\n";
      continue;
    }
    Put(&s, uint8_t{2}, big);
    Put(&s, 0.25f, big);
    Put(&s, 0.75f, big);
    auto put_int = [&](const std::string& t, int64_t x) {
      if (t == "uchar")
        Put(&s, uint8_t(x), big);
      else if (t == "char")
        Put(&s, int8_t(x), big);
      else if (t == "ushort")
        Put(&s, uint16_t(x), big);
      else if (t == "short")
        Put(&s, int16_t(x), big);
      else if (t == "uint")
        Put(&s, uint32_t(x), big);
      else
        Put(&s, int32_t(x), big);
    };
    put_int(count_type, 4);
    for (int k = 0; k < 4; ++k) put_int(index_type, q[k]);
    Put(&s, int16_t{-7}, big);
  }
  return s;
}

Result<TriangleMesh> Off(const std::string& bytes) {
  MeshInput in(bytes, "test.off");
  return ReadOff(in, Progress{});
}
Result<TriangleMesh> Ply(const std::string& bytes) {
  MeshInput in(bytes, "test.ply");
  return ReadPly(in, Progress{});
}

// The cube exactly: 8 vertices in order, 12 triangles (the fan of each quad in order),
// area 6 and signed volume 1 (divergence theorem: Σ p0·(p1 × p2) / 6).
void ExpectCube(const Result<TriangleMesh>& r) {
  ASSERT_TRUE(r.ok()) << r.status().message();
  const TriangleMesh& m = *r;
  ASSERT_EQ(m.positions.size(), 8u);
  for (int v = 0; v < 8; ++v) EXPECT_EQ(m.positions[v], CubeVertex(v)) << "vertex " << v;
  ASSERT_EQ(m.triangles.size(), 12u);
  double area = 0, volume = 0;
  for (int f = 0; f < 6; ++f) {
    EXPECT_EQ(m.triangles[2 * f], glm::uvec3(kQuads[f][0], kQuads[f][1], kQuads[f][2])) << "face " << f;
    EXPECT_EQ(m.triangles[2 * f + 1], glm::uvec3(kQuads[f][0], kQuads[f][2], kQuads[f][3])) << "face " << f;
  }
  for (const auto& t : m.triangles) {
    glm::dvec3 a = m.positions[t[0]], b = m.positions[t[1]], c = m.positions[t[2]];
    area += glm::length(glm::cross(b - a, c - a)) / 2;
    volume += glm::dot(a, glm::cross(b, c)) / 6;
  }
  EXPECT_DOUBLE_EQ(area, 6.0);
  EXPECT_DOUBLE_EQ(volume, 1.0);
  EXPECT_EQ(m.degenerate_dropped, 0u);
}

void ExpectError(const Result<TriangleMesh>& r, std::initializer_list<const char*> parts) {
  ASSERT_FALSE(r.ok());
  for (const char* p : parts) EXPECT_NE(r.status().message().find(p), std::string::npos) << r.status().message();
}

TEST(MeshReader, OffCubeIsTwelveFanTriangles) { ExpectCube(Off(CubeOff())); }

TEST(MeshReader, OffAcceptsCommentsCrlfCountsOnTheHeaderLineAndColours) {
  std::string s = CubeOff("# a cube\nCOFF 8 6 12 # counts here\n\n");
  std::string crlf;
  for (char c : s) crlf += c == '\n' ? std::string("\r\n") : std::string(1, c);
  ExpectCube(Off(crlf));
}

TEST(MeshReader, PlyCubeInEveryEncodingAndIntegerType) {
  for (const char* format : {"ascii", "binary_little_endian", "binary_big_endian"}) {
    for (auto [ct, it] :
         {std::pair{"uchar", "int"}, {"ushort", "uint"}, {"char", "short"}, {"uint", "uchar"}, {"int", "ushort"}}) {
      SCOPED_TRACE(std::string(format) + " " + ct + " " + it);
      ExpectCube(Ply(CubePly(format, ct, it)));
    }
  }
}

TEST(MeshReader, PlyDoubleCoordinatesAreRoundedToFloatOnce) {
  std::string s =
      "ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty double x\nproperty double y\n"
      "property double z\nelement face 1\nproperty list uchar int vertex_index\nend_header\n";
  for (double v : {0.1, 0.0, 0.0, 1.0, 1e-3, 0.0, 0.0, 1.0, 1.0 / 3}) Put(&s, v, false);
  Put(&s, uint8_t{3}, false);
  for (int32_t i : {0, 1, 2}) Put(&s, i, false);
  auto r = Ply(s);
  ASSERT_TRUE(r.ok()) << r.status().message();
  EXPECT_EQ(r->positions[0].x, double(0.1f));
  EXPECT_EQ(r->positions[1].y, double(1e-3f));
  EXPECT_EQ(r->positions[2].z, double(1.0f / 3));
  EXPECT_EQ(r->triangles.size(), 1u);
}

TEST(MeshReader, PentagonIsAFanAndDegenerateFacesAreCounted) {
  auto r = Off("OFF\n5 4 0\n0 0 0\n1 0 0\n2 1 0\n1 2 0\n0 1 0\n5 0 1 2 3 4\n3 0 0 1\n2 0 1\n4 0 1 2 1\n");
  ASSERT_TRUE(r.ok()) << r.status().message();
  std::vector<glm::uvec3> want = {{0, 1, 2}, {0, 2, 3}, {0, 3, 4}};
  EXPECT_EQ(r->triangles, want);
  EXPECT_EQ(r->degenerate_dropped, 3u);  // a repeated vertex (twice) and a 2-vertex face
}

TEST(MeshReader, OutOfRangeIndexNamesTheFaceAndTheIndex) {
  ExpectError(Off("OFF\n3 2 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n3 0 1 3\n"),
              {"test.off:7", "face 1", "vertex index 3", "out of range", "0..2"});
  std::string ply =
      "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
      "element face 2\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n"
      "3 0 1 2\n3 0 -1 2\n";
  ExpectError(Ply(ply), {"test.ply:14", "face 1", "vertex index -1", "out of range"});
  std::string bin = CubePly("binary_little_endian", "uchar", "int");
  // The last index of the last face (before its 2-byte flag) becomes 8.
  int32_t eight = 8;
  std::memcpy(&bin[bin.size() - 2 - 4], &eight, 4);
  ExpectError(Ply(bin), {"face 5", "vertex index 8", "out of range"});
}

TEST(MeshReader, HeadersDeclaringMoreThanTheFileHoldsAreRefusedBeforeAllocating) {
  ExpectError(Off("OFF\n50000000 1 0\n0 0 0\n"), {"test.off:2", "50000000 vertices", "need at least"});
  ExpectError(Off("OFF\n4000000000 1 0\n"), {"4000000000 vertices", "need at least 24000000002 bytes"});
  ExpectError(Off("OFF\n5000000000 1 0\n"), {"5000000000 vertices", "at most 4294967295"});
  ExpectError(Off("OFF\n3 18446744073709551615 0\n0 0 0\n"), {"18446744073709551615 faces", "more than 2^64"});
  ExpectError(
      Ply("ply\nformat binary_little_endian 1.0\nelement vertex 1000000000\nproperty float x\nproperty float y\n"
          "property float z\nend_header\n"),
      {"1000000000 vertex", "need at least 12000000000 bytes"});
}

TEST(MeshReader, LyingListCountsAndTruncatedBodiesAreErrors) {
  std::string s = CubePly("binary_little_endian", "uchar", "int");
  std::string lie = s;
  // Face 5's index count (after its texcoord list of 1 + 8 bytes) becomes 255.
  lie[lie.size() - 2 - 16 - 1] = char(255);
  ExpectError(Ply(lie), {"face 5 declares 255 vertices", "truncated"});
  ExpectError(Ply(s.substr(0, s.size() - 30)), {"test.ply", "truncated"});
  ExpectError(Off("OFF\n3 1 0\n0 0 0\n# padding padding padding padding padding\n"),
              {"ends after 1 of the 3 vertices"});
  ExpectError(Off("OFF\n3 1 0\n0 0 0\n1 0\n0 1 0\n3 0 1 2\n"), {"test.off:4", "vertex 1 has fewer than 3"});
}

TEST(MeshReader, NonFiniteAndMalformedValuesNameTheVertex) {
  ExpectError(Off("OFF\n3 1 0\n0 0 0\n1 nan 0\n0 1 0\n3 0 1 2\n"), {"test.off:4", "vertex 1", "\"nan\""});
  ExpectError(Off("OFF\n3 1 0\n0 0 0\n1 1e999 0\n0 1 0\n3 0 1 2\n"), {"vertex 1", "1e999"});
  std::string s =
      "ply\nformat binary_little_endian 1.0\nelement vertex 1\nproperty float x\nproperty float y\n"
      "property float z\nend_header\n";
  Put(&s, 0.0f, false);
  Put(&s, std::numeric_limits<float>::infinity(), false);
  Put(&s, 0.0f, false);
  ExpectError(Ply(s), {"vertex 0 y", "not a finite"});
  ExpectError(Ply("ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\n"
                  "end_header\n0 zero 0\n"),
              {"test.ply:8", "\"zero\""});
  ExpectError(Ply("ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nend_header\n0 0\n"),
              {"no \"z\" property"});
  ExpectError(Ply("ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\n"), {"no \"end_header\""});
  ExpectError(Ply("ply\nformat utf8 1.0\nend_header\n"), {"test.ply:2", "format \"utf8\""});
  ExpectError(Ply("ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\nproperty float y\nproperty float z\n"
                  "element face 0\nproperty list uchar float vertex_indices\nend_header\n"),
              {"integer item type"});
  ExpectError(Off("OFF BINARY\n"), {"binary OFF is not supported"});
  ExpectError(Off(""), {"empty file"});
}

TEST(MeshReader, ElementsWithoutPropertiesCostNothingWhateverTheyDeclare) {
  std::string s = CubePly("ascii", "uchar", "int");
  s.insert(s.find("end_header"), "element junk 4000000000\n");
  ExpectCube(Ply(s));
}

// ---- OBJ ----

Result<TriangleMesh> Obj(const std::string& bytes) {
  MeshInput in(bytes, "test.obj");
  return ReadObj(in, Progress{});
}
Result<TriangleMesh> Stl(const std::string& bytes) {
  MeshInput in(bytes, "test.stl");
  return ReadStl(in, Progress{});
}

// The cube as OBJ: the 8 vertices (with a w), then the quads with every reference form
// (i, i/t, i//n, i/t/n) and negative indices counting back from the last vertex read, and
// the statements a reader skips (comments, vt, vn, o, g, s, usemtl, mtllib, l).
std::string CubeObj() {
  std::string s = "# the unit cube\nmtllib cube.mtl\no cube\ng faces\n";
  for (int v = 0; v < 8; ++v) {
    glm::dvec3 p = CubeVertex(v);
    s += "v " + std::to_string(int(p.x)) + " " + std::to_string(int(p.y)) + " " + std::to_string(int(p.z)) + " 1.0\n";
  }
  s += "vt 0 0\nvt 1 0\nvn 0 0 1\ns 1\nusemtl grey\nl 1 2\n";
  const char* forms[4] = {"%d", "%d/1", "%d//1", "%d/2/1"};
  for (int f = 0; f < 6; ++f) {
    s += "f";
    for (int k = 0; k < 4; ++k) {
      // Alternate 1-based and negative (-8 is the first vertex) references.
      int index = (f + k) % 2 == 0 ? kQuads[f][k] + 1 : kQuads[f][k] - 8;
      char buf[32];
      std::snprintf(buf, sizeof buf, forms[(f + k) % 4], index);
      s += std::string(" ") + buf;
    }
    s += f == 2 ? " # a trailing comment\n" : "\n";
  }
  return s;
}

TEST(MeshReader, ObjCubeWithQuadsNegativeIndicesAndEveryReferenceForm) { ExpectCube(Obj(CubeObj())); }

TEST(MeshReader, ObjCrlfLineContinuationsAndFacesBeforeTheirVertices) {
  std::string s = CubeObj();
  // Continue the first face over two lines, and move all faces before the vertices (the
  // faces then use 1-based indices only, negative ones would count back from nothing).
  std::string faces, rest;
  for (int f = 0; f < 6; ++f) {
    faces += "f";
    for (int k = 0; k < 4; ++k) faces += (f == 0 && k == 2 ? " \\\r\n  " : " ") + std::to_string(kQuads[f][k] + 1);
    faces += "\r\n";
  }
  for (int v = 0; v < 8; ++v) {
    glm::dvec3 p = CubeVertex(v);
    rest += "v " + std::to_string(int(p.x)) + " " + std::to_string(int(p.y)) + " " + std::to_string(int(p.z)) + "\r\n";
  }
  ExpectCube(Obj(faces + rest));
}

TEST(MeshReader, ObjPolygonIsAFanRepeatsAreRemovedAndDegenerateFacesCounted) {
  auto r =
      Obj("v 0 0 0\nv 1 0 0\nv 2 1 0\nv 1 2 0\nv 0 1 0\n"
          "f 1 2 3 4 5\n"  // a pentagon: 3 fan triangles
          "f 1 2 2 3\n"    // a quad with a repeated corner: the triangle 1 2 3 (OpenMesh did the same)
          "f 1 1 2\n");    // 2 distinct vertices: dropped, counted
  ASSERT_TRUE(r.ok()) << r.status().message();
  std::vector<glm::uvec3> want = {{0, 1, 2}, {0, 2, 3}, {0, 3, 4}, {0, 1, 2}};
  EXPECT_EQ(r->triangles, want);
  EXPECT_EQ(r->degenerate_dropped, 1u);
}

TEST(MeshReader, ObjVertexPositionsAreRoundedToFloatOnce) {
  auto r = Obj("v 0.1 1e-3 0.333333333333333333333\nv +1 -2.5e+1 .5\nv 3 0 0\nf 1 2 3\n");
  ASSERT_TRUE(r.ok()) << r.status().message();
  EXPECT_EQ(r->positions[0], glm::dvec3(0.1f, 1e-3f, 1.0f / 3));
  EXPECT_EQ(r->positions[1], glm::dvec3(1, -25, 0.5));
}

TEST(MeshReader, ObjBadReferencesNameTheLineTheFaceAndTheValue) {
  const std::string v3 = "v 0 0 0\nv 1 0 0\nv 0 1 0\n";
  // The fuzzer's find: a reference with no vertex index (OpenMesh asserted on it).
  ExpectError(Obj("f /4"), {"test.obj:1", "face 0", "\"/4\"", "malformed"});
  ExpectError(Obj(v3 + "f 1 2 3\nf /4\n"), {"test.obj:5", "face 1", "\"/4\"", "malformed"});
  ExpectError(Obj(v3 + "f 1/x 2 3\n"), {"test.obj:4", "\"1/x\"", "malformed"});
  ExpectError(Obj(v3 + "f 1/2/3/4 2 3\n"), {"test.obj:4", "\"1/2/3/4\"", "malformed"});
  ExpectError(Obj(v3 + "f one 2 3\n"), {"test.obj:4", "vertex index \"one\"", "not an integer"});
  ExpectError(Obj(v3 + "f 1 2\n"), {"test.obj:4", "face 0 lists 2 vertices", "at least 3"});
  ExpectError(Obj(v3 + "f\n"), {"test.obj:4", "face 0 lists 0 vertices"});
  ExpectError(Obj(v3 + "f 0 1 2\n"), {"test.obj:4", "vertex index \"0\"", "out of range", "0 is never valid"});
  ExpectError(Obj(v3 + "f -4 1 2\n"), {"test.obj:4", "vertex index \"-4\"", "3 vertices so far"});
  ExpectError(Obj(v3 + "f 1 2 3\nf 1 2 99\n"), {"test.obj:5", "face 1", "vertex index \"99\"", "out of range"});
  // A forward index the rest of the file could define is checked at the end.
  ExpectError(Obj(v3 + "f 1 2 4\n# room for one more vertex: v 1 1 1\n"),
              {"test.obj:4", "face 0", "vertex index \"4\"", "the file has 3 vertices"});
  ExpectError(Obj(v3 + "f 1 2 99999999999999999999\n"), {"vertex index \"99999999999999999999\""});
  ExpectError(Obj(v3 + "f 1 2 -99999999999999999999\n"), {"vertex index \"-99999999999999999999\""});
}

TEST(MeshReader, ObjNonFiniteAndMissingCoordinatesNameTheVertex) {
  ExpectError(Obj("v 0 0 0\nv 1 0 nan\nv 0 1 0\nf 1 2 3\n"),
              {"test.obj:2", "vertex coordinate 3 is \"nan\"", "vertex 2"});
  ExpectError(Obj("v 0 0 0\nv 1 inf 0\n"), {"test.obj:2", "\"inf\""});
  ExpectError(Obj("v 0 0 1e999\n"), {"test.obj:1", "\"1e999\""});
  ExpectError(Obj("v 0 0 0\nv 1 0\n"), {"test.obj:2", "vertex 2 has fewer than 3 coordinates"});
  ExpectError(Obj("v 0 0 0,5\n"), {"test.obj:1", "\"0,5\""});
}

TEST(MeshReader, ObjContinuationJoinsTheNextLine) {
  auto r = Obj("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 \\\n3\n");
  ASSERT_TRUE(r.ok()) << r.status().message();
  EXPECT_EQ(r->triangles.size(), 1u);
}

// ---- STL ----

// The cube's 12 fan triangles as STL facets (positions, no indices).
std::vector<std::array<glm::vec3, 3>> CubeFacets() {
  std::vector<std::array<glm::vec3, 3>> out;
  for (const auto& q : kQuads) {
    for (int i = 1; i <= 2; ++i) {
      out.push_back({glm::vec3(CubeVertex(q[0])), glm::vec3(CubeVertex(q[i])), glm::vec3(CubeVertex(q[i + 1]))});
    }
  }
  return out;
}

std::string CubeStlAscii() {
  std::string s = "solid cube exported by hand\n";
  for (const auto& t : CubeFacets()) {
    s += "  facet normal 0 0 0\n    outer loop\n";
    for (const auto& p : t) {
      s += "      vertex " + std::to_string(p.x) + " " + std::to_string(p.y) + " " + std::to_string(p.z) + "\n";
    }
    s += "    endloop\n  endfacet\n";
  }
  return s + "endsolid cube exported by hand\n";
}

std::string CubeStlBinary(const std::string& header = "binary cube") {
  std::string s = header;
  s.resize(80, ' ');
  Put(&s, uint32_t(12), false);
  for (const auto& t : CubeFacets()) {
    for (int c = 0; c < 3; ++c) Put(&s, 0.0f, false);  // normal
    for (const auto& p : t)
      for (int c = 0; c < 3; ++c) Put(&s, p[c], false);
    Put(&s, uint16_t(0), false);  // attribute byte count
  }
  return s;
}

// STL's vertices are the distinct positions in order of first appearance; the triangles
// are the cube's, corner for corner.
void ExpectStlCube(const Result<TriangleMesh>& r) {
  ASSERT_TRUE(r.ok()) << r.status().message();
  const TriangleMesh& m = *r;
  ASSERT_EQ(m.positions.size(), 8u);
  ASSERT_EQ(m.triangles.size(), 12u);
  auto facets = CubeFacets();
  double area = 0, volume = 0;
  for (size_t i = 0; i < 12; ++i) {
    for (int k = 0; k < 3; ++k) {
      EXPECT_EQ(m.positions[m.triangles[i][k]], glm::dvec3(facets[i][k])) << "triangle " << i << " corner " << k;
    }
    glm::dvec3 a = m.positions[m.triangles[i][0]], b = m.positions[m.triangles[i][1]],
               c = m.positions[m.triangles[i][2]];
    area += glm::length(glm::cross(b - a, c - a)) / 2;
    volume += glm::dot(a, glm::cross(b, c)) / 6;
  }
  // First appearance: the first facet's corners are vertices 0, 1, 2.
  EXPECT_EQ(m.triangles[0], glm::uvec3(0, 1, 2));
  EXPECT_DOUBLE_EQ(area, 6.0);
  EXPECT_DOUBLE_EQ(volume, 1.0);
  EXPECT_EQ(m.degenerate_dropped, 0u);
}

TEST(MeshReader, StlCubeAsciiAndBinary) {
  ExpectStlCube(Stl(CubeStlAscii()));
  ExpectStlCube(Stl(CubeStlBinary()));
  // Many binary writers start the header with "solid": the length decides.
  ExpectStlCube(Stl(CubeStlBinary("solid cube, but binary")));
}

TEST(MeshReader, StlAsciiAcceptsAnyLayoutAnyCaseAndSeveralSolids) {
  // After the solid's name line: everything on one line, in upper case, the first
  // vertex's x written as -0 (merged with the 0 of later corners), then a second solid.
  std::string s = CubeStlAscii();
  std::string body = s.substr(s.find('\n') + 1);
  for (char& c : body) c = c == '\n' ? ' ' : char(std::toupper(static_cast<unsigned char>(c)));
  body.replace(body.find("0.000000"), 8, "-0.0");
  ExpectStlCube(Stl("solid cube\n" + body + "\nsolid empty\nendsolid\n"));
}

TEST(MeshReader, StlDegenerateFacetsAreCounted) {
  std::string s =
      "solid d\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\nvertex 0 1 0\nendloop\nendfacet\n"
      "facet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\nvertex 0 0 -0\nendloop\nendfacet\n"
      "endsolid d\n";
  auto r = Stl(s);
  ASSERT_TRUE(r.ok()) << r.status().message();
  EXPECT_EQ(r->triangles.size(), 1u);
  EXPECT_EQ(r->positions.size(), 3u);
  EXPECT_EQ(r->degenerate_dropped, 1u);
}

TEST(MeshReader, StlHostileInputsAreErrorsNamingTheField) {
  // A binary count the file cannot hold (and no "solid"): both numbers named.
  std::string lie = CubeStlBinary();
  uint32_t huge = 4000000000u;
  std::memcpy(&lie[80], &huge, 4);
  ExpectError(Stl(lie), {"declares 4000000000 triangles", "200000000084 bytes", "the file has 684"});
  // A truncated binary file.
  std::string bin = CubeStlBinary();
  ExpectError(Stl(bin.substr(0, bin.size() - 7)), {"declares 12 triangles", "the file has 677"});
  // The same, when its header starts with "solid": read as ASCII, the error says both.
  std::string sbin = CubeStlBinary("solid but binary");
  ExpectError(Stl(sbin.substr(0, sbin.size() - 7)),
              {"test.stl", "before \"endsolid\"", "read as binary", "declares 12 triangles"});
  ExpectError(Stl("junk"), {"too short for a binary one"});
  ExpectError(Stl(""), {"too short"});
  std::string ascii = CubeStlAscii();
  ExpectError(Stl(ascii.substr(0, ascii.size() / 2)), {"test.stl", "the file ends", "truncated"});
  ExpectError(Stl(ascii.substr(0, ascii.find("endsolid"))), {"before \"endsolid\""});
  std::string nan = ascii;
  nan.replace(nan.find("vertex 0.000000 0.000000 0.000000") + 7, 8, "nan");
  ExpectError(Stl(nan), {"test.stl:4", "facet 0 vertex 0 coordinate 1 is \"nan\""});
  std::string four = ascii;
  four.insert(four.find("endloop"), "vertex 1 1 1\n");
  ExpectError(Stl(four), {"test.stl:7", "expected \"endloop\"", "exactly 3 vertices", "\"vertex\""});
  std::string binf = CubeStlBinary();
  float inf = std::numeric_limits<float>::infinity();
  std::memcpy(&binf[84 + 50 * 3 + 12 + 12 * 2 + 4], &inf, 4);
  ExpectError(Stl(binf), {"test.stl (byte 274)", "triangle 3 vertex 2 y", "not a finite"});
}

// ---- OBJ and STL against OpenMesh ----

using OmMesh = OpenMesh::TriMesh_ArrayKernelT<>;

// Reads `path` with OpenMesh: positions (float, as it stores them) and the faces' vertex
// ids in face order.
void ReadWithOpenMesh(const std::string& path, std::vector<glm::dvec3>* positions, std::vector<glm::uvec3>* triangles) {
  OmMesh mesh;
  OpenMesh::IO::Options opt;
  ASSERT_TRUE(OpenMesh::IO::read_mesh(mesh, path, opt)) << path;
  for (auto v : mesh.vertices()) {
    auto p = mesh.point(v);
    positions->push_back({p[0], p[1], p[2]});
  }
  for (auto f : mesh.faces()) {
    std::vector<unsigned> ids;
    for (auto v : mesh.fv_range(f)) ids.push_back(static_cast<unsigned>(v.idx()));
    ASSERT_EQ(ids.size(), 3u);
    triangles->push_back({ids[0], ids[1], ids[2]});
  }
}

void ExpectSameAsOpenMesh(const std::string& path) {
  SCOPED_TRACE(path);
  std::vector<glm::dvec3> positions;
  std::vector<glm::uvec3> triangles;
  ReadWithOpenMesh(path, &positions, &triangles);
  auto in = MeshInput::Open(path, nullptr);
  ASSERT_TRUE(in.ok()) << in.status().message();
  const bool stl = path.ends_with(".stl");
  auto r = stl ? ReadStl(*in, Progress{}) : ReadObj(*in, Progress{});
  ASSERT_TRUE(r.ok()) << r.status().message();
  ASSERT_GT(triangles.size(), 0u);
  EXPECT_EQ(r->positions, positions);  // exactly: the same float for every coordinate
  EXPECT_EQ(r->triangles, triangles);
}

class MeshFile : public ::testing::Test {
 protected:
  std::string Write(const std::string& name, const std::string& bytes) {
    std::string path = ::testing::TempDir() + "/ltb_mesh_reader_" + std::to_string(::getpid()) + "_" + name;
    std::ofstream(path, std::ios::binary) << bytes;
    paths_.push_back(path);
    return path;
  }
  void TearDown() override {
    for (const auto& p : paths_) ::unlink(p.c_str());
  }
  std::vector<std::string> paths_;
};

// A grid larger than the 1 MiB read piece, so lines straddle refills: the file reads to
// exactly what the same bytes in memory give.
std::string GridOff(int w) {
  std::string s = "OFF\n" + std::to_string(w * w) + " " + std::to_string(2 * (w - 1) * (w - 1)) + " 0\n";
  for (int y = 0; y < w; ++y)
    for (int x = 0; x < w; ++x) s += std::to_string(x * 0.001) + " " + std::to_string(y * 0.001) + " 0.125\n";
  for (int y = 0; y + 1 < w; ++y)
    for (int x = 0; x + 1 < w; ++x) {
      int a = y * w + x;
      s += "3 " + std::to_string(a) + " " + std::to_string(a + 1) + " " + std::to_string(a + w + 1) + "\n";
      s += "3 " + std::to_string(a) + " " + std::to_string(a + w + 1) + " " + std::to_string(a + w) + "\n";
    }
  return s;
}

TEST_F(MeshFile, FileReadsLikeMemoryAcrossPieces) {
  std::string bytes = GridOff(300);
  ASSERT_GT(bytes.size(), size_t{3} << 20);
  auto mem = Off(bytes);
  ASSERT_TRUE(mem.ok()) << mem.status().message();
  auto file = LoadMeshFile(Write("grid.off", bytes));
  ASSERT_TRUE(file.ok()) << file.status().message();
  EXPECT_EQ(file->positions, mem->positions);
  EXPECT_EQ(file->triangles, mem->triangles);
  EXPECT_EQ(file->triangles.size(), 2u * 299 * 299);
}

TEST_F(MeshFile, CancelStopsReading) {
  std::string path = Write("grid.off", GridOff(300));
  Progress p;
  p.cancelled = [] { return true; };
  auto r = LoadMeshFile(path, p);
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.status().code(), StatusCode::kCancelled);
  EXPECT_NE(r.status().message().find("interrupted while reading the mesh"), std::string::npos);
}

TEST_F(MeshFile, DirectoriesAndDevicesAreRefusedByName) {
  auto r = LoadMeshFile(::testing::TempDir());
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("is a directory"), std::string::npos) << r.status().message();
  r = LoadMeshFile("/dev/null");
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("character device"), std::string::npos) << r.status().message();
}

// A w×w grid of quads as OBJ, larger than the 1 MiB read piece: coordinates with 9
// significant digits (not floats: each is rounded), references alternating i/t/n and
// negative, and (unless `continued` is false) every tenth face continued over two lines.
std::string GridObj(int w, bool continued = true) {
  std::string s = "# grid\n";
  uint64_t x = 12345;
  char buf[96];
  for (int y = 0; y < w; ++y) {
    for (int i = 0; i < w; ++i) {
      x = x * 6364136223846793005ull + 1442695040888963407ull;
      std::snprintf(buf, sizeof buf, "v %.9g %.9g %.9g\n", i * 0.01 + 1e-3 * double(x >> 40) / (1 << 24),
                    y * 0.01 + 1e-3 * double((x >> 16) & 0xFFFFFF) / (1 << 24), double(x >> 11) / (1ull << 53));
      s += buf;
    }
  }
  s += "vt 0 0\nvn 0 0 1\n";
  const int n = w * w;
  for (int y = 0; y + 1 < w; ++y) {
    for (int i = 0; i + 1 < w; ++i) {
      int a = y * w + i + 1;  // 1-based
      int c[4] = {a, a + 1, a + w + 1, a + w};
      std::snprintf(buf, sizeof buf, "f %d/1/1 %d %s%d//1 %d\n", c[0], c[1] - n - 1,
                    continued && (y * w + i) % 10 == 0 ? "\\\n " : "", c[2], c[3] - n - 1);
      s += buf;
    }
  }
  return s;
}

TEST_F(MeshFile, ObjFileReadsLikeMemoryAcrossPieces) {
  std::string bytes = GridObj(200);
  ASSERT_GT(bytes.size(), size_t{2} << 20);
  auto mem = Obj(bytes);
  ASSERT_TRUE(mem.ok()) << mem.status().message();
  auto file = LoadMeshFile(Write("grid.obj", bytes));
  ASSERT_TRUE(file.ok()) << file.status().message();
  EXPECT_EQ(file->positions, mem->positions);
  EXPECT_EQ(file->triangles, mem->triangles);
  EXPECT_EQ(file->triangles.size(), 2u * 199 * 199);
}

TEST_F(MeshFile, CancelStopsReadingObjAndStl) {
  Progress p;
  p.cancelled = [] { return true; };
  std::string stl;
  for (int i = 0; i < 3000; ++i) stl += CubeStlAscii();  // several solids, > 1 MiB
  for (const std::string& path : {Write("grid.obj", GridObj(200)), Write("cubes.stl", stl)}) {
    auto r = LoadMeshFile(path, p);
    ASSERT_FALSE(r.ok()) << path;
    EXPECT_EQ(r.status().code(), StatusCode::kCancelled) << r.status().message();
    EXPECT_NE(r.status().message().find("interrupted while reading the mesh"), std::string::npos);
  }
}

TEST_F(MeshFile, ObjAndStlReadLikeOpenMesh) {
  ExpectSameAsOpenMesh(Write("cube.obj", CubeObj()));
  // Without continuation lines: OpenMesh does not join them (it dropped such a face).
  ExpectSameAsOpenMesh(Write("grid.obj", GridObj(60, false)));
  ExpectSameAsOpenMesh(Write("cube_ascii.stl", CubeStlAscii()));
  ExpectSameAsOpenMesh(Write("cube_binary.stl", CubeStlBinary("solid, yet binary")));
  // The grid as STL, both encodings: shared corners merge in order of first appearance.
  auto grid = Obj(GridObj(60));
  ASSERT_TRUE(grid.ok()) << grid.status().message();
  std::string ascii = "solid grid\n", binary(80, ' ');
  Put(&binary, uint32_t(grid->triangles.size()), false);
  for (const auto& t : grid->triangles) {
    ascii += "facet normal 0 0 1\nouter loop\n";
    for (int c = 0; c < 3; ++c) Put(&binary, 0.0f, false);
    for (int k = 0; k < 3; ++k) {
      glm::vec3 p(grid->positions[t[k]]);
      char buf[96];
      std::snprintf(buf, sizeof buf, "vertex %.9g %.9g %.9g\n", p.x, p.y, p.z);
      ascii += buf;
      for (int c = 0; c < 3; ++c) Put(&binary, p[c], false);
    }
    ascii += "endloop\nendfacet\n";
    Put(&binary, uint16_t(0), false);
  }
  ExpectSameAsOpenMesh(Write("grid_ascii.stl", ascii + "endsolid grid\n"));
  ExpectSameAsOpenMesh(Write("grid_binary.stl", binary));
}

// ---- Vertex colours ----

// The sRGB EOTF, written out independently of the reader's.
double Srgb8(int c) {
  const double x = c / 255.0;
  if (x <= 0.04045) return x / 12.92;
  return std::pow((x + 0.055) / 1.055, 2.4);
}

// The cube's vertex v gets a distinct 8-bit colour, including values on the linear
// segment of the sRGB curve (0, 5, 10) and both ends.
std::array<int, 3> CubeColour(int v) { return {v * 36, 255 - v * 30, v < 3 ? v * 5 : 100 + v}; }

const double kTriangle[3][3] = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}};

TEST(MeshReader, SrgbDecodeKnownValues) {
  EXPECT_EQ(SrgbToLinear(0), 0.0);
  EXPECT_EQ(SrgbToLinear(1), 1.0);
  EXPECT_DOUBLE_EQ(SrgbToLinear(0.04045), 0.04045 / 12.92);            // the linear segment's end
  EXPECT_NEAR(SrgbToLinear(128 / 255.0), 0.21586050011389926, 1e-15);  // the published 8-bit table
  EXPECT_NEAR(SrgbToLinear(0.5), 0.21404114048223255, 1e-15);
  EXPECT_DOUBLE_EQ(SrgbToLinear(10 / 255.0), 10 / 255.0 / 12.92);
  for (int c = 0; c < 256; ++c) EXPECT_NEAR(SrgbToLinear(c / 255.0), Srgb8(c), 1e-15) << c;
}

Result<TriangleMesh> PlyColours(const std::string& bytes) {
  MeshInput in(bytes, "test.ply");
  return ReadPly(in, Progress{}, false, true);
}
Result<TriangleMesh> OffColours(const std::string& bytes, bool normals = false) {
  MeshInput in(bytes, "test.off");
  return ReadOff(in, Progress{}, normals, true);
}
Result<TriangleMesh> ObjColours(const std::string& bytes, bool normals = false) {
  MeshInput in(bytes, "test.obj");
  return ReadObj(in, Progress{}, normals, true);
}

// The cube as PLY with uchar red green blue alpha vertex properties (CubeColour), x y z
// float, in the given encoding.
std::string ColourCubePly(const std::string& format) {
  std::string s = "ply\nformat " + format +
                  " 1.0\nelement vertex 8\nproperty float x\nproperty float y\nproperty float z\n"
                  "property uchar red\nproperty uchar green\nproperty uchar blue\nproperty uchar alpha\n"
                  "element face 6\nproperty list uchar int vertex_indices\nend_header\n";
  const bool big = format == "binary_big_endian";
  for (int v = 0; v < 8; ++v) {
    glm::dvec3 p = CubeVertex(v);
    auto c = CubeColour(v);
    if (format == "ascii") {
      s += std::to_string(int(p.x)) + " " + std::to_string(int(p.y)) + " " + std::to_string(int(p.z));
      for (int k : c) s += " " + std::to_string(k);
      s += " 128\n";
      continue;
    }
    for (int k = 0; k < 3; ++k) Put(&s, float(p[k]), big);
    for (int k : c) Put(&s, uint8_t(k), big);
    Put(&s, uint8_t{128}, big);
  }
  for (const auto& q : kQuads) {
    if (format == "ascii") {
      s += "4 " + std::to_string(q[0]) + " " + std::to_string(q[1]) + " " + std::to_string(q[2]) + " " +
           std::to_string(q[3]) + "\n";
      continue;
    }
    Put(&s, uint8_t{4}, big);
    for (int k = 0; k < 4; ++k) Put(&s, int32_t(q[k]), big);
  }
  return s;
}

// The cube as COFF (or CNOFF with a normal per vertex), 8-bit colours and an alpha.
std::string ColourCubeOff(bool normals) {
  std::string s = normals ? "CNOFF\n8 6 12\n" : "COFF\n8 6 12\n";
  for (int v = 0; v < 8; ++v) {
    glm::dvec3 p = CubeVertex(v);
    s += std::to_string(int(p.x)) + " " + std::to_string(int(p.y)) + " " + std::to_string(int(p.z));
    if (normals) s += " 0 0 1";
    for (int k : CubeColour(v)) s += " " + std::to_string(k);
    s += " 255\n";
  }
  for (const auto& q : kQuads)
    s += "4 " + std::to_string(q[0]) + " " + std::to_string(q[1]) + " " + std::to_string(q[2]) + " " +
         std::to_string(q[3]) + "\n";
  return s;
}

// OpenMesh's vertex colours of `path` (8-bit, as it stores them), in vertex order.
std::vector<std::array<int, 3>> OpenMeshColours(const std::string& path) {
  OmMesh mesh;
  mesh.request_vertex_colors();
  OpenMesh::IO::Options opt = OpenMesh::IO::Options::VertexColor;
  std::vector<std::array<int, 3>> out;
  EXPECT_TRUE(OpenMesh::IO::read_mesh(mesh, path, opt)) << path;
  EXPECT_TRUE(opt.vertex_has_color()) << path << ": OpenMesh read no vertex colours";
  for (auto v : mesh.vertices()) {
    auto c = mesh.color(v);
    out.push_back({int(c[0]), int(c[1]), int(c[2])});
  }
  return out;
}

// Our colours are OpenMesh's 8-bit ones, sRGB-decoded; and the CubeColour ones.
void ExpectColoursLikeOpenMesh(const std::string& path, const Result<TriangleMesh>& r) {
  SCOPED_TRACE(path);
  ASSERT_TRUE(r.ok()) << r.status().message();
  auto om = OpenMeshColours(path);
  ASSERT_EQ(om.size(), 8u);
  ASSERT_EQ(r->colours.size(), 8u);
  for (int v = 0; v < 8; ++v) {
    EXPECT_EQ(om[v], CubeColour(v)) << "OpenMesh, vertex " << v;
    for (int c = 0; c < 3; ++c) EXPECT_DOUBLE_EQ(r->colours[v][c], Srgb8(om[v][c])) << "vertex " << v << " " << c;
  }
}

TEST_F(MeshFile, PlyUcharColoursInEveryEncodingMatchOpenMesh) {
  for (const char* format : {"ascii", "binary_little_endian", "binary_big_endian"}) {
    const std::string path = Write(std::string(format) + "_colours.ply", ColourCubePly(format));
    auto r = LoadMeshFile(path, Progress{}, false, true);
    ExpectCube(r);
    ExpectColoursLikeOpenMesh(path, r);
  }
}

TEST_F(MeshFile, CoffAndCnoffColoursMatchOpenMesh) {
  const std::string coff = Write("cube.off", ColourCubeOff(false));
  ExpectColoursLikeOpenMesh(coff, LoadMeshFile(coff, Progress{}, false, true));
  // CNOFF: the colour follows the normal; with and without the normals asked for.
  const std::string cnoff = Write("cube_n.off", ColourCubeOff(true));
  auto both = LoadMeshFile(cnoff, Progress{}, true, true);
  ExpectColoursLikeOpenMesh(cnoff, both);
  ASSERT_TRUE(both.ok());
  EXPECT_EQ(both->file_normals, std::vector<glm::dvec3>(8, glm::dvec3(0, 0, 1)));
  ExpectColoursLikeOpenMesh(cnoff, LoadMeshFile(cnoff, Progress{}, false, true));
}

TEST(MeshReader, ColoursAreReadOnlyWhenAskedFor) {
  auto r = Ply(ColourCubePly("ascii"));
  ExpectCube(r);
  EXPECT_TRUE(r->colours.empty());
  auto o = Off(ColourCubeOff(true));
  ExpectCube(o);
  EXPECT_TRUE(o->colours.empty());
  // Asked for, but the file has none: empty (LoadMeshFile reports it).
  auto none = PlyColours(CubePly("ascii", "uchar", "int"));  // has "red" only
  ExpectCube(none);
  EXPECT_TRUE(none->colours.empty());
  auto plain = OffColours(CubeOff());
  ExpectCube(plain);
  EXPECT_TRUE(plain->colours.empty());
}

// x y z float, then the colour properties as given, big endian: the values known exactly.
TEST(MeshReader, PlyFloatColoursAreLinearAsStoredInBigEndian) {
  std::string s =
      "ply\nformat binary_big_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
      "property float red\nproperty uchar alpha\nproperty double green\nproperty float blue\n"
      "element face 1\nproperty list uchar uint vertex_indices\nend_header\n";
  const double rgb[3][3] = {{0.25, 0.5, 0}, {1, 2.5, 0.125}, {0.1f, 1.0 / 3, 0.75}};
  for (int v = 0; v < 3; ++v) {
    for (int c = 0; c < 3; ++c) Put(&s, float(kTriangle[v][c]), true);
    Put(&s, float(rgb[v][0]), true);
    Put(&s, uint8_t{7}, true);
    Put(&s, double(rgb[v][1]), true);
    Put(&s, float(rgb[v][2]), true);
  }
  Put(&s, uint8_t{3}, true);
  for (uint32_t i : {0u, 1u, 2u}) Put(&s, i, true);
  auto r = PlyColours(s);
  ASSERT_TRUE(r.ok()) << r.status().message();
  ASSERT_EQ(r->colours.size(), 3u);
  for (int v = 0; v < 3; ++v) EXPECT_EQ(r->colours[v], glm::dvec3(rgb[v][0], rgb[v][1], rgb[v][2])) << v;
  EXPECT_EQ(r->triangles.size(), 1u);
}

TEST(MeshReader, PlyIntegerColoursOfEveryTypeAreScaledAndSrgbDecoded) {
  const std::string head =
      "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\n";
  // ushort diffuse_*: 65535 is 1, 32768 is sRGB 0.50000763 (0.21404820...), 0 is 0.
  auto r = PlyColours(head +
                      "property ushort diffuse_red\nproperty ushort diffuse_green\nproperty ushort diffuse_blue\n"
                      "end_header\n0 0 0 65535 32768 0\n1 0 0 0 1 2\n");
  ASSERT_TRUE(r.ok()) << r.status().message();
  ASSERT_EQ(r->colours.size(), 2u);
  EXPECT_DOUBLE_EQ(r->colours[0].x, 1.0);
  EXPECT_NEAR(r->colours[0].y, 0.2140482022981852, 1e-15);
  EXPECT_EQ(r->colours[0].z, 0.0);
  EXPECT_DOUBLE_EQ(r->colours[1].y, 1.0 / 65535 / 12.92);
  EXPECT_DOUBLE_EQ(r->colours[1].z, 2.0 / 65535 / 12.92);
  // char (int8) r g b: 127 is 1; and "red" wins over r g b when both are there.
  r = PlyColours(head + "property char r\nproperty char g\nproperty char b\nend_header\n0 0 0 127 0 5\n1 0 0 1 2 3\n");
  ASSERT_TRUE(r.ok()) << r.status().message();
  EXPECT_EQ(r->colours[0], glm::dvec3(1, 0, 5.0 / 127 / 12.92));
  r = PlyColours(head +
                 "property float r\nproperty float g\nproperty float b\nproperty uchar red\nproperty uchar green\n"
                 "property uchar blue\nend_header\n0 0 0 0.5 0.5 0.5 255 128 0\n1 0 0 9 9 9 0 0 0\n");
  ASSERT_TRUE(r.ok()) << r.status().message();
  EXPECT_EQ(r->colours[0], glm::dvec3(1, Srgb8(128), 0));
  EXPECT_EQ(r->colours[1], glm::dvec3(0));
}

TEST(MeshReader, OffColoursIntegerSrgbFloatLinearAlphaAndTexcoords) {
  auto r = OffColours(
      "COFF\n3 1 0\n"
      "0 0 0 255 128 10 255\n"  // 8-bit sRGB with an alpha
      "1 0 0 0.5 1.5 0\n"       // linear floats (> 1 allowed)
      "0 1 0 1 0.25 0e0\n"      // one non-integer: all three are floats
      "3 0 1 2 255 0 0\n");     // a face colour is ignored
  ASSERT_TRUE(r.ok()) << r.status().message();
  ASSERT_EQ(r->colours.size(), 3u);
  EXPECT_EQ(r->colours[0], glm::dvec3(1, Srgb8(128), 10 / 255.0 / 12.92));
  EXPECT_EQ(r->colours[1], glm::dvec3(0.5, 1.5, 0));
  EXPECT_EQ(r->colours[2], glm::dvec3(1, 0.25, 0));
  // STCOFF: s t after the colour.
  r = OffColours("STCOFF\n3 1 0\n0 0 0 255 255 255 0.5 0.5\n1 0 0 0 0 0 1 0\n0 1 0 0.5 0.5 0.5 0 1\n3 0 1 2\n");
  ASSERT_TRUE(r.ok()) << r.status().message();
  EXPECT_EQ(r->colours, (std::vector<glm::dvec3>{{1, 1, 1}, {0, 0, 0}, {0.5, 0.5, 0.5}}));
}

TEST(MeshReader, ObjVertexColoursAreSixNumbers) {
  const std::string tri = "v 0 0 0 1 0.5 0\nv 1 0 0 0.25 0.125 2\nv 0 1 0 0 0 1e-3\nf 1 2 3\n";
  auto r = ObjColours(tri);
  ASSERT_TRUE(r.ok()) << r.status().message();
  EXPECT_EQ(r->colours, (std::vector<glm::dvec3>{{1, 0.5, 0}, {0.25, 0.125, 2}, {0, 0, 1e-3}}));
  EXPECT_EQ(r->positions[1], glm::dvec3(1, 0, 0));
  auto plain = Obj(tri);  // not asked for: ignored
  ASSERT_TRUE(plain.ok());
  EXPECT_TRUE(plain->colours.empty());
  // x y z w (4 numbers) and 7 numbers are not colours; none has one: empty.
  auto w = ObjColours("v 0 0 0 1\nv 1 0 0 1 1 1 1\nv 0 1 0\nf 1 2 3\n");
  ASSERT_TRUE(w.ok()) << w.status().message();
  EXPECT_TRUE(w->colours.empty());
  // Some with, some without: the line of the first vertex without, either way round.
  ExpectError(ObjColours("v 0 0 0 1 1 1\n# c\nv 1 0 0\nv 0 1 0 1 1 1\nf 1 2 3\n"),
              {"test.obj:3", "vertex 2 has no colour", "every vertex"});
  ExpectError(ObjColours("v 0 0 0\nv 1 0 0 1 1 1\nv 0 1 0\nf 1 2 3\n"),
              {"test.obj:1", "vertex 1 has no colour", "vertex 2 (line 2) has one"});
  ExpectError(ObjColours("v 0 0 0 1 1 1\nv 1 0 0 1 1 1 1\n"), {"test.obj:2", "vertex 2 has no colour"});
}

TEST(MeshReader, BadColoursNameTheFileTheLineOrByteAndTheValue) {
  const std::string head =
      "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\n"
      "property float red\nproperty float green\nproperty float blue\nend_header\n";
  ExpectError(PlyColours(head + "0 0 0 1 1 1\n1 0 0 -0.5 0 0\n"), {"test.ply:12", "vertex 1 red is -0.5", ">= 0"});
  ExpectError(PlyColours(head + "0 0 0 1 inf 1\n1 0 0 0 0 0\n"), {"test.ply:11", "vertex 0 green is inf", "finite"});
  ExpectError(PlyColours(head + "0 0 0 1 1 one\n1 0 0 0 0 0\n"), {"test.ply:11", "\"one\"", "not a float"});
  std::string bin =
      "ply\nformat binary_little_endian 1.0\nelement vertex 1\nproperty float x\nproperty float y\n"
      "property float z\nproperty char red\nproperty char green\nproperty char blue\nend_header\n";
  const size_t header = bin.size();
  for (float f : {0.0f, 0.0f, 0.0f}) Put(&bin, f, false);
  for (int8_t c : {int8_t{1}, int8_t{-3}, int8_t{2}}) Put(&bin, c, false);
  const std::string byte = "test.ply (byte " + std::to_string(header + 15) + ")";
  ExpectError(PlyColours(bin), {byte.c_str(), "vertex 0 green is -3"});
  const std::string off = "COFF\n3 1 0\n0 0 0 255 0 0\n";
  const std::string rest = "0 1 0 1 1 1\n3 0 1 2\n";
  ExpectError(OffColours(off + "1 0 0 255 0\n" + rest), {"test.off:4", "vertex 1 colour component 3 is missing"});
  ExpectError(OffColours(off + "1 0 0\n" + rest), {"test.off:4", "vertex 1 colour component 1 is missing", "COFF"});
  ExpectError(OffColours(off + "1 0 0 255 x 0\n" + rest), {"test.off:4", "component 2 is \"x\"", "not a number"});
  ExpectError(OffColours(off + "1 0 0 255 0,5 0\n" + rest), {"test.off:4", "\"0,5\""});
  ExpectError(OffColours(off + "1 0 0 -1 0 0\n" + rest), {"test.off:4", "component 1 is \"-1\"", ">= 0"});
  ExpectError(OffColours(off + "1 0 0 0.5 -0.25 0\n" + rest), {"test.off:4", "\"-0.25\"", ">= 0"});
  ExpectError(OffColours(off + "1 0 0 0.5 nan 0\n" + rest), {"test.off:4", "\"nan\"", "finite"});
  ExpectError(OffColours(off + "1 0 0 256 0 0\n" + rest), {"test.off:4", "\"256\"", "above 255"});
  // CNOFF without the normals asked for: a missing normal leaves the colour short.
  ExpectError(OffColours("CNOFF\n1 0 0\n0 0 0 0 0 1 255 255\n"), {"test.off:3", "component 3 is missing"});
  ExpectError(ObjColours("v 0 0 0 -0.1 0 0\n"), {"test.obj:1", "vertex 1 colour component 1 is \"-0.1\""});
  ExpectError(ObjColours("v 0 0 0 1 1 1\nv 1 0 0 1 nan 1\n"), {"test.obj:2", "vertex 2 colour component 2", "\"nan\""});
  ExpectError(ObjColours("v 0 0 0 1 1 red\n"), {"test.obj:1", "\"red\""});
}

TEST_F(MeshFile, MissingColoursAreAnErrorNamingTheFileAndWhatToAdd) {
  struct Case {
    std::string name, bytes;
    std::vector<const char*> parts;
  };
  const std::vector<Case> cases = {
      {"plain.ply",
       CubePly("ascii", "uchar", "int"),
       {"plain.ply", "PLY file stores no vertex colours", "red green blue"}},
      {"plain.off", CubeOff(), {"plain.off", "OFF file stores no vertex colours", "COFF"}},
      {"plain.obj", CubeObj(), {"plain.obj", "OBJ file stores no vertex colours", "v x y z r g b"}},
      {"plain.stl", CubeStlAscii(), {"plain.stl", "STL stores no vertex colours"}},
  };
  for (const Case& c : cases) {
    const std::string path = Write(c.name, c.bytes);
    auto r = LoadMeshFile(path, Progress{}, false, true);
    ASSERT_FALSE(r.ok()) << c.name;
    for (const char* p : c.parts) EXPECT_NE(r.status().message().find(p), std::string::npos) << r.status().message();
    EXPECT_TRUE(LoadMeshFile(path).ok()) << c.name;  // not asked for: fine
  }
}

TEST_F(MeshFile, ColoursSurviveFinalizeAndTransform) {
  auto r =
      LoadMeshFile(Write("c.obj", "v 0 0 0 1 0 0\nv 1 0 0 0 1 0\nv 0 1 0 0 0 1\nv 5 5 5 2 2 2\nf 1 2 3\nf 1 1 2\n"),
                   Progress{}, false, true);
  ASSERT_TRUE(r.ok()) << r.status().message();
  const std::vector<glm::dvec3> want = {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}, {2, 2, 2}};
  EXPECT_EQ(r->colours, want);  // the unused vertex 4 keeps its row and colour
  Object o;
  o.scale = {-2, 1, 3};
  o.rotate_degrees = {10, 20, 30};
  ApplyTransform(ObjectTransform(o), &*r);
  EXPECT_EQ(r->colours, want);
}

// A quad (two triangles) with a colour per corner, encoded by libdraco: 8-bit RGBA
// colours (sRGB) or float RGB ones (linear as stored); Draco may renumber the points, so
// each is matched by its position.
const float kQuadPos[4][3] = {{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0}};
const uint8_t kQuadRgba[4][4] = {{255, 0, 10, 255}, {128, 64, 32, 0}, {0, 255, 200, 9}, {1, 2, 3, 4}};
const float kQuadRgb[4][3] = {{0.25f, 0.5f, 0.75f}, {1, 2.5f, 0}, {0.1f, 0.2f, 0.3f}, {0, 0, 1}};

std::string EncodeQuad(bool with_colour, bool float_colour, int method) {
  draco::TriangleSoupMeshBuilder b;
  b.Start(2);
  const int pos = b.AddAttribute(draco::GeometryAttribute::POSITION, 3, draco::DT_FLOAT32);
  int col = -1;
  if (with_colour) {
    col = float_colour ? b.AddAttribute(draco::GeometryAttribute::COLOR, 3, draco::DT_FLOAT32)
                       : b.AddAttribute(draco::GeometryAttribute::COLOR, 4, draco::DT_UINT8);
  }
  const int faces[2][3] = {{0, 1, 2}, {0, 2, 3}};
  for (int f = 0; f < 2; ++f) {
    const int* c = faces[f];
    b.SetAttributeValuesForFace(pos, draco::FaceIndex(f), kQuadPos[c[0]], kQuadPos[c[1]], kQuadPos[c[2]]);
    if (col >= 0 && float_colour)
      b.SetAttributeValuesForFace(col, draco::FaceIndex(f), kQuadRgb[c[0]], kQuadRgb[c[1]], kQuadRgb[c[2]]);
    else if (col >= 0)
      b.SetAttributeValuesForFace(col, draco::FaceIndex(f), kQuadRgba[c[0]], kQuadRgba[c[1]], kQuadRgba[c[2]]);
  }
  std::unique_ptr<draco::Mesh> mesh = b.Finalize();
  EXPECT_NE(mesh, nullptr);
  if (mesh == nullptr) return {};
  draco::Encoder enc;
  enc.SetEncodingMethod(method);
  enc.SetSpeedOptions(5, 5);  // no quantisation set: positions and colours are stored exactly
  draco::EncoderBuffer buf;
  draco::Status s = enc.EncodeMeshToBuffer(*mesh, &buf);
  EXPECT_TRUE(s.ok()) << s.error_msg_string();
  return std::string(buf.data(), buf.data() + buf.size());
}

TEST_F(MeshFile, DracoColourAttributeUint8IsSrgbFloatIsLinear) {
  for (int method : {draco::MESH_SEQUENTIAL_ENCODING, draco::MESH_EDGEBREAKER_ENCODING}) {
    for (bool float_colour : {false, true}) {
      SCOPED_TRACE("method " + std::to_string(method) + (float_colour ? " float" : " uint8"));
      auto r = LoadMeshFile(Write("quad.drc", EncodeQuad(true, float_colour, method)), Progress{}, false, true);
      ASSERT_TRUE(r.ok()) << r.status().message();
      ASSERT_EQ(r->positions.size(), 4u);
      ASSERT_EQ(r->colours.size(), 4u);
      EXPECT_EQ(r->triangles.size(), 2u);
      for (size_t i = 0; i < 4; ++i) {
        int k = -1;
        for (int j = 0; j < 4; ++j)
          if (r->positions[i] == glm::dvec3(kQuadPos[j][0], kQuadPos[j][1], kQuadPos[j][2])) k = j;
        ASSERT_GE(k, 0) << "point " << i;
        for (int c = 0; c < 3; ++c) {
          const double want = float_colour ? double(kQuadRgb[k][c]) : Srgb8(kQuadRgba[k][c]);
          EXPECT_DOUBLE_EQ(r->colours[i][c], want) << "point " << i << " component " << c;
        }
      }
    }
  }
  auto none = LoadMeshFile(Write("bare.drc", EncodeQuad(false, false, draco::MESH_SEQUENTIAL_ENCODING)), Progress{},
                           false, true);
  ASSERT_FALSE(none.ok());
  EXPECT_NE(none.status().message().find("Draco file stores no vertex colours"), std::string::npos)
      << none.status().message();
  EXPECT_NE(none.status().message().find("COLOR"), std::string::npos);
}

TEST(MeshReader, BundledBunnyObjReadsLikeOpenMesh) {
  const std::string path = std::string(LTB_SOURCE_DIR) + "/data/meshes/bunny.obj";
  if (!std::ifstream(path)) GTEST_SKIP() << path << " missing: run scripts/fetch_samples.sh";
  ExpectSameAsOpenMesh(path);
}

}  // namespace
}  // namespace ltb::sample
