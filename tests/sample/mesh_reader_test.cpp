// Our OFF and PLY readers against meshes known in closed form: the unit cube written as
// OFF and as PLY in every encoding (ascii, binary little and big endian) with extra
// properties and assorted integer types loads to the same 8 vertices and the same 12 fan
// triangles, whose areas sum to 6 and whose signed volume is 1; hostile headers, lying
// list counts, out-of-range indices and truncated bodies are errors naming the field.
#include <gtest/gtest.h>

#include <unistd.h>

#include <bit>
#include <cmath>
#include <cstring>
#include <fstream>
#include <string>
#include <vector>

#include <glm/geometric.hpp>

#include "stages/sample/geometry.h"
#include "stages/sample/mesh_reader.h"

namespace ltb::sample {
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
  for (const auto& q : kQuads) s += "4 " + std::to_string(q[0]) + " " + std::to_string(q[1]) + " " + std::to_string(q[2]) + " " + std::to_string(q[3]) + "\n";
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
  std::string s = "ply\nformat " + format + " 1.0\ncomment the unit cube\nelement vertex 8\nproperty float x\n"
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
      if (t == "uchar") Put(&s, uint8_t(x), big);
      else if (t == "char") Put(&s, int8_t(x), big);
      else if (t == "ushort") Put(&s, uint16_t(x), big);
      else if (t == "short") Put(&s, int16_t(x), big);
      else if (t == "uint") Put(&s, uint32_t(x), big);
      else Put(&s, int32_t(x), big);
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
    for (auto [ct, it] : {std::pair{"uchar", "int"}, {"ushort", "uint"}, {"char", "short"}, {"uint", "uchar"},
                          {"int", "ushort"}}) {
      SCOPED_TRACE(std::string(format) + " " + ct + " " + it);
      ExpectCube(Ply(CubePly(format, ct, it)));
    }
  }
}

TEST(MeshReader, PlyDoubleCoordinatesAreRoundedToFloatOnce) {
  std::string s = "ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty double x\nproperty double y\n"
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
  std::string ply = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
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
  ExpectError(Ply("ply\nformat binary_little_endian 1.0\nelement vertex 1000000000\nproperty float x\nproperty float y\n"
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
  std::string s = "ply\nformat binary_little_endian 1.0\nelement vertex 1\nproperty float x\nproperty float y\n"
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

}  // namespace
}  // namespace ltb::sample
