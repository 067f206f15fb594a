#include "stages/mesh/mesh_reader.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <bit>
#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstring>
#include <limits>

#include "stages/mesh/mesh_text.h"

namespace ltb::mesh {

using namespace mesh_text;

namespace {

static_assert(std::endian::native == std::endian::little, "the PLY reader swaps bytes for big-endian files only");

// Appends the polygon's fan triangles, or counts it as degenerate (fewer than 3
// vertices, or a vertex repeated). `stamp[v]` holds the last polygon that used v.
void AddPolygon(const std::vector<uint32_t>& f, uint64_t face, std::vector<uint64_t>* stamp, TriangleMesh* m) {
  const size_t k = f.size();
  if (k < 3) {
    m->degenerate_dropped++;
    return;
  }
  bool repeated;
  if (k == 3) {
    repeated = f[0] == f[1] || f[1] == f[2] || f[0] == f[2];
  } else {
    if (stamp->empty()) stamp->assign(m->positions.size(), std::numeric_limits<uint64_t>::max());
    repeated = false;
    for (uint32_t v : f) {
      if ((*stamp)[v] == face) repeated = true;
      (*stamp)[v] = face;
    }
  }
  if (repeated) {
    m->degenerate_dropped++;
    return;
  }
  for (size_t i = 1; i + 1 < k; ++i) m->triangles.push_back({f[0], f[i], f[i + 1]});
}

// A colour component must be finite and >= 0 (a float one may exceed 1: it scales an
// albedo, whose product the scene checks).
bool ValidColour(double c) { return std::isfinite(c) && c >= 0; }

// A value for a message: the shortest text that reads back to it (-0.25, 1e-09, nan).
std::string Number(double d) {
  char buf[32];
  auto [p, ec] = std::to_chars(buf, buf + sizeof buf, d);
  return ec == std::errc() ? std::string(buf, p) : std::to_string(d);
}

std::string VertexRange(uint64_t nv) {
  return nv == 0 ? "the file declares no vertices"
                 : "the file declares " + std::to_string(nv) + " vertices: 0.." + std::to_string(nv - 1);
}

}  // namespace

double SrgbToLinear(double c) { return c <= 0.04045 ? c / 12.92 : std::pow((c + 0.055) / 1.055, 2.4); }

// ---- MeshInput ----

MeshInput::MeshInput(std::string_view bytes, std::string name)
    : name_(std::move(name)), data_(bytes.data()), end_(bytes.size()), size_(bytes.size()) {}

MeshInput::MeshInput(MeshInput&& o) noexcept { *this = std::move(o); }

MeshInput& MeshInput::operator=(MeshInput&& o) noexcept {
  if (this == &o) return *this;
  if (fd_ >= 0) ::close(fd_);
  name_ = std::move(o.name_);
  fd_ = o.fd_;
  o.fd_ = -1;
  progress_ = o.progress_;
  const bool own = o.data_ == o.buf_.data() && !o.buf_.empty();
  buf_ = std::move(o.buf_);
  data_ = own ? buf_.data() : o.data_;
  pos_ = o.pos_;
  end_ = o.end_;
  base_ = o.base_;
  size_ = o.size_;
  line_ = o.line_;
  return *this;
}

MeshInput::~MeshInput() {
  if (fd_ >= 0) ::close(fd_);
}

Result<MeshInput> MeshInput::Open(const std::string& path, const Progress* progress) {
  // O_NONBLOCK: opening a FIFO must not wait for a writer; fstat then refuses it.
  int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC | O_NONBLOCK);
  if (fd < 0) {
    int e = errno;
    if (e == ENOENT) return NotFound(path + ": mesh file not found");
    return IoError(path + ": cannot open the mesh file", e);
  }
  struct stat st {};
  if (::fstat(fd, &st) != 0) {
    int e = errno;
    ::close(fd);
    return IoError(path + ": cannot stat the mesh file", e);
  }
  if (!S_ISREG(st.st_mode)) {
    ::close(fd);
    const char* what = S_ISDIR(st.st_mode)    ? "a directory"
                       : S_ISFIFO(st.st_mode) ? "a FIFO (named pipe)"
                       : S_ISSOCK(st.st_mode) ? "a socket"
                       : S_ISCHR(st.st_mode)  ? "a character device"
                       : S_ISBLK(st.st_mode)  ? "a block device"
                                              : "not a regular file";
    return InvalidArgument(path + ": is " + what + ", not a mesh file; give the path of a regular file");
  }
  int flags = ::fcntl(fd, F_GETFL);
  if (flags >= 0) ::fcntl(fd, F_SETFL, flags & ~O_NONBLOCK);
  MeshInput in;
  in.name_ = path;
  in.fd_ = fd;
  in.progress_ = progress;
  in.size_ = static_cast<uint64_t>(st.st_size);
  in.buf_.resize(std::min<uint64_t>(kPiece, std::max<uint64_t>(in.size_, 1)));
  in.data_ = in.buf_.data();
  return in;
}

