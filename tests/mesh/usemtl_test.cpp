// usemtl = true (docs/SCENE.md "Materials from OBJ `usemtl`"): the OBJ reader's groups of a
// small hand-written file (faces before any usemtl, a quad fan, a dropped face, names
// switching back and forth, a name no face follows), checked by hand; Finalize keeping
// triangle_group aligned when it drops zero-area and out-of-range triangles; BuildGeometry
// splitting a usemtl object into one Embree geometry per material (geom_material,
// geom_object, shading normals, vertex colours and row meshes per geometry id, rays hitting
// the right geometry and primitive), its vertex rows' materials, its geometry hash; the
// errors (a usemtl name no [[material]] defines, naming the OBJ line; usemtl on a PLY mesh,
// a plane, a non-boolean); and the Cornell box of embree3's models with its materials.
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <glm/geometric.hpp>
#include <string>
#include <vector>

#include "stages/mesh/mesh_reader.h"
#include "stages/mesh/triangle_mesh.h"
#include "stages/sample/scene.h"
#include "stages/sample/scene_geometry.h"

namespace ltb::sample {
using namespace ::ltb::mesh;  // the readers under test (stages/mesh), placed by the scene code
namespace usemtl_test {       // named: the unity build puts this file beside normals_test.cpp

std::string Dir() {
  // One directory a process: ctest runs each test in its own process, two at a time, and
  // two tests rewriting the same split.obj changed each other's geometry hash.
  const std::string d = ::testing::TempDir() + "usemtl_test_" + std::to_string(::getpid()) + "/";
  std::filesystem::create_directories(d);
  return d;
}

std::string Write(const std::string& name, const std::string& bytes) {
  const std::string path = Dir() + name;
  std::ofstream(path, std::ios::binary) << bytes;
  return path;
}

bool Has(const Status& s, const std::string& part) { return s.message().find(part) != std::string::npos; }

void Replace(std::string* s, const std::string& from, const std::string& to) {
  const size_t at = s->find(from);
  ASSERT_NE(at, std::string::npos) << from;
  s->replace(at, from.size(), to);
}

// Six vertices: the unit square 1 2 3 4 and the square 2 5 6 3 next to it, at z = 0.
const char kVerts[] =
    "v 0 0 0\n"  // line 1
    "v 1 0 0\n"
    "v 1 1 0\n"
    "v 0 1 0\n"
    "v 2 0 0\n"
    "v 2 1 0\n";  // line 6

// Faces before any usemtl, a name no face follows before it is used again, a quad fan,
// a face dropped for a repeated vertex, names switching back and forth, a name with a
// blank inside, and one no face ever follows.
const std::string kGrouped = std::string(kVerts) +
                             "f 1 2 3\n"             // 7: group 0
                             "usemtl white\n"        // 8: no face follows
                             "usemtl red\n"          // 9
                             "f 1 2 3 4\n"           // 10: quad, 2 triangles of red
                             "f 1 1 2\n"             // 11: dropped (1 1 2)
                             "usemtl  white  # x\n"  // 12
                             "f 2 5 6 3\n"           // 13: quad, 2 triangles of white
                             "usemtl red\n"          // 14
                             "f 3 6 4\n"             // 15: red
                             "usemtl my paint\n"     // 16
                             "f 1 3 4\n"             // 17: my paint
                             "usemtl unused\n";      // 18: no face follows

TEST(UsemtlReader, GroupsOfHandWrittenObj) {
  MeshInput in(kGrouped, "g.obj");
  auto r = ReadObj(in, Progress{}, false, false, /*groups=*/true);
  ASSERT_TRUE(r.ok()) << r.status().message();
  const std::vector<glm::uvec3> tris = {{0, 1, 2}, {0, 1, 2}, {0, 2, 3}, {1, 4, 5}, {1, 5, 2}, {2, 5, 3}, {0, 2, 3}};
  EXPECT_EQ(r->triangles, tris);
  EXPECT_EQ(r->degenerate_dropped, 1u);
  EXPECT_EQ(r->group_names, (std::vector<std::string>{"", "white", "red", "my paint", "unused"}));
  // white: the usemtl of its first triangle (line 12), not its first usemtl (line 8);
  // unused: its only usemtl.
  EXPECT_EQ(r->group_lines, (std::vector<uint64_t>{0, 12, 9, 16, 18}));
  EXPECT_EQ(r->triangle_group, (std::vector<uint32_t>{0, 2, 2, 1, 1, 2, 3}));

  // Not asked for: the same triangles, no groups (usemtl skipped as before).
  MeshInput plain(kGrouped, "g.obj");
  auto p = ReadObj(plain, Progress{});
  ASSERT_TRUE(p.ok()) << p.status().message();
  EXPECT_EQ(p->triangles, tris);
  EXPECT_TRUE(p->group_names.empty());
  EXPECT_TRUE(p->group_lines.empty());
  EXPECT_TRUE(p->triangle_group.empty());

  // No usemtl at all: every triangle in group 0.
  const std::string quad = std::string(kVerts) + "f 1 2 3 4\n";  // MeshInput keeps a view of it
  MeshInput none(quad, "n.obj");
  auto n = ReadObj(none, Progress{}, false, false, true);
  ASSERT_TRUE(n.ok()) << n.status().message();
  EXPECT_EQ(n->group_names, std::vector<std::string>{""});
  EXPECT_EQ(n->group_lines, std::vector<uint64_t>{0});
  EXPECT_EQ(n->triangle_group, (std::vector<uint32_t>{0, 0}));

  // A usemtl without a name: an error naming the line when asked, skipped otherwise.
  const std::string bare = std::string(kVerts) + "usemtl   # none\nf 1 2 3\n";
  MeshInput b1(bare, "bare.obj");
  auto e = ReadObj(b1, Progress{}, false, false, true);
  ASSERT_FALSE(e.ok());
  EXPECT_TRUE(Has(e.status(), "bare.obj:7: usemtl without a material name")) << e.status().message();
  MeshInput b2(bare, "bare.obj");
  EXPECT_TRUE(ReadObj(b2, Progress{}).ok());
}

TEST(UsemtlReader, FinalizeKeepsGroupsAligned) {
  TriangleMesh m;
  m.positions = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {2, 0, 0}, {1, 1, 0}};
  // Zero-area (collinear 0 1 3) and out-of-range (index 9) triangles between groups.
  m.triangles = {{0, 1, 2}, {0, 1, 3}, {1, 4, 2}, {0, 9, 1}, {1, 3, 4}};
  m.triangle_group = {0, 1, 2, 3, 4};
  Finalize(&m);
  EXPECT_EQ(m.triangles, (std::vector<glm::uvec3>{{0, 1, 2}, {1, 4, 2}, {1, 3, 4}}));
  EXPECT_EQ(m.triangle_group, (std::vector<uint32_t>{0, 2, 4}));
  EXPECT_EQ(m.degenerate_dropped, 2u);
  // A mirroring transform swaps corners, not triangles; a scale keeps them all.
  Object mirror;
  mirror.scale = {-1, 2, 1};
  ApplyTransform(ObjectTransform(mirror), &m);
  EXPECT_EQ(m.triangles, (std::vector<glm::uvec3>{{0, 2, 1}, {1, 2, 4}, {1, 4, 3}}));
  EXPECT_EQ(m.triangle_group, (std::vector<uint32_t>{0, 2, 4}));

