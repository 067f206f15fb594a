#include "stages/mesh/draco_header.h"

#include <cstring>

namespace ltb::mesh {
namespace {

// Bitstream versions as libdraco compares them: major * 256 + minor.
constexpr int Version(int major, int minor) { return major * 256 + minor; }

// Reads Draco's primitive fields from a byte span; every read fails at the end of it.
class Cursor {
 public:
  explicit Cursor(std::span<const unsigned char> b) : b_(b) {}
  bool U8(uint32_t* v) {
    if (pos_ >= b_.size()) return false;
    *v = b_[pos_++];
    return true;
  }
  bool U16(uint32_t* v) {
    if (b_.size() - pos_ < 2) return false;
    *v = uint32_t(b_[pos_]) | uint32_t(b_[pos_ + 1]) << 8;
    pos_ += 2;
    return true;
  }
  bool U32(uint32_t* v) {
    if (b_.size() - pos_ < 4) return false;
    *v = 0;
    for (int i = 3; i >= 0; --i) *v = *v << 8 | b_[pos_ + i];
    pos_ += 4;
    return true;
  }
  // Draco's unsigned varint: 7 bits per byte, low group first, the high bit says another
  // byte follows; the value is kept modulo 2^32 as libdraco's uint32 arithmetic keeps it.
  bool Varint(uint32_t* v) {
    uint64_t value = 0;
    int shift = 0;
    for (;;) {
      uint32_t byte;
      if (!U8(&byte)) return false;
      if (shift < 32) value |= uint64_t(byte & 0x7f) << shift;
      shift += 7;
      if (!(byte & 0x80)) break;
    }
    *v = static_cast<uint32_t>(value);
    return true;
  }
  bool Skip(uint64_t n) {
    if (b_.size() - pos_ < n) return false;
    pos_ += n;
    return true;
  }
  size_t remaining() const { return b_.size() - pos_; }

 private:
  std::span<const unsigned char> b_;
  size_t pos_ = 0;
};

// A count field: uint32 before version 2.0 (or 2.2, `varint_from`), a varint from then on.
bool Count(Cursor& c, int version, int varint_from, uint32_t* v) {
  return version < varint_from ? c.U32(v) : c.Varint(v);
}

// One metadata node: entries (name, value), then the number of child nodes. A child starts
// with its name. libdraco walks the tree depth first; every node reads the same fields in
// any order, so counting the nodes still to read walks the same bytes.
bool SkipMetadata(Cursor& c) {
  uint64_t pending = 1;
  bool root = true;
  while (pending > 0) {
    --pending;
    uint32_t len, n;
    if (!root && (!c.U8(&len) || !c.Skip(len))) return false;  // child's name
    root = false;
    if (!c.Varint(&n)) return false;
    for (uint32_t i = 0; i < n; ++i) {
      uint32_t size;
      if (!c.U8(&len) || !c.Skip(len) || !c.Varint(&size) || size == 0 || !c.Skip(size)) return false;
    }
    if (!c.Varint(&n) || n > c.remaining()) return false;
    pending += n;
  }
  return true;
}

}  // namespace

std::optional<DracoCounts> ReadDracoCounts(std::span<const unsigned char> file) {
  Cursor c(file);
  if (file.size() < 5 || std::memcmp(file.data(), "DRACO", 5) != 0) return std::nullopt;
  c.Skip(5);
  uint32_t major, minor, type, method, flags;
  if (!c.U8(&major) || !c.U8(&minor) || !c.U8(&type) || !c.U8(&method) || !c.U16(&flags)) return std::nullopt;
  // Only triangle meshes (type 1) of mesh bitstream versions 1.x and 2.0–2.2 decode.
  if (type != 1 || major < 1 || major > 2 || (major == 2 && minor > 2) || method > 1) return std::nullopt;
  const int version = Version(int(major), int(minor));
  DracoCounts out;
  out.version_major = int(major);
  out.version_minor = int(minor);
  out.method = int(method);
  if (version >= Version(1, 3) && (flags & 0x8000)) {
    uint32_t attributes, id;
    if (!c.Varint(&attributes)) return std::nullopt;
    for (uint32_t i = 0; i < attributes; ++i) {
      if (!c.Varint(&id) || !SkipMetadata(c)) return std::nullopt;
    }
    if (!SkipMetadata(c)) return std::nullopt;
  }
  if (method == 0) {  // sequential: faces, points
    if (!Count(c, version, Version(2, 2), &out.faces) || !Count(c, version, Version(2, 2), &out.vertices)) {
      return std::nullopt;
    }
    return out;
  }
  uint32_t traversal;  // edgebreaker: traversal kind, [new vertices], vertices, faces, ...
  if (!c.U8(&traversal)) return std::nullopt;
  if (version < Version(2, 2) && !Count(c, version, Version(2, 0), &out.extra_vertices)) return std::nullopt;
  if (!Count(c, version, Version(2, 0), &out.vertices) || !Count(c, version, Version(2, 0), &out.faces)) {
    return std::nullopt;
  }
  uint32_t attribute_data, symbols, splits;
  if (!c.U8(&attribute_data) || !Count(c, version, Version(2, 0), &symbols) ||
      !Count(c, version, Version(2, 0), &splits)) {
    return out;  // libdraco stops here too, but after the faces: check what was read
  }
  out.extra_vertices += splits;
  return out;
}

Status CheckDracoCounts(const std::string& path, std::span<const unsigned char> file) {
  std::optional<DracoCounts> counts = ReadDracoCounts(file);
  if (!counts) return Status::Ok();  // libdraco fails on the same bytes before allocating
  const uint64_t limit = kDracoMaxFacesPerByte * file.size();
  const uint64_t vertices = uint64_t(counts->vertices) + counts->extra_vertices;
  if (counts->faces <= limit && vertices <= 3 * limit) return Status::Ok();
  return InvalidArgument(
      path + ": the Draco header (bitstream " + std::to_string(counts->version_major) + "." +
      std::to_string(counts->version_minor) + ", " + (counts->method == 0 ? "sequential" : "edgebreaker") +
      ") declares " + std::to_string(counts->faces) + " faces and " + std::to_string(vertices) +
      " vertices in a file of " + std::to_string(file.size()) + " bytes; no Draco encoding packs more than " +
      std::to_string(kDracoMaxFacesPerByte) + " faces per byte, so the file is corrupt (re-export or re-encode it)");
}

}  // namespace ltb::mesh
