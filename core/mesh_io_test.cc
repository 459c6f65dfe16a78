#include <cstring>

#include <gtest/gtest.h>

#include "core/error.h"
#include "core/file_util.h"
#include "core/mesh.h"
#include "tests/test_support.h"

namespace sope {
namespace {

// Unit square in z = 0 as two triangles.
TriangleMesh Square() {
  TriangleMesh mesh;
  mesh.vertices = {{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0}};
  mesh.faces = {{0, 1, 2}, {0, 2, 3}};
  return mesh;
}

TEST(MeshIo, ObjAndPlyRoundTrip) {
  testing::ScratchDir scratch;
  for (const char* name : {"m.obj", "m.ply"}) {
    WriteMesh(scratch.File(name), Square());
    const TriangleMesh mesh = ReadMesh(scratch.File(name));
    EXPECT_EQ(mesh.vertices, Square().vertices);
    EXPECT_EQ(mesh.faces, Square().faces);
    EXPECT_NEAR(mesh.SurfaceArea(), 1.0, 1e-9);
    EXPECT_NEAR((mesh.SurfaceCentroid() - Eigen::Vector3d(0.5, 0.5, 0)).norm(), 0, 1e-9);
  }
}

TEST(MeshIo, ObjPolygonsNegativeIndicesAndSlashes) {
  testing::ScratchDir scratch;
  WriteFileAtomic(scratch.File("q.obj"),
                  "# quad\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvn 0 0 1\nvt 0 0\n"
                  "f -4/1/1 -3/1/1 -2//1 -1\n");
  const TriangleMesh mesh = ReadMesh(scratch.File("q.obj"));
  ASSERT_EQ(mesh.faces.size(), 2u);
  EXPECT_EQ(mesh.faces[1], Eigen::Vector3i(0, 2, 3));
}

TEST(MeshIo, OffAndStl) {
  testing::ScratchDir scratch;
  WriteFileAtomic(scratch.File("s.off"),
                  "OFF # comment\n4 1 0\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n4 0 1 2 3 255 0 0\n");
  EXPECT_NEAR(ReadMesh(scratch.File("s.off")).SurfaceArea(), 1.0, 1e-9);
  WriteFileAtomic(scratch.File("a.STL"),
                  "solid t\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\n"
                  "vertex 1 1 0\nendloop\nendfacet\nfacet normal 0 0 1\nouter loop\n"
                  "vertex 0 0 0\nvertex 1 1 0\nvertex 0 1 0\nendloop\nendfacet\nendsolid t\n");
  const TriangleMesh ascii = ReadMesh(scratch.File("a.STL"));
  EXPECT_EQ(ascii.vertices.size(), 4u);  // shared by coordinates
  EXPECT_NEAR(ascii.SurfaceArea(), 1.0, 1e-9);
  std::string binary(80, ' ');
  const uint32_t count = 2;
  binary.append(reinterpret_cast<const char*>(&count), 4);
  const float triangles[2][12] = {{0, 0, 1, 0, 0, 0, 1, 0, 0, 1, 1, 0},
                                  {0, 0, 1, 0, 0, 0, 1, 1, 0, 0, 1, 0}};
  for (const auto& t : triangles) {
    binary.append(reinterpret_cast<const char*>(t), 48);
    binary.append(2, '\0');
  }
  WriteFileAtomic(scratch.File("b.stl"), binary);
  EXPECT_NEAR(ReadMesh(scratch.File("b.stl")).SurfaceArea(), 1.0, 1e-6);
}

TEST(MeshIo, MalformedMeshesAreErrors) {
  testing::ScratchDir scratch;
  WriteFileAtomic(scratch.File("bad.obj"), "v 0 0 0\nf 1 2 3\n");
  EXPECT_THROW_WITH_MESSAGE(ReadMesh(scratch.File("bad.obj")), Error, "bad.obj", "vertex index 2");
  WriteFileAtomic(scratch.File("empty.obj"), "v 0 0 0\n");
  EXPECT_THROW_WITH_MESSAGE(ReadMesh(scratch.File("empty.obj")), Error, "empty.obj", "no faces");
  WriteFileAtomic(scratch.File("bad.off"), "OFF\n3 1 0\n0 0 0\n1 0\n");
  EXPECT_THROW_WITH_MESSAGE(ReadMesh(scratch.File("bad.off")), Error, "bad.off", "vertex 1");
  WriteFileAtomic(scratch.File("bad.stl"), "garbage");
  EXPECT_THROW_WITH_MESSAGE(ReadMesh(scratch.File("bad.stl")), Error, "bad.stl");
  EXPECT_THROW_WITH_MESSAGE(ReadMesh(scratch.File("model.3ds")), Error, "model.3ds", "'3ds'");
}

TEST(MeshIo, SharedMeshesLoadWhenPresent) {
  SOPE_REQUIRE_SHARED_DATA(data);
  for (const char* name : {"ycb/MustardBottle.obj", "classic/teapot.obj", "classic/spot.obj"}) {
    const TriangleMesh mesh = ReadMesh(data + "/meshes/" + name);
    EXPECT_GT(mesh.faces.size(), 100u) << name;
    EXPECT_GT(mesh.SurfaceArea(), 0.0) << name;
  }
}

}  // namespace
}  // namespace sope