  // Through LoadMeshFile: a zero-area triangle (collinear 1 2 5) between two groups.
  auto f = LoadMeshFile(
      Write("zero.obj", std::string(kVerts) + "usemtl a\nf 1 2 3\nusemtl b\nf 1 2 5\nf 2 5 6\nusemtl a\nf 1 3 4\n"),
      Progress{}, false, false, true);
  ASSERT_TRUE(f.ok()) << f.status().message();
  EXPECT_EQ(f->triangles, (std::vector<glm::uvec3>{{0, 1, 2}, {1, 4, 5}, {0, 2, 3}}));
  EXPECT_EQ(f->group_names, (std::vector<std::string>{"", "a", "b"}));
  EXPECT_EQ(f->triangle_group, (std::vector<uint32_t>{1, 2, 1}));
  EXPECT_EQ(f->degenerate_dropped, 1u);

  // Groups from any other format: an error naming the file.
  auto off = LoadMeshFile(Write("t.off", "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n"), Progress{}, false, false, true);
  ASSERT_FALSE(off.ok());
  EXPECT_TRUE(Has(off.status(), "t.off: usemtl = true: only OBJ files have usemtl statements"))
      << off.status().message();
}

// The OBJ of the BuildGeometry tests: 7 vertices (the last used by no face), at z = 0; a
// triangle before any usemtl, then red, white, red. Vertex colours so that the per-geometry
// colour entries can be checked.
const char kSplitObj[] =
    "v 0 0 0 1 0 0\n"  // 1
    "v 1 0 0 0 1 0\n"  // 2
    "v 0 1 0 0 0 1\n"  // 3
    "v 1 1 0 1 1 0\n"  // 4
    "v 2 0 0 0 1 1\n"  // 5
    "v 2 1 0 1 0 1\n"  // 6
    "v 5 5 0 1 1 1\n"  // 7: no face uses it
    "f 1 2 3\n"        // 8: base (the object's material)
    "usemtl red\n"     // 9
    "f 2 4 3\n"        // 10
    "usemtl white\n"   // 11
    "f 2 5 4\n"        // 12
    "usemtl red\n"     // 13
    "f 5 6 4\n";       // 14

std::string SplitScene(const std::string& object_material, const std::string& usemtl = "usemtl = true\n") {
  return "[output]\nmode = \"vertex\"\nobjects = [\"m\"]\n"
         "[[material]]\nname = \"base\"\nalbedo = 0.5\n"
         "[[material]]\nname = \"white\"\nalbedo = 0.75\n"
         "[[material]]\nname = \"red\"\nalbedo = [0.6, 0.1, 0.1]\n"
         "[[object]]\nname = \"m\"\ntype = \"mesh\"\nfile = \"split.obj\"\nnormals = \"smooth\"\n"
         "colours = \"file\"\nmaterial = \"" +
         object_material + "\"\n" + usemtl +
         "[[object]]\nname = \"floor\"\ntype = \"plane\"\nmaterial = \"white\"\nsize = [20, 20]\n"
         "translate = [0, 0, -1]\n";
}

Result<Geometry> Build(const std::string& name, const std::string& body) {
  auto s = ParseScene(Write(name, body));
  if (!s.ok()) return s.status();
  return BuildGeometry(*s);
}

TEST(UsemtlGeometry, OneEmbreeGeometryPerMaterial) {
  Write("split.obj", kSplitObj);
  auto g = Build("split.toml", SplitScene("base"));
  ASSERT_TRUE(g.ok()) << g.status().message();
  const int base = 0, white = 1, red = 2;
  // base [t0], red [t1, t3], white [t2] in order of first appearance, then the plane.
  EXPECT_EQ(g->geom_material, (std::vector<int>{base, red, white, white}));
  EXPECT_EQ(g->geom_object, (std::vector<int>{0, 0, 0, 1}));
  const std::vector<std::vector<glm::uvec3>> parts = {{{0, 1, 2}}, {{1, 3, 2}, {4, 5, 3}}, {{1, 4, 3}}};
  ASSERT_EQ(g->row_meshes.size(), 4u);
  ASSERT_EQ(g->shading.size(), 4u);
  ASSERT_EQ(g->colours.size(), 4u);
  for (size_t id = 0; id < 3; ++id) {
    EXPECT_EQ(g->row_meshes[id].first_row, 0u) << id;
    EXPECT_EQ(g->row_meshes[id].triangles, parts[id]) << id;
    EXPECT_EQ(g->shading[id].triangles, parts[id]) << id;
    EXPECT_EQ(g->shading[id].normals.size(), 7u) << id;
    EXPECT_EQ(g->colours[id].triangles, parts[id]) << id;
    ASSERT_EQ(g->colours[id].colours.size(), 7u) << id;
    EXPECT_EQ(g->colours[id].colours[4], glm::dvec3(0, 1, 1)) << id;
  }
  // The plane: its first row after the object's 7 (it has no rows), nothing per vertex.
  EXPECT_EQ(g->row_meshes[3].first_row, 7u);
  EXPECT_TRUE(g->row_meshes[3].triangles.empty());
  EXPECT_TRUE(g->shading[3].normals.empty());
  EXPECT_TRUE(g->colours[3].colours.empty());

  // The object's vertices are rows once; each takes its first triangle's material (the
  // unused vertex 7, the object's).
  ASSERT_EQ(g->vertex_rows.size(), 7u);
  const int want[7] = {base, base, base, red, white, red, base};
  for (int v = 0; v < 7; ++v) EXPECT_EQ(g->vertex_rows[v].material, want[v]) << "vertex " << v;
  EXPECT_EQ(g->vertex_rows[4].colour, glm::dvec3(0, 1, 1));

  // A ray down through each triangle's centroid hits its geometry and primitive.
  const glm::dvec3 p[7] = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {1, 1, 0}, {2, 0, 0}, {2, 1, 0}, {5, 5, 0}};
  for (size_t id = 0; id < 3; ++id) {
    for (size_t k = 0; k < parts[id].size(); ++k) {
      const glm::uvec3& t = parts[id][k];
      const glm::dvec3 c = (p[t[0]] + p[t[1]] + p[t[2]]) / 3.0;
      const Hit h = g->rays->Intersect(c + glm::dvec3(0, 0, 1), {0, 0, -1});
      ASSERT_TRUE(h.hit) << id << " " << k;
      EXPECT_EQ(h.geom_id, id) << k;
      EXPECT_EQ(h.prim_id, k) << id;
      EXPECT_EQ(g->geom_material[h.geom_id], g->geom_material[id]);
      const glm::uvec3& row = g->row_meshes[h.geom_id].triangles[h.prim_id];
      EXPECT_EQ(row, t);
    }
  }
  const Hit floor = g->rays->Intersect({5, 5, 1}, {0, 0, -1});  // past the mesh: the plane
  ASSERT_TRUE(floor.hit);
  EXPECT_EQ(floor.geom_id, 3u);

