// libFuzzer target: any byte string as an .ltm file (a container of any kind, or a stage
// manifest). Opens it, reads every committed chunk (dense and sparse), summarizes every
// array, runs verify, and for a small complete matrix converts it to a dense .npy (which
// decodes column-transformed, quantized and cpca outputs). None of it may crash, hang or
// leak.
//
// The input is written to <tmp>/input.ltm. For manifests to reach their shards, set
// LTB_FUZZ_AUX to a directory whose contents (e.g. m.shards/00000-of-00002.ltm, written by
// scripts/fuzz_corpus.sh) are copied beside it at start-up.
// Build and run: docs/FUZZING.md.
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <filesystem>
#include <string>

#include "format/io/array_summary.h"
#include "format/io/container_reader.h"
#include "format/io/verifier.h"
#include "stages/convert/convert.h"
#include "tests/fuzz/fuzz_file.h"

namespace {

// Dense conversion only for matrices this small (a valid all-zero-chunk container may
// declare a huge shape in a few bytes; writing that out is not a reader bug).
constexpr uint64_t kMaxConvertBytes = 4ull << 20;

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
  return 0;
}
