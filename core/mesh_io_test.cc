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
  // A face index int64 cannot hold was cast (undefined; found by ply_fuzz, 2026-12-05).
  WriteFileAtomic(scratch.File("huge_index.ply"),
                  "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
                  "property float z\nelement face 1\nproperty list uchar int vertex_indices\n"
                  "end_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 1e98\n");
  EXPECT_THROW_WITH_MESSAGE(ReadMesh(scratch.File("huge_index.ply")), Error, "huge_index.ply",
                            "not an index");
}

TEST(MeshIo, SharedMeshesLoadWhenPresent) {
  SOPE_REQUIRE_SHARED_DATA(data);
  for (const char* name : {"ycb/MustardBottle.obj", "classic/teapot.obj", "classic/spot.obj"}) {
    const TriangleMesh mesh = ReadMesh(data + "/meshes/" + name);
    EXPECT_GT(mesh.faces.size(), 100u) << name;
    EXPECT_GT(mesh.SurfaceArea(), 0.0) << name;
  }
}

// Issue 13: counts beyond what the file can hold were allocated first (std::bad_alloc,
// "vector::_M_default_append"); now they are refused naming the count.
TEST(MeshIo, CountsBeyondTheFileSizeAreRefusedBeforeAllocating) {
  testing::ScratchDir scratch;
  auto error_for = [&](const std::string& name, const std::string& text) -> std::string {
    WriteFileAtomic(scratch.File(name), text);
    try {
      ReadMesh(scratch.File(name));
    } catch (const Error& e) {
      return e.what();
    }
    return "";
  };
  std::string error = error_for("huge.ply",
                                "ply\nformat ascii 1.0\nelement vertex 9223372036854775807\n"
                                "property float x\nproperty float y\nproperty float z\n"
                                "end_header\n0 0 0\n");
  EXPECT_NE(error.find("9223372036854775807 rows"), std::string::npos) << error;
  std::string hundred =
      "ply\nformat binary_little_endian 1.0\nelement vertex 1000000000\nproperty float x\n"
      "property float y\nproperty float z\nelement face 1\n"
      "property list uchar int vertex_indices\nend_header\n";
  hundred += std::string(100 * 12, '\0');
  error = error_for("short.ply", hundred);
  EXPECT_NE(error.find("1000000000 rows"), std::string::npos) << error;
  error = error_for("noprops.ply",
                    "ply\nformat ascii 1.0\nelement junk 9000000000000000000\nend_header\n");
  EXPECT_NE(error.find("junk"), std::string::npos) << error;
  error = error_for("huge.off", "OFF\n1000000000000 1 0\n0 0 0\n");
  EXPECT_NE(error.find("1000000000000 vertices"), std::string::npos) << error;
  // A count that does fit still reads.
  EXPECT_EQ(error_for("ok.off", "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n"), "");
}

}  // namespace
}  // namespace sope
