// libFuzzer target: any byte string as an .ltm file (a container of any kind, or a stage
// manifest). Opens it, reads every committed chunk (dense and sparse), summarizes every
// array, runs verify, and for a small complete matrix converts it to a dense .npy (which
// decodes column-transformed, quantized and cpca outputs). None of it may crash, hang or
// leak.
//
// Every checksum stops a random mutation at the first frame it touches, so each input is
// read twice: as given (the checksum paths) and, when that differs, with every checksum
// recomputed (RepairChecksums, after docs/FORMAT.md): the header's, the metadata's, each
// frame's payload and header checksum, the index entries' copies of the frame headers and
// the trailer's. That lets mutations of the metadata JSON, frame fields and payloads reach
// the parsers and decoders behind the checks.
//
// The input is written to <tmp>/input.ltm. For manifests to reach their shards, set
// LTB_FUZZ_AUX to a directory whose contents (e.g. m.shards/00000-of-00002.ltm, written by
// scripts/fuzz_corpus.sh) are copied beside it at start-up.
// Build and run: docs/FUZZING.md.
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <string>
#include <vector>

#include "format/bytes.h"
#include "format/io/array_summary.h"
#include "format/io/container_reader.h"
#include "format/io/verifier.h"
#include "stages/convert/convert.h"
#include "tests/fuzz/fuzz_file.h"

namespace {

// Dense conversion only for matrices this small (a valid all-zero-chunk container may
// declare a huge shape in a few bytes; writing that out is not a reader bug).
constexpr uint64_t kMaxConvertBytes = 4ull << 20;

using ltb::format::Checksum;
using ltb::format::LoadU16;
using ltb::format::LoadU32;
using ltb::format::LoadU64;
using ltb::format::StoreU64;

uint64_t Sum(const std::vector<std::byte>& b, uint64_t offset, uint64_t length) {
  return Checksum(ltb::format::ByteSpan(b.data() + offset, length));
}

uint64_t RoundUp64(uint64_t n) { return (n + 63) / 64 * 64; }

// Recomputes every checksum a container holds (see the comment at the top). Returns false
// when the bytes do not start like a container.
bool RepairChecksums(std::vector<std::byte>* bytes) {
  std::vector<std::byte>& b = *bytes;
  const uint64_t size = b.size();
  static const unsigned char kMagic[8] = {0x89, 'L', 'T', 'M', '\r', '\n', 0x1a, '\n'};
  if (size < 64 || std::memcmp(b.data(), kMagic, 8) != 0) return false;
  const uint64_t meta_len = LoadU64(b.data() + 32);
  if (meta_len <= size - 64) StoreU64(b.data() + 40, Sum(b, 64, meta_len));
  StoreU64(b.data() + 56, Sum(b, 0, 56));
  if (meta_len > size) return true;
  // Frames, from the first 64-byte boundary after the metadata.
  struct Frame {
    uint64_t offset;
    uint16_t type;
    uint64_t payload_length;
  };
  std::vector<Frame> frames;
  uint64_t off = 64 + RoundUp64(meta_len);
  while (off <= size && size - off >= 64 && LoadU32(b.data() + off) == 0x464d544c /* "LTMF" */) {
    const uint64_t pl = LoadU64(b.data() + off + 8);
    if (pl > size - off - 64) break;
    frames.push_back({off, LoadU16(b.data() + off + 4), pl});
    off += 64 + RoundUp64(pl);
  }
  auto fix_frame = [&](const Frame& f) {
    StoreU64(b.data() + f.offset + 40, Sum(b, f.offset + 64, f.payload_length));
    StoreU64(b.data() + f.offset + 56, Sum(b, f.offset, 56));
  };
  for (const Frame& f : frames)
    if (f.type != 2) fix_frame(f);
  // Index frames: each entry's copy of its frame header, then the index's own checksums.
  for (const Frame& f : frames) {
    if (f.type != 2 || f.payload_length < 8) continue;
    const uint64_t count = LoadU64(b.data() + f.offset + 64);
    for (uint64_t i = 0; i < count && 8 + (i + 1) * 72 <= f.payload_length; ++i) {
      std::byte* entry = b.data() + f.offset + 64 + 8 + i * 72;
      const uint64_t target = LoadU64(entry);
      for (const Frame& g : frames) {
        if (g.offset == target && g.type != 2) {
          std::memcpy(entry + 8, b.data() + g.offset, 64);
          break;
        }
      }
    }
    fix_frame(f);
  }
  // The trailer: the last 64 bytes.
  if (size >= 128 && std::memcmp(b.data() + size - 64, "LTMTRAIL", 8) == 0) {
    StoreU64(b.data() + size - 8, Sum(b, size - 64, 56));
  }
  return true;
}

// Reads the container (or manifest) at `path` every way a reader does.
void ReadAll(const std::string& path) {
  bool convert = false;
  {
    auto reader = ltb::io::ContainerReader::Open(path);
    if (reader.ok()) {
      for (const auto& e : reader->chunk_frames()) {
        (void)reader->ReadChunk(e.header.array, e.header.chunk_index);
        (void)reader->ReadSparse(e.header.array, e.header.chunk_index);
      }
      for (uint32_t a = 0; a < reader->metadata().arrays.size(); ++a) (void)ltb::io::SummarizeArray(*reader, a, 1);
      if (reader->complete() && !reader->metadata().arrays.empty()) {
        const auto& spec = reader->metadata().arrays[0];
        convert = spec.rows != 0 && spec.cols != 0 && spec.rows <= kMaxConvertBytes / 4 / spec.cols;
      }
    }
  }
  (void)ltb::io::VerifyContainer(path);
  if (convert) {
    ltb::stages::ConvertOptions o;
    o.input = path;
    o.output = ltb::fuzz::TempDir() + "/output.npy";
    o.jobs = 1;
    o.mem_limit = 64ull << 20;
    o.overwrite = true;
    (void)ltb::stages::RunConvert(o, ltb::Progress{});
  }
}

}  // namespace

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  if (const char* aux = std::getenv("LTB_FUZZ_AUX")) {
    std::error_code ec;
    std::filesystem::copy(aux, ltb::fuzz::TempDir(),
                          std::filesystem::copy_options::recursive | std::filesystem::copy_options::overwrite_existing,
                          ec);
  }
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string path = ltb::fuzz::WriteFile("input.ltm", data, size);
  if (path.empty()) return 0;
  ReadAll(path);
  std::vector<std::byte> fixed(reinterpret_cast<const std::byte*>(data),
                               reinterpret_cast<const std::byte*>(data) + size);
  if (RepairChecksums(&fixed) && std::memcmp(fixed.data(), data, size) != 0) {
    if (ltb::fuzz::WriteFile("input.ltm", fixed.data(), fixed.size()).empty()) return 0;
    ReadAll(path);
  }
  return 0;
}
