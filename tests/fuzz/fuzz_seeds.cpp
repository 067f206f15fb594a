// Writes seed files for the fuzz targets that need a real encoder (scripts/fuzz_corpus.sh
// runs it at fuzz time; nothing generated is committed):
//   OUT/exr/   OpenEXR environment maps: every compression, half/float/uint, RGB, RGBA, Y,
//              luminance-chroma, scanline and tiled, lat-long and crosses, offset windows.
//   OUT/mesh/  the mesh MESH (a small OBJ) written by OpenMesh as OFF, PLY, OBJ and STL,
//              ASCII and binary (both byte orders for PLY), with and without normals,
//              colours and texture coordinates; and by Draco as .drc (edgebreaker and
//              sequential, several quantizations, with normals, a point cloud).
//   OUT/ltm/   containers written by ltbake's own writer where the stages would need large
//              inputs: payloads written with O_DIRECT behind padding frames (the stages do
//              that only for chunks of 64 KiB and more; here from 4 KiB), sealed and not;
//              every dtype in every encoding (raw, zero, zstd, sparse, sparse-zstd), and
//              sparse-coded wavelet-like i32 columns; files
//              of a writer stopped after every few mutations (torn and unsealed).
// usage: ltb_fuzz_seeds OUT MESH.obj
#include <ImfChannelList.h>
#include <ImfFrameBuffer.h>
#include <ImfHeader.h>
#include <ImfOutputFile.h>
#include <ImfRgbaFile.h>
#include <ImfTiledOutputFile.h>
#include <ImfTiledRgbaFile.h>
#include <draco/compression/encode.h>
#include <draco/mesh/triangle_soup_mesh_builder.h>
#include <draco/point_cloud/point_cloud_builder.h>

#include <OpenMesh/Core/IO/MeshIO.hh>
#include <OpenMesh/Core/Mesh/PolyMesh_ArrayKernelT.hh>
#include <array>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "format/array_spec.h"
#include "format/chunk_codec.h"
#include "format/io/container_writer.h"

namespace fs = std::filesystem;

