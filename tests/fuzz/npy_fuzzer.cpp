// libFuzzer target: any byte string as a .npy file. Parses the header from the bytes
// (format/npy.h), then converts the file to an .ltm with `convert` (stages/convert), which
// opens the file, checks the header against its size and reads every value (float32 and
// float64, checking the float32 range). None of it may crash, hang or leak.
// Build and run: docs/FUZZING.md.
#include <cstddef>
#include <cstdint>
#include <string>

#include "format/npy.h"
#include "stages/convert/convert.h"
#include "tests/fuzz/fuzz_file.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  (void)ltb::format::ParseNpyHeader(ltb::format::ByteSpan(reinterpret_cast<const std::byte*>(data), size));
  const std::string path = ltb::fuzz::WriteFile("input.npy", data, size);
  if (path.empty()) return 0;
  ltb::stages::ConvertOptions o;
  o.input = path;
  o.output = ltb::fuzz::TempDir() + "/output.ltm";
  o.jobs = 1;
  o.mem_limit = 64ull << 20;
  o.chunk_bytes = 4096;  // several chunks even for small inputs
  o.overwrite = true;
  (void)ltb::stages::RunConvert(o, ltb::Progress{});
  return 0;
}
