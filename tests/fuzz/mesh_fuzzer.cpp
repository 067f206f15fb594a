// libFuzzer target: any byte string as a mesh file with the extension LTB_FUZZ_EXT (".off",
// ".ply", ".obj", ".stl" through OpenMesh; ".drc" through Draco), loaded as `sample` loads
// a scene's mesh: LoadMeshFile (stages/mesh/triangle_mesh.h) reads, triangulates, checks the
// coordinates and computes normals; a mesh that loads is transformed as an object is. Each
// input is read as `normals = "file"` reads it (the normals the file stores) and, when that
// fails, positions only. None of it may crash, hang or leak.
// Build and run: docs/FUZZING.md.
#include <cstddef>
#include <cstdint>
#include <string>

#include "stages/mesh/triangle_mesh.h"
#include "stages/sample/scene_geometry.h"
#include "tests/fuzz/fuzz_file.h"

#ifndef LTB_FUZZ_EXT
#error "define LTB_FUZZ_EXT (\".off\", \".ply\", \".obj\", \".stl\" or \".drc\")"
#endif

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string path = ltb::fuzz::WriteFile(std::string("input") + LTB_FUZZ_EXT, data, size);
  if (path.empty()) return 0;
  auto mesh = ltb::mesh::LoadMeshFile(path, ltb::Progress{}, /*file_normals=*/true);
  if (!mesh.ok()) mesh = ltb::mesh::LoadMeshFile(path);
  if (!mesh.ok()) return 0;
  ltb::sample::Object o;
  o.type = ltb::sample::Object::Type::kMesh;
  o.scale = {2, -1, 0.5};  // mirroring: flips the winding
  o.rotate_degrees = {10, 20, 30};
  ltb::mesh::ApplyTransform(ltb::sample::ObjectTransform(o), &*mesh);
  return 0;
}