  // The object's material also named by usemtl: its triangles join that geometry; rows,
  // and the geometry hash (how materials split the triangles is not geometry), unchanged.
  auto w = Build("split_white.toml", SplitScene("white"));
  ASSERT_TRUE(w.ok()) << w.status().message();
  EXPECT_EQ(w->geom_material, (std::vector<int>{white, red, white}));
  EXPECT_EQ(w->row_meshes[0].triangles, (std::vector<glm::uvec3>{{0, 1, 2}, {1, 4, 3}}));
  EXPECT_EQ(w->row_meshes[1].triangles, parts[1]);
  EXPECT_EQ(w->vertex_rows[0].material, white);
  EXPECT_EQ(w->vertex_rows[6].material, white);
  EXPECT_EQ(w->geometry_hash, g->geometry_hash);

  // Without usemtl (the key absent or false): one geometry, the object's material, the
  // usemtl statements ignored; the same hash either way, another one than with usemtl.
  auto off = Build("split_off.toml", SplitScene("base", ""));
  ASSERT_TRUE(off.ok()) << off.status().message();
  EXPECT_EQ(off->geom_material, (std::vector<int>{base, white}));
  EXPECT_EQ(off->geom_object, (std::vector<int>{0, 1}));
  EXPECT_EQ(off->row_meshes[0].triangles, (std::vector<glm::uvec3>{{0, 1, 2}, {1, 3, 2}, {1, 4, 3}, {4, 5, 3}}));
  for (const RowPoint& r : off->vertex_rows) EXPECT_EQ(r.material, base);
  auto f = Build("split_false.toml", SplitScene("base", "usemtl = false\n"));
  ASSERT_TRUE(f.ok()) << f.status().message();
  EXPECT_EQ(f->geometry_hash, off->geometry_hash);
  EXPECT_NE(off->geometry_hash, g->geometry_hash);
}

