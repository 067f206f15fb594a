// libFuzzer target: any byte string as a recipe (docs/RECIPE.md) read by ParseRecipe
// (pipeline/recipe.h); when it holds an inline [scene] table, the scene it writes out is
// parsed as `ltbake run` does. At start-up the directory holds the files seeds name: a
// scene (tiny.toml) and two environment maps (sky.hdr, sky.exr; the recipe parser only
// checks that they exist). None of it may crash, hang or leak.
// Build and run: docs/FUZZING.md.
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <string>

#include "pipeline/recipe.h"
#include "stages/sample/scene.h"
#include "tests/fuzz/fuzz_file.h"

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  ltb::fuzz::WriteFile("tiny.toml",
                       "[camera]\neye = [0.0, -3.0, 2.0]\n[[object]]\ntype = \"plane\"\nsize = [4.0, 4.0]\n");
  ltb::fuzz::WriteFile("sky.hdr", "#?RADIANCE\n");
  ltb::fuzz::WriteFile("sky.exr", "v/1\x01");
  setenv("LTB_FUZZ_DIR", ltb::fuzz::TempDir().c_str(), 1);  // for "${LTB_FUZZ_DIR}" in seeds
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string path = ltb::fuzz::WriteFile("recipe.toml", data, size);
  if (path.empty()) return 0;
  auto recipe = ltb::pipeline::ParseRecipe(path);
  if (!recipe.ok() || recipe->inline_scene.empty()) return 0;
  const std::string scene = ltb::fuzz::WriteFile("inline-scene.toml", recipe->inline_scene);
  if (!scene.empty()) (void)ltb::sample::ParseScene(scene);
  return 0;
}