Status MeshInput::Fill(size_t want) {
  if (end_ - pos_ >= want || fd_ < 0) return Status::Ok();
  if (pos_ > 0) {  // keep the unread bytes at the front
    std::memmove(buf_.data(), buf_.data() + pos_, end_ - pos_);
    base_ += pos_;
    end_ -= pos_;
    pos_ = 0;
  }
  if (buf_.size() < want) buf_.resize(std::max(want, 2 * buf_.size()));
  data_ = buf_.data();
  while (end_ < want && base_ + end_ < size_) {
    if (progress_ != nullptr && progress_->Cancelled())
      return Cancelled(name_ + ": interrupted while reading the mesh");
    size_t room = static_cast<size_t>(std::min<uint64_t>(buf_.size() - end_, size_ - (base_ + end_)));
    ssize_t n = ::read(fd_, buf_.data() + end_, room);
    if (n < 0) {
      if (errno == EINTR) continue;
      return IoError(name_ + ": read failed at byte " + std::to_string(base_ + end_), errno);
    }
    if (n == 0) {  // the file shrank while we read it: what is there is all there is
      size_ = base_ + end_;
      break;
    }
    end_ += static_cast<size_t>(n);
  }
  return Status::Ok();
}

Result<bool> MeshInput::NextLine(std::string_view* line) {
  size_t scanned = pos_;
  for (;;) {
    const void* nl = scanned < end_ ? std::memchr(data_ + scanned, '\n', end_ - scanned) : nullptr;
    if (nl != nullptr) {
      size_t e = static_cast<const char*>(nl) - data_;
      *line = std::string_view(data_ + pos_, e - pos_);
      pos_ = e + 1;
      break;
    }
    if (end_ - pos_ > kMaxLine) {
      return InvalidArgument(name_ + ":" + std::to_string(line_ + 1) + ": line longer than " +
                             std::to_string(kMaxLine >> 20) + " MiB; not a mesh file?");
    }
    if (consumed() + (end_ - pos_) >= size_) {  // the last line, without '\n'
      if (pos_ == end_) return false;
      *line = std::string_view(data_ + pos_, end_ - pos_);
      pos_ = end_;
      break;
    }
    size_t have = end_ - pos_;
    LTB_RETURN_IF_ERROR(Fill(have + kPiece));
    scanned = pos_ + have;
  }
  ++line_;
  if (!line->empty() && line->back() == '\r') line->remove_suffix(1);
  return true;
}

Result<std::string_view> MeshInput::Peek(size_t n) {
  LTB_RETURN_IF_ERROR(Fill(n));
  return std::string_view(data_ + pos_, std::min(n, end_ - pos_));
}

Status MeshInput::Read(void* dst, size_t n, const std::string& what) {
  char* out = static_cast<char*>(dst);
  while (n > 0) {
    if (pos_ == end_) {
      LTB_RETURN_IF_ERROR(Fill(std::min(n, kPiece)));
      if (pos_ == end_) {
        return DataLoss(name_ + ": the file ends at byte " + std::to_string(consumed()) + " inside " + what +
                        " (truncated, or a count in the header is wrong)");
      }
    }
    size_t k = std::min(n, end_ - pos_);
    if (out != nullptr) {
      std::memcpy(out, data_ + pos_, k);
      out += k;
    }
    pos_ += k;
    n -= k;
  }
  return Status::Ok();
}

