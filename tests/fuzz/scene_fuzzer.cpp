// libFuzzer target: any byte string as a scene file (docs/SCENE.md) read by ParseScene
// (stages/sample/scene.h), which checks every key and value. Mesh files are named, not
// loaded, by the parser (the mesh formats have their own targets), so nothing outside the
// input is read. None of it may crash, hang or leak.
// Build and run: docs/FUZZING.md.
#include <cstddef>
#include <cstdint>
#include <string>

#include "stages/sample/scene.h"
#include "tests/fuzz/fuzz_file.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string path = ltb::fuzz::WriteFile("scene.toml", data, size);
  if (path.empty()) return 0;
  (void)ltb::sample::ParseScene(path);
  return 0;
}
