// Meshes in OBJ, OFF and STL (ASCII and binary) (core/mesh_io: ReadMesh picks the parser by
// extension). The first input byte chooses the extension (seeds carry the right one:
// 'o' .obj, 'f' .off, 's' .stl, see make-seeds.sh); the rest is the file.
#include <cstddef>
#include <cstdint>

#include "core/error.h"
#include "core/mesh.h"
#include "fuzz/fuzz_support.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  if (size < 1) return 0;
  const char* name = "input.obj";
  switch (data[0]) {
    case 'f': name = "input.off"; break;
    case 's': name = "input.stl"; break;
    case 'O': name = "input.OBJ"; break;  // extensions are case-insensitive
    default: break;
  }
  const std::string path = sope::fuzz::WriteInput(data + 1, size - 1, name);
  try {
    const sope::TriangleMesh mesh = sope::ReadMesh(path);
    mesh.BoundingDiagonal();
    mesh.SurfaceArea();
  } catch (const sope::Error&) {
  }
  return 0;
}
