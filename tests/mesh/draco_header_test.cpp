// ReadDracoCounts against libdraco's own encoder (the independent oracle): grids of known
// face counts encoded sequentially and by edgebreaker at every speed, with and without
// nested metadata, read back the counts the mesh was built with; hand-made headers of the
// older bitstream versions (fixed-width counts before 2.0, a new-vertex count before 2.2)
// sit exactly at and one past the faces-per-byte limit; the 548-byte fuzzer file that
// made libdraco take ~400 MB is refused by LoadMeshFile before libdraco sees it.
#include "stages/mesh/draco_header.h"

#include <draco/compression/encode.h>
#include <draco/mesh/triangle_soup_mesh_builder.h>
#include <draco/metadata/geometry_metadata.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <fstream>
#include <string>
#include <vector>

#include "stages/mesh/triangle_mesh.h"

namespace ltb::sample {
using namespace ::ltb::mesh;  // the readers under test (stages/mesh), placed by the scene code
namespace {

using Bytes = std::vector<unsigned char>;

// An n × n grid of quads, two triangles each: 2n² faces.
std::unique_ptr<draco::Mesh> Grid(int n) {
  draco::TriangleSoupMeshBuilder b;
  b.Start(2 * n * n);
  const int pos = b.AddAttribute(draco::GeometryAttribute::POSITION, 3, draco::DT_FLOAT32);
  int f = 0;
  for (int j = 0; j < n; ++j) {
    for (int i = 0; i < n; ++i) {
      draco::Vector3f a(float(i), float(j), 0), bb(float(i + 1), float(j), 0), c(float(i), float(j + 1), 0),
          d(float(i + 1), float(j + 1), 0);
      b.SetAttributeValuesForFace(pos, draco::FaceIndex(f++), a.data(), bb.data(), d.data());
      b.SetAttributeValuesForFace(pos, draco::FaceIndex(f++), a.data(), d.data(), c.data());
    }
  }
  return b.Finalize();
}

Bytes Encode(const draco::Mesh& mesh, int method, int speed) {
  draco::Encoder enc;
  enc.SetEncodingMethod(method);
  enc.SetSpeedOptions(speed, speed);
  enc.SetAttributeQuantization(draco::GeometryAttribute::POSITION, 11);
  draco::EncoderBuffer buf;
  draco::Status s = enc.EncodeMeshToBuffer(mesh, &buf);
  EXPECT_TRUE(s.ok()) << s.error_msg_string();
  return Bytes(buf.data(), buf.data() + buf.size());
}

TEST(DracoHeader, CountsOfEncodedGridsInEveryMethodAndSpeed) {
  for (int n : {1, 7, 40}) {
    auto mesh = Grid(n);
    ASSERT_NE(mesh, nullptr);
    for (int method : {draco::MESH_SEQUENTIAL_ENCODING, draco::MESH_EDGEBREAKER_ENCODING}) {
      for (int speed : {0, 5, 10}) {
        Bytes file = Encode(*mesh, method, speed);
        auto counts = ReadDracoCounts(file);
        ASSERT_TRUE(counts.has_value()) << "n " << n << " method " << method << " speed " << speed;
        EXPECT_EQ(counts->faces, uint32_t(2 * n * n)) << "method " << method << " speed " << speed;
        EXPECT_EQ(counts->method, method);
        EXPECT_EQ(counts->version_major, 2);
        EXPECT_EQ(counts->version_minor, 2);
        // (n + 1)² grid points; edgebreaker may count a few more (split vertices).
        EXPECT_GE(uint64_t(counts->vertices) + counts->extra_vertices, uint64_t((n + 1) * (n + 1)));
        EXPECT_TRUE(CheckDracoCounts("grid.drc", file).ok());
      }
    }
  }
}

TEST(DracoHeader, MetadataOfTheMeshAndItsAttributesIsSkipped) {
  auto mesh = Grid(9);
  auto geometry = std::make_unique<draco::GeometryMetadata>();
  geometry->AddEntryString("name", "a grid with a long enough name to take several bytes");
  geometry->AddEntryIntArray("ints", std::vector<int32_t>(300, 7));  // a value past 127 bytes
  auto child = std::make_unique<draco::Metadata>();
  child->AddEntryDouble("scale", 2.5);
  auto grandchild = std::make_unique<draco::Metadata>();
  grandchild->AddEntryInt("depth", 2);
  child->AddSubMetadata("grandchild", std::move(grandchild));
  geometry->AddSubMetadata("child", std::move(child));
  geometry->AddSubMetadata("sibling", std::make_unique<draco::Metadata>());
  mesh->AddMetadata(std::move(geometry));
  auto attribute = std::make_unique<draco::AttributeMetadata>();
  attribute->AddEntryString("units", "metres");
  mesh->AddAttributeMetadata(0, std::move(attribute));
  for (int method : {draco::MESH_SEQUENTIAL_ENCODING, draco::MESH_EDGEBREAKER_ENCODING}) {
    Bytes file = Encode(*mesh, method, 5);
    ASSERT_EQ(file[10] & 0x80, 0x80) << "the encoder did not set the metadata flag";
    auto counts = ReadDracoCounts(file);
    ASSERT_TRUE(counts.has_value());
    EXPECT_EQ(counts->faces, 2u * 9 * 9) << "method " << method;
  }
}

TEST(DracoHeader, TruncatedAndForeignBytesGiveNoCounts) {
  Bytes file = Encode(*Grid(5), draco::MESH_EDGEBREAKER_ENCODING, 5);
  // Header (11 bytes) + traversal kind + vertices and faces varints: any cut before the
  // faces count ends leaves nothing to check.
  for (size_t cut : {0, 4, 5, 10, 11, 12, 13}) {
    EXPECT_FALSE(ReadDracoCounts(std::span(file).first(cut)).has_value()) << "cut " << cut;
  }
  Bytes point_cloud = file;
  point_cloud[7] = 0;  // encoder type: point cloud
  EXPECT_FALSE(ReadDracoCounts(point_cloud).has_value());
  Bytes future = file;
  future[5] = 2, future[6] = 3;  // bitstream 2.3: libdraco 1.5 refuses it
  EXPECT_FALSE(ReadDracoCounts(future).has_value());
}

// A hand-made header of an older bitstream, padded to `size` bytes.
Bytes OldHeader(int major, int minor, int method, uint32_t vertices, uint32_t faces, size_t size) {
  Bytes b = {'D', 'R', 'A', 'C', 'O', uint8_t(major), uint8_t(minor), 1, uint8_t(method), 0, 0};
  auto u32 = [&](uint32_t v) {
    for (int i = 0; i < 4; ++i) b.push_back(uint8_t(v >> (8 * i)));
  };
  auto varint = [&](uint32_t v) {
    do {
      b.push_back(uint8_t((v & 0x7f) | (v > 0x7f ? 0x80 : 0)));
      v >>= 7;
    } while (v);
  };
  const int version = major * 256 + minor;
  if (method == 0) {  // sequential: faces, points; fixed width before 2.2
    if (version < 2 * 256 + 2)
      u32(faces), u32(vertices);
    else
      varint(faces), varint(vertices);
  } else {  // edgebreaker: kind, new vertices (before 2.2), vertices, faces; fixed width before 2.0
    b.push_back(0);
    if (version < 2 * 256)
      u32(0), u32(vertices), u32(faces);
    else if (version < 2 * 256 + 2)
      varint(0), varint(vertices), varint(faces);
    else
      varint(vertices), varint(faces);
  }
  b.resize(size, 0);
  return b;
}

TEST(DracoHeader, OlderBitstreamsAtAndPastTheLimit) {
  const size_t size = 100;
  const uint32_t limit = uint32_t(kDracoMaxFacesPerByte * size);
  for (auto [major, minor] : {std::pair{1, 1}, {1, 3}, {2, 0}, {2, 1}, {2, 2}}) {
    for (int method : {0, 1}) {
      SCOPED_TRACE("bitstream " + std::to_string(major) + "." + std::to_string(minor) + " method " +
                   std::to_string(method));
      auto counts = ReadDracoCounts(OldHeader(major, minor, method, 12345, 67890, size));
      ASSERT_TRUE(counts.has_value());
      EXPECT_EQ(counts->faces, 67890u);
      EXPECT_EQ(counts->vertices, 12345u);
      EXPECT_TRUE(CheckDracoCounts("x.drc", OldHeader(major, minor, method, 3, limit, size)).ok());
      Status s = CheckDracoCounts("x.drc", OldHeader(major, minor, method, 3, limit + 1, size));
      EXPECT_FALSE(s.ok());
      EXPECT_NE(s.message().find(std::to_string(limit + 1) + " faces"), std::string::npos) << s.message();
      EXPECT_NE(s.message().find("100 bytes"), std::string::npos) << s.message();
      EXPECT_FALSE(CheckDracoCounts("x.drc", OldHeader(major, minor, method, 3 * limit + 1, limit, size)).ok());
    }
  }
}

TEST(DracoHeader, FuzzerFileDecodingHundredsOfMegabytesIsRefusedFirst) {
  // drc_fuzzer run 6: bitstream 1.1 edgebreaker declaring 0x01010101 = 16,843,009 faces in
  // 548 bytes; libdraco sized its corner table (~540 MB at peak) before failing.
  Bytes file(548, 0x94);
  const char head[] = "DRACO\x01\x01\x01\x01\x01\x01\x01\x01\x01\x01\x01\x01\x01\x01\x01\x01\x01\x01\x01";
  std::copy(head, head + sizeof head - 1, file.begin());
  auto counts = ReadDracoCounts(file);
  ASSERT_TRUE(counts.has_value());
  EXPECT_EQ(counts->faces, 16843009u);
  const std::string path = ::testing::TempDir() + "/ltb_draco_" + std::to_string(::getpid()) + ".drc";
  std::ofstream(path, std::ios::binary).write(reinterpret_cast<const char*>(file.data()), std::streamsize(file.size()));
  auto mesh = LoadMeshFile(path);
  ASSERT_FALSE(mesh.ok());
  EXPECT_NE(mesh.status().message().find("16843009 faces"), std::string::npos) << mesh.status().message();
  EXPECT_NE(mesh.status().message().find(path), std::string::npos);
  std::remove(path.c_str());
}

}  // namespace
}  // namespace ltb::sample
