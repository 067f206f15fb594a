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

namespace mesh_text {

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

}  // namespace mesh_text

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

}  // namespace ltb::mesh