TEST(UsemtlGeometry, Errors) {
  Write("split.obj", kSplitObj);
  // "white" (OBJ line 11) defined by no [[material]].
  std::string body = SplitScene("base");
  Replace(&body, "name = \"white\"\nalbedo = 0.75", "name = \"grey\"\nalbedo = 0.5");
  Replace(&body, "material = \"white\"\nsize", "material = \"grey\"\nsize");
  const std::string scene = Dir() + "unknown.toml";
  auto g = Build("unknown.toml", body);
  ASSERT_FALSE(g.ok());
  const std::string want = scene + ":13: object \"m\": " + Dir() + "split.obj:11: usemtl \"white\" names no " +
                           "[[material]] of the scene (it has \"base\", \"grey\", \"red\"); add a [[material]] " +
                           "with name = \"white\", or leave usemtl out of the object";
  EXPECT_TRUE(Has(g.status(), want)) << g.status().message() << "\nwant: " << want;

  // usemtl on a mesh that is not OBJ, on a plane, and not a boolean.
  const std::string cam = "[camera]\neye = [0.0, 0.0, 5.0]\nup = [0.0, 1.0, 0.0]\n";
  auto ply = ParseScene(Write("ply.toml", cam + "[[object]]\nname = \"bun\"\ntype = \"mesh\"\nfile = \"b.ply\"\n"
                                                "usemtl = true\n"));
  ASSERT_FALSE(ply.ok());
  EXPECT_TRUE(Has(ply.status(), "ply.toml:8: object \"bun\": usemtl = true needs an OBJ file"))
      << ply.status().message();
  EXPECT_TRUE(Has(ply.status(), "b.ply\" is a \".ply\" file")) << ply.status().message();
  auto plane = ParseScene(Write("plane.toml", cam + "[[object]]\nname = \"floor\"\ntype = \"plane\"\nusemtl = true\n"));
  ASSERT_FALSE(plane.ok());
  EXPECT_TRUE(Has(plane.status(),
                  "plane.toml:7: object \"floor\": usemtl = true is for type = \"mesh\" with an OBJ "
                  "file"))
      << plane.status().message();
  EXPECT_TRUE(ParseScene(Write("plane0.toml", cam + "[[object]]\ntype = \"plane\"\nusemtl = false\n")).ok());
  auto type = ParseScene(Write("type.toml", cam + "[[object]]\ntype = \"mesh\"\nfile = \"a.obj\"\nusemtl = \"yes\"\n"));
  ASSERT_FALSE(type.ok());
  EXPECT_TRUE(Has(type.status(), "type.toml:7: \"usemtl\" is \"yes\"; it must be true or false"))
      << type.status().message();
  auto upper = ParseScene(Write("upper.toml", cam + "[[object]]\ntype = \"mesh\"\nfile = \"A.OBJ\"\nusemtl = true\n"));
  ASSERT_TRUE(upper.ok()) << upper.status().message();
  EXPECT_TRUE(upper->objects[0].usemtl);
}

