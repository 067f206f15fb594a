// libFuzzer target: any byte string as an environment map, written to a file with the
// extension LTB_FUZZ_EXT (".hdr": ltbake's Radiance RGBE reader; ".exr": OpenEXR through
// its library). LoadEnvMap reads it (the format by its magic bytes, the layout from the
// size: lat-long, crosses, with clamping so more maps reach the next step); a map that loads
// is resampled to a small cubemap (R = 4), as relight and convert do, within a memory
// limit of 512 MiB. None of it may crash, hang, leak or allocate past the limit.
// Build and run: docs/FUZZING.md.
#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "stages/images/envmap.h"
#include "tests/fuzz/fuzz_file.h"

#ifndef LTB_FUZZ_EXT
#error "define LTB_FUZZ_EXT (\".hdr\" or \".exr\")"
#endif

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string path = ltb::fuzz::WriteFile(std::string("input") + LTB_FUZZ_EXT, data, size);
  if (path.empty()) return 0;
  ltb::stages::EnvLoadOptions options;
  options.clamp = true;
  // As the CLI passes its --mem-limit (default 1 GiB): half the fuzzer's -malloc_limit_mb,
  // so what the limit allows also fits in the fuzzer's.
  options.max_bytes = uint64_t(512) << 20;
  auto env = ltb::stages::LoadEnvMap(path, options);
  if (!env.ok()) return 0;
  constexpr uint64_t kR = 4;
  auto resampler = ltb::stages::CubemapResampler::Create(*env, kR);
  if (!resampler.ok()) return 0;
  std::vector<float> cube(6 * kR * kR * 3);
  resampler->Resample(0.7, cube.data());
  return 0;
}