// ---- OFF ----

namespace {

// The next line that holds something other than a comment ('#' to the end of the line).
Result<bool> NextContent(MeshInput& in, std::string_view* line) {
  for (;;) {
    LTB_ASSIGN_OR_RETURN(bool have, in.NextLine(line));
    if (!have) return false;
    size_t hash = line->find('#');
    if (hash != std::string_view::npos) *line = line->substr(0, hash);
    Tokens t{*line};
    std::string_view tok;
    if (t.Next(&tok)) return true;
  }
}

}  // namespace

namespace {

// The header keyword and the counts line: the vertex and face counts, checked against the
// bytes that follow before anything is reserved.
struct OffCounts {
  uint64_t nv = 0, nf = 0;
  bool normals = false;  // NOFF: nx ny nz follow x y z on every vertex line
  bool colours = false;  // COFF: r g b [a] follow x y z (and nx ny nz) on every vertex line
};

Result<OffCounts> ReadOffHeader(MeshInput& in) {
  const std::string& name = in.name();
  auto at = [&] { return name + ":" + std::to_string(in.line()); };
  std::string_view line;
  LTB_ASSIGN_OR_RETURN(bool have, NextContent(in, &line));
  if (!have) return InvalidArgument(name + ": empty file, not an OFF mesh");
  Tokens tk{line};
  std::string_view kw;
  tk.Next(&kw);
  // [ST][C][N][4][n]OFF: a vertex line holds x y z, then nx ny nz (N), then r g b [a] (C),
  // then s t (ST), in that order (Geomview's OFF, and OpenMesh's reader).
  std::string_view k = kw;
  if (k.substr(0, 2) == "ST") k.remove_prefix(2);
  const bool colours = k.substr(0, 1) == "C";
  if (colours) k.remove_prefix(1);
  const bool normals = k.substr(0, 1) == "N";
  if (normals) k.remove_prefix(1);
  if (k == "4OFF" || k == "nOFF" || k == "4nOFF") {
    return InvalidArgument(at() + ": " + Quote(kw) +
                           ": OFF with 4-D or n-D vertices is not supported; write x y z vertices");
  }
  if (k != "OFF")
    return InvalidArgument(at() + ": expected an OFF header (\"OFF\"), found " + Quote(kw) + "; not an OFF file");
  std::string_view tok;
  std::vector<uint64_t> counts;
  bool more = tk.Next(&tok);
  if (more && tok == "BINARY") {
    return InvalidArgument(at() + ": binary OFF is not supported; convert the mesh to ASCII OFF or PLY");
  }
  Tokens ct = tk;
  if (!more) {
    LTB_ASSIGN_OR_RETURN(bool c, NextContent(in, &line));
    if (!c) return DataLoss(name + ": the file ends before the counts line \"vertices faces edges\"");
    ct = Tokens{line};
    more = ct.Next(&tok);
  }
  while (more && counts.size() < 3) {
    uint64_t v;
    if (!ParseNumber(tok, &v)) {
      return InvalidArgument(at() + ": count " + Quote(tok) +
                             " is not a non-negative integer (expected \"vertices faces edges\")");
    }
    counts.push_back(v);
    more = ct.Next(&tok);
  }
  if (counts.size() < 2) return InvalidArgument(at() + ": expected the counts \"vertices faces edges\"");
  const uint64_t nv = counts[0], nf = counts[1];
  // Every vertex line holds at least "0 0 0\n" (6 bytes), every face line a count and a
  // line end (2 bytes): a header that declares more than the file can hold is refused
  // before anything is reserved.
  if (nv > kMaxVertices) {
    return InvalidArgument(at() + ": the header declares " + std::to_string(nv) + " vertices; at most " +
                           std::to_string(kMaxVertices) + " are supported");
  }
  uint64_t need = 0;
  if (!MulAdd(nf, 2, nv * 6, &need) || need > in.remaining() + 1) {
    return DataLoss(at() + ": the header declares " + std::to_string(nv) + " vertices and " + std::to_string(nf) +
                    " faces, which need at least " + Bytes(need) + " bytes, but only " +
                    std::to_string(in.remaining()) + " follow the header (truncated, or a wrong count)");
  }
  return OffCounts{nv, nf, normals, colours};
}

// COFF: the r g b [a] of vertex i (after x y z and nx ny nz) as linear RGB. Three integers
// are 8-bit sRGB (0..255); otherwise (a decimal point or an exponent) linear floats.
Status ParseOffColour(Tokens& t, uint64_t i, const MeshInput& in, glm::dvec3* out) {
  auto at = [&] { return in.name() + ":" + std::to_string(in.line()); };
  std::string_view tok[3];
  bool ints = true;
  int64_t n[3] = {0, 0, 0};
  for (int c = 0; c < 3; ++c) {
    if (!t.Next(&tok[c])) {
      return InvalidArgument(at() + ": vertex " + std::to_string(i) + " colour component " + std::to_string(c + 1) +
                             " is missing (COFF: x y z [nx ny nz] r g b [a] on every vertex line)");
    }
    ints = ints && ParseNumber(tok[c], &n[c]);
  }
  for (int c = 0; c < 3; ++c) {
    auto bad = [&](const std::string& why) {
      return InvalidArgument(at() + ": vertex " + std::to_string(i) + " colour component " + std::to_string(c + 1) +
                             " is " + Quote(tok[c]) + why);
    };
    if (ints) {
      if (n[c] < 0) return bad("; a colour component must be >= 0");
      if (n[c] > 255) {
        return bad(
            ", above 255 (three integers are 8-bit sRGB, 0..255; write linear floats with a decimal "
            "point, e.g. 0.5)");
      }
      (*out)[c] = SrgbToLinear(static_cast<double>(n[c]) / 255);
      continue;
    }
    double d;
    if (!ParseNumber(tok[c], &d)) return bad(", not a number (COFF: r g b [a] after x y z [nx ny nz])");
    if (!ValidColour(d)) return bad("; a colour component must be finite and >= 0");
    (*out)[c] = d;
  }
  return Status::Ok();
}

// The nv vertex lines into m->positions (sized), their normals into m->file_normals when
// it is sized (NOFF, and asked for) and their colours into m->colours when it is sized
// (COFF, and asked for).
Status ReadOffVertices(MeshInput& in, const OffCounts& counts, const Progress& progress, TriangleMesh* m) {
  const std::string& name = in.name();
  const uint64_t nv = counts.nv;
  const bool skip_normals = counts.normals && m->file_normals.empty();
  auto at = [&] { return name + ":" + std::to_string(in.line()); };
  std::string_view line, tok;
  for (uint64_t i = 0; i < nv; ++i) {
    if ((i & 0xFFFF) == 0xFFFF && progress.Cancelled()) return Cancelled(name + ": interrupted while reading the mesh");
    LTB_ASSIGN_OR_RETURN(bool ok, NextContent(in, &line));
    if (!ok) {
      return DataLoss(name + ": the file ends after " + std::to_string(i) + " of the " + std::to_string(nv) +
                      " vertices the header declares (truncated, or a wrong count)");
    }
    Tokens t{line};
    float p[3];
    for (int c = 0; c < 3; ++c) {
      if (!t.Next(&tok))
        return InvalidArgument(at() + ": vertex " + std::to_string(i) + " has fewer than 3 coordinates");
      if (!ParseNumber(tok, &p[c]) || !std::isfinite(p[c])) {
        return InvalidArgument(at() + ": vertex " + std::to_string(i) + " coordinate " + std::to_string(c + 1) +
                               " is " + Quote(tok) + ", not a finite number; fix or remove the vertex");
      }
    }
    m->positions[i] = {p[0], p[1], p[2]};
    if (!m->file_normals.empty()) {
      float n[3];
      for (int c = 0; c < 3; ++c) {
        tok = {};
        if (!t.Next(&tok) || !ParseNumber(tok, &n[c])) {
          return InvalidArgument(at() + ": vertex " + std::to_string(i) + " normal component " + std::to_string(c + 1) +
                                 " is " + (tok.empty() ? std::string("missing") : Quote(tok)) +
                                 " (NOFF: x y z nx ny nz on every vertex line)");
        }
      }
      m->file_normals[i] = {n[0], n[1], n[2]};
    } else if (skip_normals) {
      for (int c = 0; c < 3; ++c) t.Next(&tok);  // CNOFF without normals asked for: r g b follow them
    }
    if (!m->colours.empty()) LTB_RETURN_IF_ERROR(ParseOffColour(t, i, in, &m->colours[i]));
  }
  return Status::Ok();
}

// The nf face lines, each polygon fanned into m->triangles (or counted as degenerate).
Status ReadOffFaces(MeshInput& in, uint64_t nv, uint64_t nf, const Progress& progress, TriangleMesh* m) {
  const std::string& name = in.name();
  auto at = [&] { return name + ":" + std::to_string(in.line()); };
  std::string_view line, tok;
  std::vector<uint32_t> face;
  std::vector<uint64_t> stamp;
  for (uint64_t f = 0; f < nf; ++f) {
    if ((f & 0xFFFF) == 0xFFFF && progress.Cancelled()) return Cancelled(name + ": interrupted while reading the mesh");
    LTB_ASSIGN_OR_RETURN(bool ok, NextContent(in, &line));
    if (!ok) {
      return DataLoss(name + ": the file ends after " + std::to_string(f) + " of the " + std::to_string(nf) +
                      " faces the header declares (truncated, or a wrong count)");
    }
    Tokens t{line};
    uint64_t n = 0;
    t.Next(&tok);
    if (!ParseNumber(tok, &n)) {
      return InvalidArgument(at() + ": face " + std::to_string(f) + ": vertex count " + Quote(tok) +
                             " is not a non-negative integer");
    }
    if (n > line.size()) {
      return InvalidArgument(at() + ": face " + std::to_string(f) + " declares " + std::to_string(n) +
                             " vertices but its line is " + std::to_string(line.size()) + " bytes long");
    }
    face.clear();
    for (uint64_t j = 0; j < n; ++j) {
      uint64_t v;
      if (!t.Next(&tok)) {
        return InvalidArgument(at() + ": face " + std::to_string(f) + " declares " + std::to_string(n) +
                               " vertices but lists " + std::to_string(j));
      }
      if (!ParseNumber(tok, &v)) {
        return InvalidArgument(at() + ": face " + std::to_string(f) + ": vertex index " + Quote(tok) +
                               " is not a non-negative integer");
      }
      if (v >= nv) {
        return InvalidArgument(at() + ": face " + std::to_string(f) + ": vertex index " + std::to_string(v) +
                               " is out of range (" + VertexRange(nv) + "); fix the face or the vertex count");
      }
      face.push_back(static_cast<uint32_t>(v));
    }
    AddPolygon(face, f, &stamp, m);
  }
  return Status::Ok();
}

}  // namespace

Result<TriangleMesh> ReadOff(MeshInput& in, const Progress& progress, bool normals, bool colours) {
  LTB_ASSIGN_OR_RETURN(const OffCounts counts, ReadOffHeader(in));
  TriangleMesh m;
  m.positions.resize(counts.nv);
  if (normals && counts.normals) m.file_normals.resize(counts.nv);
  if (colours && counts.colours) m.colours.resize(counts.nv);
  m.triangles.reserve(counts.nf);
  LTB_RETURN_IF_ERROR(ReadOffVertices(in, counts, progress, &m));
  LTB_RETURN_IF_ERROR(ReadOffFaces(in, counts.nv, counts.nf, progress, &m));
  return m;
}

// ---- PLY ----

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