const char kCornell[] = "/usr/share/doc/embree3/models/cornell_box.obj";

std::string CornellScene(const std::string& materials) {
  return std::string("[camera]\neye = [2.78, 8.0, 2.73]\ntarget = [2.78, -2.8, 2.73]\nup = [0, 0, 1]\nfov = 37\n") +
         materials + "[[object]]\nname = \"box\"\ntype = \"mesh\"\nfile = \"" + kCornell +
         "\"\nusemtl = true\nmaterial = \"white\"\nscale = 0.01\nrotate = [90, 0, 0]\n";
}

TEST(UsemtlGeometry, CornellBox) {
  if (!std::filesystem::exists(kCornell)) GTEST_SKIP() << kCornell << " is not installed (package embree3)";
  const std::string mats =
      "[[material]]\nname = \"white\"\nalbedo = 0.75\n"
      "[[material]]\nname = \"red\"\nalbedo = [0.63, 0.065, 0.05]\n"
      "[[material]]\nname = \"green\"\nalbedo = [0.14, 0.45, 0.091]\n";
  // light and blue: usemtl statements whose faces the file comments out, so not needed.
  for (const std::string& extra :
       {std::string(), std::string("[[material]]\nname = \"light\"\nalbedo = 0.75\n[[material]]\nname = \"blue\"\n")}) {
    auto g = Build("cornell.toml", CornellScene(mats + extra));
    ASSERT_TRUE(g.ok()) << g.status().message();
    // Floor, ceiling, back wall (white), green wall, red wall, then the blocks (white).
    EXPECT_EQ(g->geom_material, (std::vector<int>{0, 2, 1}));
    EXPECT_EQ(g->geom_object, (std::vector<int>{0, 0, 0}));
    ASSERT_EQ(g->shading.size(), 3u);
    EXPECT_EQ(g->colours.size(), 3u);
    ASSERT_EQ(g->row_meshes.size(), 3u);
    EXPECT_TRUE(g->row_meshes[0].triangles.empty());  // image mode: no rows
    // Rays from inside the box (after rotate x 90° and scale 0.01: x, -z, y of the file, in
    // metres) hit the walls' materials.
    auto at = [&](glm::dvec3 o, glm::dvec3 d) {
      const Hit h = g->rays->Intersect(o, d);
      return h.hit ? g->geom_material[h.geom_id] : -1;
    };
    // Above the blocks, below the ceiling, halfway from the open front to the back wall.
    const glm::dvec3 mid(2.78, -2.8, 4.5);
    EXPECT_EQ(at(mid, {-1, 0, 0}), 2);  // x = 0: the green wall
    EXPECT_EQ(at(mid, {1, 0, 0}), 1);   // the red wall
    EXPECT_EQ(at(mid, {0, -1, 0}), 0);  // the back wall
    EXPECT_EQ(at(mid, {0, 0, 1}), 0);   // the ceiling
    EXPECT_EQ(at(mid, {0, 1, 0}), -1);  // the front wall's faces are commented out
  }
  // Without "red": an error naming OBJ line 67.
  auto g = Build("cornell_nored.toml",
                 CornellScene("[[material]]\nname = \"white\"\n[[material]]\nname = \"green\"\nalbedo = 0.2\n"));
  ASSERT_FALSE(g.ok());
  EXPECT_TRUE(Has(g.status(), std::string(kCornell) + ":67: usemtl \"red\" names no [[material]] of the scene (it "
                                                      "has \"white\", \"green\")"))
      << g.status().message();
}

}  // namespace usemtl_test
}  // namespace ltb::sample
