// Mesh files: OBJ, OFF, STL (ASCII and binary) and PLY (through the shared PLY parser).
#include <array>
#include <cmath>
#include <limits>
#include <cstring>
#include <map>
#include <sstream>

#include <Eigen/Geometry>
#include <fmt/format.h>

#include "core/error.h"
#include "core/file_util.h"
#include "core/mesh.h"
#include "core/ply_reader.h"

namespace sope {
namespace {

// Adds polygon `indices` as a triangle fan.
void AddPolygon(const std::vector<int>& indices, TriangleMesh* mesh) {
  for (size_t k = 2; k < indices.size(); ++k) {
    mesh->faces.emplace_back(indices[0], indices[k - 1], indices[k]);
  }
}

TriangleMesh ReadObj(const std::string& path) {
  const std::string data = ReadFileToString(path, "mesh");
  std::istringstream stream(data);
  TriangleMesh mesh;
  std::string line;
  size_t line_number = 0;
  std::vector<int> polygon;
  while (std::getline(stream, line)) {
    ++line_number;
    if (line.size() < 2) continue;
    if (line[0] == 'v' && (line[1] == ' ' || line[1] == '\t')) {
      std::istringstream words(line.substr(2));
      Eigen::Vector3f v;
      SOPE_CHECK(static_cast<bool>(words >> v.x() >> v.y() >> v.z()),
                 "mesh {}: line {}: malformed vertex", path, line_number);
      mesh.vertices.push_back(v);
    } else if (line[0] == 'f' && (line[1] == ' ' || line[1] == '\t')) {
      std::istringstream words(line.substr(2));
      std::string token;
      polygon.clear();
      while (words >> token) {
        // v, v/vt, v//vn or v/vt/vn; negative indices count from the end.
        char* end = nullptr;
        const long index = std::strtol(token.c_str(), &end, 10);
        SOPE_CHECK(end != token.c_str() && index != 0, "mesh {}: line {}: malformed face '{}'",
                   path, line_number, token);
        const long resolved =
            index > 0 ? index - 1 : static_cast<long>(mesh.vertices.size()) + index;
        SOPE_CHECK(resolved >= 0 && resolved < static_cast<long>(mesh.vertices.size()),
                   "mesh {}: line {}: vertex index {} out of range", path, line_number, index);
        polygon.push_back(static_cast<int>(resolved));
      }
      SOPE_CHECK(polygon.size() >= 3, "mesh {}: line {}: face with fewer than 3 vertices", path,
                 line_number);
      AddPolygon(polygon, &mesh);
    }
  }
  return mesh;
}

TriangleMesh ReadOff(const std::string& path) {
  const std::string data = ReadFileToString(path, "mesh");
  std::istringstream stream(data);
  // Comments (#) are stripped by reading token by token after removing them per line.
  std::string cleaned, line;
  while (std::getline(stream, line)) {
    const size_t hash = line.find('#');
    cleaned += (hash == std::string::npos ? line : line.substr(0, hash)) + "\n";
  }
  std::istringstream words(cleaned);
  std::string magic;
  words >> magic;
  SOPE_CHECK(magic == "OFF", "mesh {}: missing 'OFF' magic (only plain OFF is supported)",
             path);
  long vertex_count = -1, face_count = -1, edge_count = -1;
  SOPE_CHECK(static_cast<bool>(words >> vertex_count >> face_count >> edge_count) &&
                 vertex_count >= 0 && face_count >= 0,
             "mesh {}: malformed OFF counts", path);
  // The vertex count against the file size before allocating: a vertex is three numbers,
  // each at least one character and a separator. (Faces are not allocated by count; a
  // truncated face list fails at the first missing face.)
  SOPE_CHECK(6.0 * static_cast<double>(vertex_count) <= static_cast<double>(cleaned.size()) + 1.0,
             "mesh {}: OFF claims {} vertices, more than its {} bytes can hold", path,
             vertex_count, cleaned.size());
  TriangleMesh mesh;
  mesh.vertices.resize(vertex_count);
  for (long i = 0; i < vertex_count; ++i) {
    Eigen::Vector3f& v = mesh.vertices[i];
    SOPE_CHECK(static_cast<bool>(words >> v.x() >> v.y() >> v.z()),
               "mesh {}: truncated at vertex {}", path, i);
  }
  std::vector<int> polygon;
  for (long i = 0; i < face_count; ++i) {
    long n = 0;
    SOPE_CHECK(static_cast<bool>(words >> n) && n >= 3 && n < 1000,
               "mesh {}: malformed face {}", path, i);
    polygon.resize(n);
    for (long k = 0; k < n; ++k) {
      SOPE_CHECK(static_cast<bool>(words >> polygon[k]) && polygon[k] >= 0 &&
                     polygon[k] < vertex_count,
                 "mesh {}: face {}: bad vertex index", path, i);
    }
    // Skip an optional colour on the rest of the line.
    std::string rest;
    std::getline(words, rest);
    AddPolygon(polygon, &mesh);
  }
  return mesh;
}

TriangleMesh ReadStl(const std::string& path) {
  const std::string data = ReadFileToString(path, "mesh");
  TriangleMesh mesh;
  // Vertices are shared by exact coordinates so normals and neighbourhoods work.
  std::map<std::array<float, 3>, int> index_of;
  auto vertex_index = [&](const Eigen::Vector3f& v) {
    const std::array<float, 3> key{v.x(), v.y(), v.z()};
    const auto [it, inserted] = index_of.emplace(key, static_cast<int>(mesh.vertices.size()));
    if (inserted) mesh.vertices.push_back(v);
    return it->second;
  };
  const bool maybe_binary = data.size() >= 84;
  uint32_t triangle_count = 0;
  if (maybe_binary) std::memcpy(&triangle_count, data.data() + 80, 4);
  const bool binary =
      maybe_binary && data.size() == 84 + 50 * static_cast<size_t>(triangle_count);
  if (binary) {
    for (uint32_t t = 0; t < triangle_count; ++t) {
      const char* record = data.data() + 84 + 50 * static_cast<size_t>(t);
      int face[3];
      for (int k = 0; k < 3; ++k) {
        float xyz[3];
        std::memcpy(xyz, record + 12 + 12 * k, 12);
        face[k] = vertex_index(Eigen::Vector3f(xyz[0], xyz[1], xyz[2]));
      }
      mesh.faces.emplace_back(face[0], face[1], face[2]);
    }
    return mesh;
  }
  SOPE_CHECK(data.rfind("solid", 0) == 0,
             "mesh {}: neither ASCII STL ('solid') nor a complete binary STL", path);
  std::istringstream words(data);
  std::string word;
  std::vector<int> polygon;
  while (words >> word) {
    if (word == "vertex") {
      Eigen::Vector3f v;
      SOPE_CHECK(static_cast<bool>(words >> v.x() >> v.y() >> v.z()),
                 "mesh {}: malformed vertex", path);
      polygon.push_back(vertex_index(v));
    } else if (word == "endfacet") {
      SOPE_CHECK(polygon.size() >= 3, "mesh {}: facet with fewer than 3 vertices", path);
      AddPolygon(polygon, &mesh);
      polygon.clear();
    }
  }
  return mesh;
}

TriangleMesh ReadPlyMesh(const std::string& path) {
  const auto elements = internal::ReadPly(path, {"vertex", "face"});
  TriangleMesh mesh;
  for (const internal::PlyElement& element : elements) {
    if (element.name == "vertex") {
      const int x = element.Column("x"), y = element.Column("y"), z = element.Column("z");
      SOPE_CHECK(x >= 0 && y >= 0 && z >= 0, "mesh {}: vertices lack x, y, z", path);
      for (const auto& row : element.rows) mesh.vertices.emplace_back(row[x], row[y], row[z]);
    } else if (element.name == "face") {
      std::vector<int> polygon;
      for (const auto& list : element.lists) {
        polygon.assign(list.begin(), list.end());
        SOPE_CHECK(polygon.size() >= 3, "mesh {}: face with fewer than 3 vertices", path);
        AddPolygon(polygon, &mesh);
      }
    }
  }
  return mesh;
}

}  // namespace

void TriangleMesh::Check() const {
  SOPE_CHECK(!faces.empty(), "mesh has no faces");
  const int n = static_cast<int>(vertices.size());
  for (const Eigen::Vector3i& face : faces) {
    SOPE_CHECK(face.minCoeff() >= 0 && face.maxCoeff() < n,
               "mesh face index out of range (0..{})", n - 1);
  }
  for (const Eigen::Vector3f& v : vertices) {
    SOPE_CHECK(v.allFinite(), "mesh has a non-finite vertex");
  }
}

void TriangleMesh::Bounds(Eigen::Vector3f* min_corner, Eigen::Vector3f* max_corner) const {
  Eigen::Vector3f lo = Eigen::Vector3f::Constant(std::numeric_limits<float>::max());
  Eigen::Vector3f hi = -lo;
  for (const Eigen::Vector3i& face : faces) {
    for (int k = 0; k < 3; ++k) {
      lo = lo.cwiseMin(vertices[face[k]]);
      hi = hi.cwiseMax(vertices[face[k]]);
    }
  }
  *min_corner = lo;
  *max_corner = hi;
}

double TriangleMesh::BoundingDiagonal() const {
  Eigen::Vector3f lo, hi;
  Bounds(&lo, &hi);
  return (hi - lo).norm();
}

double TriangleMesh::SurfaceArea() const {
  double area = 0.0;
  for (const Eigen::Vector3i& f : faces) {
    const Eigen::Vector3d a = vertices[f[0]].cast<double>();
    area += 0.5 * (vertices[f[1]].cast<double>() - a)
                      .cross(vertices[f[2]].cast<double>() - a)
                      .norm();
  }
  return area;
}

Eigen::Vector3d TriangleMesh::SurfaceCentroid() const {
  Eigen::Vector3d weighted = Eigen::Vector3d::Zero();
  double total = 0.0;
  for (const Eigen::Vector3i& f : faces) {
    const Eigen::Vector3d a = vertices[f[0]].cast<double>();
    const Eigen::Vector3d b = vertices[f[1]].cast<double>();
    const Eigen::Vector3d c = vertices[f[2]].cast<double>();
    const double area = 0.5 * (b - a).cross(c - a).norm();
    weighted += area * (a + b + c) / 3.0;
    total += area;
  }
  return total > 0 ? Eigen::Vector3d(weighted / total) : Eigen::Vector3d::Zero();
}

void TriangleMesh::Transform(double scale, const Eigen::Vector3d& offset) {
  for (Eigen::Vector3f& v : vertices) {
    v = (scale * v.cast<double>() + offset).cast<float>();
  }
}

TriangleMesh ReadMesh(const std::string& path) {
  const std::string extension = FileExtension(path);
  TriangleMesh mesh;
  if (extension == "obj") {
    mesh = ReadObj(path);
  } else if (extension == "off") {
    mesh = ReadOff(path);
  } else if (extension == "stl") {
    mesh = ReadStl(path);
  } else if (extension == "ply") {
    mesh = ReadPlyMesh(path);
  } else {
    SOPE_THROW("mesh {}: unsupported extension '{}' (expected obj, ply, off or stl)", path,
               extension);
  }
  try {
    mesh.Check();
  } catch (const Error& e) {
    SOPE_THROW("mesh {}: {}", path, e.what());
  }
  return mesh;
}

void WriteMesh(const std::string& path, const TriangleMesh& mesh) {
  mesh.Check();
  const std::string extension = FileExtension(path);
  std::string bytes;
  if (extension == "obj") {
    fmt::memory_buffer buffer;
    for (const auto& v : mesh.vertices) {
      fmt::format_to(std::back_inserter(buffer), "v {} {} {}\n", v.x(), v.y(), v.z());
    }
    for (const auto& f : mesh.faces) {
      fmt::format_to(std::back_inserter(buffer), "f {} {} {}\n", f[0] + 1, f[1] + 1, f[2] + 1);
    }
    bytes.assign(buffer.data(), buffer.size());
  } else if (extension == "ply") {
    bytes = fmt::format(
        "ply\nformat binary_little_endian 1.0\nelement vertex {}\nproperty float x\n"
        "property float y\nproperty float z\nelement face {}\n"
        "property list uchar int vertex_indices\nend_header\n",
        mesh.vertices.size(), mesh.faces.size());
    for (const auto& v : mesh.vertices) bytes.append(reinterpret_cast<const char*>(v.data()), 12);
    for (const auto& f : mesh.faces) {
      bytes.push_back(3);
      bytes.append(reinterpret_cast<const char*>(f.data()), 12);
    }
  } else {
    SOPE_THROW("cannot write mesh {}: unsupported extension '{}' (obj or ply)", path, extension);
  }
  WriteFileAtomic(path, bytes);
}

}  // namespace sope
