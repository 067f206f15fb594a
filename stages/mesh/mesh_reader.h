// Our own mesh readers for OFF (ASCII), PLY (ascii, binary_little_endian,
// binary_big_endian), OBJ (obj_reader.cpp) and STL (binary and ASCII, stl_reader.cpp):
// one pass over the bytes, memory bounded by what the file can hold (declared counts are checked against its length
// before anything is reserved), strict (an out-of-range vertex index, a truncated body or a non-finite coordinate is an
// error naming the file, the line or element and the value) and interruptible (every 1 MiB read asks
// Progress::Cancelled). docs/SCENE.md "Mesh files" states what they accept.
#pragma once

#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

#include "format/progress.h"
#include "format/status.h"
#include "stages/mesh/triangle_mesh.h"

namespace ltb::mesh {

// Bytes of a mesh file, read in pieces (a regular file), or bytes already in memory
// (tests, fuzzers). Lines end at '\n'; a trailing '\r' is dropped.
class MeshInput {
 public:
  // Opens a regular file; a directory, FIFO, socket or device is refused by name (opening
  // never blocks).
  static Result<MeshInput> Open(const std::string& path, const Progress* progress);
  MeshInput(std::string_view bytes, std::string name);
  MeshInput(MeshInput&&) noexcept;
  MeshInput& operator=(MeshInput&&) noexcept;
  MeshInput(const MeshInput&) = delete;
  ~MeshInput();

  const std::string& name() const { return name_; }
  uint64_t size() const { return size_; }
  uint64_t consumed() const { return base_ + pos_; }
  uint64_t remaining() const { return size_ - consumed(); }
  uint64_t line() const { return line_; }  // number of the line NextLine returned last

  // The next line (without '\n' / '\r'); false at the end of the input.
  Result<bool> NextLine(std::string_view* line);
  // The next min(n, remaining()) bytes without consuming them (valid until the next call).
  Result<std::string_view> Peek(size_t n);
  // Exactly n bytes into dst (nullptr: skip them); DataLoss naming `what` when the input ends first.
  Status Read(void* dst, size_t n, const std::string& what);

 private:
  MeshInput() = default;
  // Makes at least `want` bytes available from pos_ (fewer at the end of the file).
  Status Fill(size_t want);

  std::string name_;
  int fd_ = -1;
  const Progress* progress_ = nullptr;
  std::vector<char> buf_;
  const char* data_ = nullptr;  // buf_.data() for files, the caller's bytes otherwise
  size_t pos_ = 0, end_ = 0;    // unread bytes are data_[pos_, end_)
  uint64_t base_ = 0;           // file offset of data_[0]
  uint64_t size_ = 0;
  uint64_t line_ = 0;
};

// Vertex positions as float (as the file stores them, or rounded from double), polygons
// fan-triangulated (v0, vi, vi+1) in file order. Faces with fewer than 3 vertices or a
// repeated vertex are dropped and counted in degenerate_dropped. Vertices keep their file
// order and ids (vertex mode rows). The mesh is not yet Finalized. With `normals`, the
// normals the file stores go into file_normals, as stored (not normalised): OFF when the
// header is NOFF (nx ny nz after x y z), PLY the vertex properties nx ny nz; left empty
// when the file has none (LoadMeshFile reports that). Without, they are not kept.
// With `colours`, the vertex colours go into m.colours as linear RGB (left empty when the
// file has none): OFF when the header has the C prefix ([ST][C][N]OFF: r g b [a] after
// x y z and after nx ny nz; three integers are 8-bit sRGB, otherwise linear floats), PLY
// the vertex properties red green blue (or diffuse_red diffuse_green diffuse_blue, or
// r g b): an integer type is divided by its largest value and sRGB-decoded, a float type
// is linear as stored. A component that is negative, not finite, or (OFF) malformed,
// missing or an integer above 255 is an error naming the file, the line or byte, the
// vertex and the value.
Result<TriangleMesh> ReadOff(MeshInput& in, const Progress& progress, bool normals = false, bool colours = false);
Result<TriangleMesh> ReadPly(MeshInput& in, const Progress& progress, bool normals = false, bool colours = false);
// OBJ: `v x y z [w]` and `f` with i, i/t, i//n or i/t/n references (1-based, or negative
// counting back from the last vertex read); every other statement is skipped. A repeated
// vertex is removed from a face (keeping the first), as OpenMesh did; a face left with
// fewer than 3 is dropped and counted. A face with fewer than 3 references, an index 0 or
// out of range, or a malformed reference is an error naming the line, the face and the
// value. With `normals`, `vn` statements are kept and each vertex gets the sum of the
// distinct normals its face references name (i//n, i/t/n), each normalised first; a
// normal index must name a `vn` defined before the face (or count back from the last);
// a vertex no reference gives a normal keeps (0, 0, 0), which LoadMeshFile reports.
// With `colours`, a `v` with exactly 6 numbers is `v x y z r g b`, a linear colour as
// stored (finite, >= 0); if some vertices have one, every vertex must (else an error
// naming the line of the first vertex without); if none has, m.colours stays empty.
// With `groups`, `usemtl NAME` statements (NAME: the rest of the statement, trimmed; a
// usemtl without one is an error naming the line) select the group of the faces that
// follow: m.group_names, m.group_lines and m.triangle_group (geometry.h), group 0 "" for
// the faces before any usemtl. Without, usemtl is skipped like any other statement.
Result<TriangleMesh> ReadObj(MeshInput& in, const Progress& progress, bool normals = false, bool colours = false,
                             bool groups = false);
// STL, binary (84 + 50·n bytes exactly) or ASCII (starting with "solid"). Vertices with
// equal coordinates are merged in order of first appearance; a triangle whose corners
// merge is dropped and counted.
Result<TriangleMesh> ReadStl(MeshInput& in, const Progress& progress);

// The sRGB transfer function (EOTF), encoded c in [0, 1] to linear: c / 12.92 for
// c <= 0.04045, ((c + 0.055) / 1.055)^2.4 above. How 8-bit (integer) colours are read.
double SrgbToLinear(double c);

}  // namespace ltb::mesh
