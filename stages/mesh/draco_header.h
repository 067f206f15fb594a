// The counts a Draco mesh file declares, read before libdraco decodes it.
//
// libdraco sizes its connectivity tables from the face count in the header before it has
// decoded a single symbol: a 548-byte file declaring 16.8 million faces made it take
// ~400 MB before failing (fuzzing, docs/FUZZING.md). ReadDracoCounts walks the same
// fields libdraco reads first (header, optional metadata, the edgebreaker or sequential
// connectivity header, in every bitstream version libdraco 1.5 accepts) so a count that no
// file of this size can hold is refused before any table exists.
#pragma once

#include <cstdint>
#include <optional>
#include <span>
#include <string>

#include "format/status.h"

namespace ltb::mesh {

struct DracoCounts {
  int version_major = 0, version_minor = 0;
  int method = 0;               // 0 sequential, 1 edgebreaker
  uint32_t faces = 0;           // declared faces
  uint32_t vertices = 0;        // declared points (sequential) or encoded vertices (edgebreaker)
  uint32_t extra_vertices = 0;  // edgebreaker: split symbols (and new vertices before 2.2)
};

// The counts, or nullopt when the bytes end or are not a mesh before the counts: libdraco
// stops at the same place, before it allocates by them, and reports its own error.
std::optional<DracoCounts> ReadDracoCounts(std::span<const unsigned char> file);

// The most faces a Draco file may declare per byte of file. A regular 1000 × 1000 grid
// (2 million faces) encoded by draco_encoder 1.5.5 at -cl 10 takes 38 faces per byte with
// 11-bit positions and 684 with 1-bit ones, the most compressible mesh we could make.
inline constexpr uint64_t kDracoMaxFacesPerByte = 1024;

// InvalidArgument naming `path` and the counts when they exceed kDracoMaxFacesPerByte
// times the file's size (vertices count as faces: each face has at most three).
Status CheckDracoCounts(const std::string& path, std::span<const unsigned char> file);

}  // namespace ltb::mesh