namespace {

int failures = 0;

void Fail(const std::string& what) {
  std::fprintf(stderr, "ltb_fuzz_seeds: %s\n", what.c_str());
  ++failures;
}

// Radiance-like test values: a smooth gradient with a bright spot.
float Value(int x, int y, int c, int w, int h) {
  float v = 0.2f + 0.5f * float(x) / w + 0.3f * float(y) / h + 0.1f * c;
  if (x == w / 3 && y == h / 4) v = 40.0f;
  return v;
}

void WriteExr(const std::string& path, int w, int h, Imf::Compression comp, Imf::PixelType type, const char* channels,
              int x0 = 0, int y0 = 0, bool tiled = false) {
  try {
    Imath::Box2i dw(Imath::V2i(x0, y0), Imath::V2i(x0 + w - 1, y0 + h - 1));
    Imf::Header header(dw, dw);
    header.compression() = comp;
    std::vector<std::string> names;
    for (const char* p = channels; *p; ++p) names.push_back(std::string(1, *p));
    for (const auto& n : names) header.channels().insert(n, Imf::Channel(type));
    const size_t n = size_t(w) * h;
    std::vector<float> f(n * names.size());
    std::vector<half> hf(n * names.size());
    std::vector<unsigned> u(n * names.size());
    for (int y = 0; y < h; ++y)
      for (int x = 0; x < w; ++x)
        for (size_t c = 0; c < names.size(); ++c) {
          size_t i = (size_t(y) * w + x) * names.size() + c;
          f[i] = Value(x, y, int(c), w, h);
          hf[i] = half(f[i]);
          u[i] = unsigned(f[i] * 10);
        }
    Imf::FrameBuffer fb;
    const size_t stride = names.size();
    for (size_t c = 0; c < names.size(); ++c) {
      char* base;
      size_t es;
      if (type == Imf::FLOAT)
        base = reinterpret_cast<char*>(f.data() + c), es = sizeof(float);
      else if (type == Imf::HALF)
        base = reinterpret_cast<char*>(hf.data() + c), es = sizeof(half);
      else
        base = reinterpret_cast<char*>(u.data() + c), es = sizeof(unsigned);
      base -= (ptrdiff_t(y0) * w + x0) * stride * es;
      fb.insert(names[c], Imf::Slice(type, base, stride * es, stride * es * w));
    }
    if (tiled) {
      header.setTileDescription(Imf::TileDescription(8, 8, Imf::ONE_LEVEL));
      Imf::TiledOutputFile out(path.c_str(), header);
      out.setFrameBuffer(fb);
      out.writeTiles(0, out.numXTiles() - 1, 0, out.numYTiles() - 1);
    } else {
      Imf::OutputFile out(path.c_str(), header);
      out.setFrameBuffer(fb);
      out.writePixels(h);
    }
  } catch (const std::exception& e) {
    Fail(path + ": " + e.what());
  }
}

void WriteRgbaExr(const std::string& path, int w, int h, Imf::RgbaChannels which, Imf::Compression comp,
                  bool tiled = false) {
  try {
    std::vector<Imf::Rgba> px(size_t(w) * h);
    for (int y = 0; y < h; ++y)
      for (int x = 0; x < w; ++x)
        px[size_t(y) * w + x] = Imf::Rgba(Value(x, y, 0, w, h), Value(x, y, 1, w, h), Value(x, y, 2, w, h), 1);
    if (tiled) {
      Imf::TiledRgbaOutputFile out(path.c_str(), w, h, 8, 8, Imf::ONE_LEVEL, Imf::ROUND_DOWN, which);
      out.setFrameBuffer(px.data(), 1, w);
      out.writeTiles(0, out.numXTiles() - 1, 0, out.numYTiles() - 1);
    } else {
      Imf::RgbaOutputFile out(path.c_str(), w, h, which, 1, Imath::V2f(0, 0), 1, Imf::INCREASING_Y, comp);
      out.setFrameBuffer(px.data(), 1, w);
      out.writePixels(h);
    }
  } catch (const std::exception& e) {
    Fail(path + ": " + e.what());
  }
}

void ExrSeeds(const std::string& dir) {
  fs::create_directories(dir);
  struct {
    Imf::Compression c;
    const char* name;
  } comps[] = {{Imf::NO_COMPRESSION, "none"},  {Imf::RLE_COMPRESSION, "rle"},   {Imf::ZIPS_COMPRESSION, "zips"},
               {Imf::ZIP_COMPRESSION, "zip"},  {Imf::PIZ_COMPRESSION, "piz"},   {Imf::PXR24_COMPRESSION, "pxr24"},
               {Imf::B44_COMPRESSION, "b44"},  {Imf::B44A_COMPRESSION, "b44a"}, {Imf::DWAA_COMPRESSION, "dwaa"},
               {Imf::DWAB_COMPRESSION, "dwab"}};
  for (const auto& c : comps) {
    WriteExr(dir + "/latlong-float-" + c.name + ".exr", 16, 8, c.c, Imf::FLOAT, "RGB");
    WriteExr(dir + "/latlong-half-" + c.name + ".exr", 16, 8, c.c, Imf::HALF, "RGB");
  }
  WriteExr(dir + "/latlong-uint.exr", 16, 8, Imf::ZIP_COMPRESSION, Imf::UINT, "RGB");
  WriteExr(dir + "/hcross-half.exr", 16, 12, Imf::PIZ_COMPRESSION, Imf::HALF, "RGB");
  WriteExr(dir + "/vcross-float.exr", 12, 16, Imf::NO_COMPRESSION, Imf::FLOAT, "RGB");
  WriteExr(dir + "/y-only.exr", 16, 8, Imf::ZIPS_COMPRESSION, Imf::FLOAT, "Y");
  WriteExr(dir + "/rgba-float.exr", 16, 8, Imf::RLE_COMPRESSION, Imf::FLOAT, "ABGR");
  WriteExr(dir + "/no-rgb.exr", 16, 8, Imf::NO_COMPRESSION, Imf::HALF, "XZ");
  WriteExr(dir + "/offset-window.exr", 16, 8, Imf::ZIP_COMPRESSION, Imf::HALF, "RGB", -5, 7);
  WriteExr(dir + "/tiled-float.exr", 16, 8, Imf::ZIP_COMPRESSION, Imf::FLOAT, "RGB", 0, 0, true);
  WriteExr(dir + "/tiled-half-piz.exr", 16, 12, Imf::PIZ_COMPRESSION, Imf::HALF, "RGB", 0, 0, true);
  WriteRgbaExr(dir + "/rgba-half.exr", 16, 8, Imf::WRITE_RGBA, Imf::ZIP_COMPRESSION);
  WriteRgbaExr(dir + "/yc.exr", 16, 8, Imf::WRITE_YC, Imf::PIZ_COMPRESSION);
  WriteRgbaExr(dir + "/yca-dwaa.exr", 16, 8, Imf::WRITE_YCA, Imf::DWAA_COMPRESSION);
  WriteRgbaExr(dir + "/y-rgba.exr", 16, 8, Imf::WRITE_Y, Imf::NO_COMPRESSION);
  WriteRgbaExr(dir + "/tiled-rgba.exr", 16, 8, Imf::WRITE_RGB, Imf::NO_COMPRESSION, true);
}

using PolyMesh = OpenMesh::PolyMesh_ArrayKernelT<>;

void WriteOm(PolyMesh& m, const std::string& path, OpenMesh::IO::Options opt) {
  if (!OpenMesh::IO::write_mesh(m, path, opt)) Fail(path + ": OpenMesh could not write it");
}

void WriteDraco(const std::string& path, const PolyMesh& m, int method, int qp, bool normals) {
  // Triangles from the polygons (fan), positions per corner.
  std::vector<std::array<PolyMesh::Point, 3>> tris;
  std::vector<std::array<PolyMesh::Normal, 3>> nrm;
  for (auto f : m.faces()) {
    std::vector<PolyMesh::VertexHandle> vs(m.cfv_begin(f), m.cfv_end(f));
    for (size_t k = 1; k + 1 < vs.size(); ++k) {
      tris.push_back({m.point(vs[0]), m.point(vs[k]), m.point(vs[k + 1])});
      nrm.push_back({m.normal(vs[0]), m.normal(vs[k]), m.normal(vs[k + 1])});
    }
  }
  draco::TriangleSoupMeshBuilder b;
  b.Start(static_cast<int>(tris.size()));
  int pos = b.AddAttribute(draco::GeometryAttribute::POSITION, 3, draco::DT_FLOAT32);
  int nor = normals ? b.AddAttribute(draco::GeometryAttribute::NORMAL, 3, draco::DT_FLOAT32) : -1;
  for (size_t i = 0; i < tris.size(); ++i) {
    draco::FaceIndex fi(static_cast<uint32_t>(i));
    b.SetAttributeValuesForFace(pos, fi, tris[i][0].data(), tris[i][1].data(), tris[i][2].data());
    if (normals) b.SetAttributeValuesForFace(nor, fi, nrm[i][0].data(), nrm[i][1].data(), nrm[i][2].data());
  }
  std::unique_ptr<draco::Mesh> mesh = b.Finalize();
  if (!mesh) return Fail(path + ": Draco mesh builder failed");
  draco::Encoder enc;
  enc.SetEncodingMethod(method);
  if (qp > 0) enc.SetAttributeQuantization(draco::GeometryAttribute::POSITION, qp);
  if (normals) enc.SetAttributeQuantization(draco::GeometryAttribute::NORMAL, 8);
  draco::EncoderBuffer buf;
  auto st = enc.EncodeMeshToBuffer(*mesh, &buf);
  if (!st.ok()) return Fail(path + ": Draco: " + st.error_msg_string());
  std::ofstream(path, std::ios::binary).write(buf.data(), static_cast<std::streamsize>(buf.size()));
}

void DracoPointCloud(const std::string& path, const PolyMesh& m) {
  draco::PointCloudBuilder b;
  b.Start(static_cast<int>(m.n_vertices()));
  int pos = b.AddAttribute(draco::GeometryAttribute::POSITION, 3, draco::DT_FLOAT32);
  for (auto v : m.vertices()) b.SetAttributeValueForPoint(pos, draco::PointIndex(v.idx()), m.point(v).data());
  auto pc = b.Finalize(false);
  draco::Encoder enc;
  enc.SetAttributeQuantization(draco::GeometryAttribute::POSITION, 11);
  draco::EncoderBuffer buf;
  auto st = enc.EncodePointCloudToBuffer(*pc, &buf);
  if (!st.ok()) return Fail(path + ": Draco: " + st.error_msg_string());
  std::ofstream(path, std::ios::binary).write(buf.data(), static_cast<std::streamsize>(buf.size()));
}

void MeshSeeds(const std::string& dir, const std::string& input) {
  fs::create_directories(dir);
  PolyMesh m;
  m.request_vertex_normals();
  m.request_vertex_colors();
  m.request_vertex_texcoords2D();
  m.request_face_normals();
  OpenMesh::IO::Options ropt;
  if (!OpenMesh::IO::read_mesh(m, input, ropt)) return Fail(input + ": OpenMesh could not read it");
  m.update_normals();
  for (auto v : m.vertices()) {
    auto p = m.point(v);
    auto byte = [](float x) { return static_cast<unsigned char>(static_cast<int>(std::fabs(x) * 1000) % 256); };
    m.set_color(v, PolyMesh::Color(byte(p[0]), byte(p[1]), 128));
    m.set_texcoord2D(v, PolyMesh::TexCoord2D(p[0], p[2]));
  }
  using O = OpenMesh::IO::Options;
  const O::value_type all = O::VertexNormal | O::VertexColor | O::VertexTexCoord;
  WriteOm(m, dir + "/plain.off", O::Default);
  WriteOm(m, dir + "/attrs.off", all);
  WriteOm(m, dir + "/binary.off", O::Binary);
  WriteOm(m, dir + "/binary-attrs.off", O::Binary | all);
  WriteOm(m, dir + "/colorfloat.off", O::VertexColor | O::ColorFloat);
  WriteOm(m, dir + "/ascii.ply", O::Default);
  WriteOm(m, dir + "/ascii-attrs.ply", all);
  WriteOm(m, dir + "/binary-lsb.ply", O::Binary | O::LSB);
  WriteOm(m, dir + "/binary-msb.ply", O::Binary | O::MSB);
  WriteOm(m, dir + "/binary-attrs.ply", O::Binary | O::LSB | all);
  WriteOm(m, dir + "/binary-colorfloat.ply", O::Binary | O::VertexColor | O::ColorFloat);
  WriteOm(m, dir + "/plain.obj", O::Default);
  WriteOm(m, dir + "/attrs.obj", O::VertexNormal | O::VertexTexCoord);
  WriteOm(m, dir + "/ascii.stl", O::Default);
  WriteOm(m, dir + "/binary.stl", O::Binary);
  WriteDraco(dir + "/edgebreaker.drc", m, draco::MESH_EDGEBREAKER_ENCODING, 11, false);
  WriteDraco(dir + "/edgebreaker-normals.drc", m, draco::MESH_EDGEBREAKER_ENCODING, 14, true);
  WriteDraco(dir + "/sequential.drc", m, draco::MESH_SEQUENTIAL_ENCODING, 8, false);
  WriteDraco(dir + "/sequential-float.drc", m, draco::MESH_SEQUENTIAL_ENCODING, 0, false);
  DracoPointCloud(dir + "/pointcloud.drc", m);
}

nlohmann::json Array(const char* name, const char* dtype, uint64_t rows, uint64_t cols, const char* layout,
                     uint64_t block) {
  return {{"name", name}, {"dtype", dtype}, {"shape", {rows, cols}}, {"layout", layout}, {"block", block}};
}

// Element k of a test array of dtype `dt`, `bytes` long: mostly zeros (sparse) or dense.
std::vector<std::byte> TestChunk(ltb::format::DType dt, uint64_t elements, uint64_t seed, bool sparse) {
  using ltb::format::DType;
  const uint64_t es = ltb::format::DTypeSize(dt);
  std::vector<std::byte> out(elements * es);
  for (uint64_t k = 0; k < elements; ++k) {
    if (sparse && (k * 7 + seed) % 11 != 0) continue;
    double v = double((k * 37 + seed * 11) % 97) - 40.0;
    std::byte* p = out.data() + k * es;
    switch (dt) {
      case DType::kF32: {
        float f = float(v) * 0.25f;
        std::memcpy(p, &f, 4);
        break;
      }
      case DType::kF64: {
        double d = v * 0.125;
        std::memcpy(p, &d, 8);
        break;
      }
      case DType::kU8: {
        uint8_t u = uint8_t(int(v) & 0xff);
        std::memcpy(p, &u, 1);
        break;
      }
      case DType::kI32: {
        int32_t i = int32_t(v) * 1000;
        std::memcpy(p, &i, 4);
        break;
      }
      case DType::kU32: {
        uint32_t u = uint32_t(std::fabs(v)) * 70000u;
        std::memcpy(p, &u, 4);
        break;
      }
      case DType::kU64: {
        uint64_t u = uint64_t(std::fabs(v)) << 40;
        std::memcpy(p, &u, 8);
        break;
      }
    }
  }
  return out;
}

// Writes a container with the writer; `stop` < UINT64_MAX stops it after that many file
// mutations (as a writer killed there), `seal` false leaves it unsealed.
void WriteLtm(const std::string& path, const nlohmann::json& meta, const ltb::io::WriterOptions& wo, bool seal,
              bool sparse_data, bool zstd) {
  std::filesystem::remove(path);
  auto w = ltb::io::ContainerWriter::Open(path, meta, wo);
  if (!w.ok()) return Fail(path + ": " + w.status().ToString());
  const auto& md = w->metadata();
  for (uint32_t a = 0; a < md.arrays.size(); ++a) {
    const auto& spec = md.arrays[a];
    for (uint64_t c = 0; c < spec.ChunkCount(); ++c) {
      ltb::format::EncodeOptions eo;
      eo.zstd = zstd;
      eo.sparse = true;
      eo.dtype = spec.dtype;
      const bool zero = sparse_data && c == 1;  // one all-zero chunk per array
      std::vector<std::byte> data = TestChunk(spec.dtype, spec.Extent(c).Elements(), c + a, sparse_data);
      if (zero) std::fill(data.begin(), data.end(), std::byte{0});
      if (!w->Put(a, c, data, eo).ok()) return;  // a stopped writer: expected
    }
  }
  if (seal) (void)w->Finish();
}

// An i32 `cols` matrix of 8 x 8 image columns like quantize's: few nonzeros, denser and
// larger near the corner, neighbouring columns alike; stored sparse-coded.
void CodedColumnsSeed(const std::string& path) {
  std::filesystem::remove(path);
  nlohmann::json meta = {{"arrays", {Array("matrix", "i32", 64, 24, "cols", 8)}}};
  auto w = ltb::io::ContainerWriter::Open(path, meta);
  if (!w.ok()) return Fail(path + ": " + w.status().ToString());
  ltb::format::EncodeOptions eo;
  eo.sparse = true;
  eo.zstd = true;
  eo.coded = true;
  eo.coded_width = 8;
  for (uint64_t c = 0; c < 3; ++c) {
    std::vector<int32_t> v(64 * 8, 0);
    for (uint64_t k = 0; k < 8; ++k)
      for (uint64_t p = 0; p < 64; ++p) {
        const uint64_t x = p % 8, y = p / 8, h = (p * 131 + (k / 2) * 7 + c * 3) % 29;
        if (h < 12 / (1 + x + y)) v[k * 64 + p] = int32_t((h % 2 ? -1 : 1) * int64_t(1 + h * (8 - x)));
      }
    ltb::Status s = w->Put(0, c, ltb::format::ByteSpan(reinterpret_cast<const std::byte*>(v.data()), 4 * v.size()), eo);
    if (!s.ok()) return Fail(path + ": " + s.ToString());
  }
  if (ltb::Status s = w->Finish(); !s.ok()) Fail(path + ": " + s.ToString());
}

void LtmSeeds(const std::string& dir) {
  fs::create_directories(dir);
  ltb::io::WriterOptions direct;
  direct.direct_io = true;
  direct.direct_min_bytes = 4096;
  nlohmann::json m = {{"arrays", {Array("matrix", "f32", 40, 32, "rows", 32), Array("mask", "u8", 40, 1, "rows", 40)}},
                      {"basis", {{"rows", {{"kind", "generic"}}}, {"cols", {{"kind", "generic"}}}}}};
  WriteLtm(dir + "/direct-padding.ltm", m, direct, true, false, false);
  WriteLtm(dir + "/direct-padding-unsealed.ltm", m, direct, false, false, false);
  nlohmann::json cols = {{"arrays", {Array("matrix", "f32", 36, 40, "cols", 30)}}};
  WriteLtm(dir + "/direct-padding-cols.ltm", cols, direct, true, false, false);

  nlohmann::json all = {{"arrays",
                         {Array("matrix", "f32", 24, 20, "rows", 8), Array("f64", "f64", 24, 6, "cols", 2),
                          Array("u8", "u8", 30, 1, "rows", 10), Array("i32", "i32", 12, 12, "cols", 4),
                          Array("u32", "u32", 12, 6, "rows", 4), Array("u64", "u64", 9, 4, "rows", 3)}}};
  ltb::io::WriterOptions plain;
  WriteLtm(dir + "/dtypes-sparse.ltm", all, plain, true, true, false);
  WriteLtm(dir + "/dtypes-sparse-zstd.ltm", all, plain, true, true, true);
  WriteLtm(dir + "/dtypes-dense-zstd.ltm", all, plain, true, false, true);
  CodedColumnsSeed(dir + "/coded-columns.ltm");
  for (uint64_t stop : {2, 5, 9, 14, 20}) {
    ltb::io::WriterOptions torn;
    torn.stop_after_mutations = stop;
    WriteLtm(dir + "/torn-" + std::to_string(stop) + ".ltm", all, torn, true, true, true);
  }
}

}  // namespace

int main(int argc, char** argv) {
  if (argc != 3) {
    std::fprintf(stderr, "usage: ltb_fuzz_seeds OUT MESH.obj\n");
    return 2;
  }
  ExrSeeds(std::string(argv[1]) + "/exr");
  MeshSeeds(std::string(argv[1]) + "/mesh", argv[2]);
  LtmSeeds(std::string(argv[1]) + "/ltm");
  return failures == 0 ? 0 : 1;
}
