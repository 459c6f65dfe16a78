// Point-cloud files: PLY by our own reader/writer (binary little-endian by default), PCD
// through PCL's reader/writer.
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <sstream>

#include <fmt/format.h>
#include <pcl/PCLPointCloud2.h>
#include <pcl/console/print.h>
#include <pcl/conversions.h>
#include <pcl/io/pcd_io.h>
#include <pcl/point_types.h>

#include "core/error.h"
#include "core/file_util.h"
#include "core/ply_reader.h"
#include "core/point_cloud.h"

namespace sope {
namespace {

PointCloud ReadPlyCloud(const std::string& path) {
  const std::vector<internal::PlyElement> elements = internal::ReadPly(path, {"vertex"});
  const internal::PlyElement* vertex = nullptr;
  for (const auto& element : elements) {
    if (element.name == "vertex") vertex = &element;
  }
  SOPE_CHECK(vertex != nullptr, "point cloud {}: no 'vertex' element", path);
  const int x = vertex->Column("x"), y = vertex->Column("y"), z = vertex->Column("z");
  SOPE_CHECK(x >= 0 && y >= 0 && z >= 0, "point cloud {}: vertices lack x, y, z", path);
  const int r = vertex->Column("red"), g = vertex->Column("green"), b = vertex->Column("blue");
  const int nx = vertex->Column("nx"), ny = vertex->Column("ny"), nz = vertex->Column("nz");
  const bool has_color = r >= 0 && g >= 0 && b >= 0;
  const bool has_normal = nx >= 0 && ny >= 0 && nz >= 0;
  PointCloud cloud;
  cloud.points.reserve(vertex->count);
  for (const std::vector<double>& row : vertex->rows) {
    cloud.points.emplace_back(row[x], row[y], row[z]);
    if (has_color) {
      cloud.colors.emplace_back(static_cast<uint8_t>(row[r]), static_cast<uint8_t>(row[g]),
                                static_cast<uint8_t>(row[b]));
    }
    if (has_normal) cloud.normals.emplace_back(row[nx], row[ny], row[nz]);
  }
  return cloud;
}

PointCloud ReadPcdCloud(const std::string& path) {
  RequireReadableFile(path, "point cloud");
  pcl::PCLPointCloud2 blob;
  pcl::PCDReader reader;
  // PCL reports problems on the console; we report them as one error instead.
  const pcl::console::VERBOSITY_LEVEL verbosity = pcl::console::getVerbosityLevel();
  pcl::console::setVerbosityLevel(pcl::console::L_ALWAYS);
  int result = -1;
  try {
    result = reader.read(path, blob);
  } catch (const std::exception& e) {
    pcl::console::setVerbosityLevel(verbosity);
    SOPE_THROW("point cloud {}: not a valid PCD file ({})", path, e.what());
  }
  pcl::console::setVerbosityLevel(verbosity);
  SOPE_CHECK(result >= 0, "point cloud {}: not a valid or complete PCD file", path);
  int xyz_fields = 0;
  bool has_rgb = false, has_normal = false;
  for (const auto& field : blob.fields) {
    xyz_fields += field.name == "x" || field.name == "y" || field.name == "z";
    has_rgb |= field.name == "rgb" || field.name == "rgba";
    has_normal |= field.name == "normal_x";
  }
  SOPE_CHECK(xyz_fields == 3, "point cloud {}: PCD lacks x, y, z fields", path);
  SOPE_CHECK(blob.data.size() >= static_cast<size_t>(blob.width) * blob.height * blob.point_step,
             "point cloud {}: PCD data is truncated", path);
  PointCloud cloud;
  pcl::PointCloud<pcl::PointXYZ> xyz;
  pcl::fromPCLPointCloud2(blob, xyz);
  cloud.points.reserve(xyz.size());
  for (const auto& p : xyz.points) cloud.points.emplace_back(p.x, p.y, p.z);
  if (has_rgb) {
    pcl::PointCloud<pcl::PointXYZRGB> rgb;
    pcl::fromPCLPointCloud2(blob, rgb);
    for (const auto& p : rgb.points) cloud.colors.emplace_back(p.r, p.g, p.b);
  }
  if (has_normal) {
    pcl::PointCloud<pcl::Normal> normals;
    pcl::fromPCLPointCloud2(blob, normals);
    for (const auto& n : normals.points) {
      cloud.normals.emplace_back(n.normal_x, n.normal_y, n.normal_z);
    }
  }
  return cloud;
}

std::string PlyBytes(const PointCloud& cloud, PlyFormat format) {
  std::string header = "ply\n";
  header += format == PlyFormat::kAscii ? "format ascii 1.0\n" : "format binary_little_endian 1.0\n";
  header += "comment sope point cloud, metres\n";
  header += fmt::format("element vertex {}\n", cloud.size());
  header += "property float x\nproperty float y\nproperty float z\n";
  if (cloud.HasNormals()) header += "property float nx\nproperty float ny\nproperty float nz\n";
  if (cloud.HasColors()) {
    header += "property uchar red\nproperty uchar green\nproperty uchar blue\n";
  }
  header += "end_header\n";
  std::string body;
  if (format == PlyFormat::kAscii) {
    fmt::memory_buffer buffer;
    for (size_t i = 0; i < cloud.size(); ++i) {
      const Eigen::Vector3f& p = cloud.points[i];
      fmt::format_to(std::back_inserter(buffer), "{} {} {}", p.x(), p.y(), p.z());
      if (cloud.HasNormals()) {
        const Eigen::Vector3f& n = cloud.normals[i];
        fmt::format_to(std::back_inserter(buffer), " {} {} {}", n.x(), n.y(), n.z());
      }
      if (cloud.HasColors()) {
        const Color3ub& c = cloud.colors[i];
        fmt::format_to(std::back_inserter(buffer), " {} {} {}", c[0], c[1], c[2]);
      }
      buffer.push_back('\n');
    }
    body.assign(buffer.data(), buffer.size());
  } else {
    static_assert(sizeof(float) == 4, "PLY float32");
    const size_t stride = 12 + (cloud.HasNormals() ? 12 : 0) + (cloud.HasColors() ? 3 : 0);
    body.resize(stride * cloud.size());
    char* out = body.data();
    for (size_t i = 0; i < cloud.size(); ++i) {
      std::memcpy(out, cloud.points[i].data(), 12);
      out += 12;
      if (cloud.HasNormals()) {
        std::memcpy(out, cloud.normals[i].data(), 12);
        out += 12;
      }
      if (cloud.HasColors()) {
        std::memcpy(out, cloud.colors[i].data(), 3);
        out += 3;
      }
    }
  }
  return header + body;
}

void WritePcdCloud(const std::string& path, const PointCloud& cloud) {
  pcl::PCLPointCloud2 blob;
  if (cloud.HasColors()) {
    pcl::PointCloud<pcl::PointXYZRGB> rgb;
    rgb.resize(cloud.size());
    for (size_t i = 0; i < cloud.size(); ++i) {
      auto& p = rgb[i];
      p.x = cloud.points[i].x();
      p.y = cloud.points[i].y();
      p.z = cloud.points[i].z();
      p.r = cloud.colors[i][0];
      p.g = cloud.colors[i][1];
      p.b = cloud.colors[i][2];
    }
    pcl::toPCLPointCloud2(rgb, blob);
  } else {
    pcl::PointCloud<pcl::PointXYZ> xyz;
    xyz.resize(cloud.size());
    for (size_t i = 0; i < cloud.size(); ++i) {
      xyz[i].x = cloud.points[i].x();
      xyz[i].y = cloud.points[i].y();
      xyz[i].z = cloud.points[i].z();
    }
    pcl::toPCLPointCloud2(xyz, blob);
  }
  // PCL writes in place: write a temporary beside the target, then rename it.
  const std::filesystem::path target(path);
  const std::string temporary =
      (target.parent_path() / ("." + target.filename().string() + ".tmp")).string();
  pcl::PCDWriter writer;
  const int result = writer.writeBinary(temporary, blob);
  if (result != 0 || std::rename(temporary.c_str(), path.c_str()) != 0) {
    std::remove(temporary.c_str());
    SOPE_THROW("cannot write {}", path);
  }
}

}  // namespace

PointCloud ReadPointCloud(const std::string& path) {
  const std::string extension = FileExtension(path);
  PointCloud cloud;
  if (extension == "ply") {
    cloud = ReadPlyCloud(path);
  } else if (extension == "pcd") {
    cloud = ReadPcdCloud(path);
  } else {
    SOPE_THROW("point cloud {}: unsupported extension '{}' (expected .ply or .pcd)", path,
               extension);
  }
  cloud.Check();
  return cloud;
}

void WritePointCloud(const std::string& path, const PointCloud& cloud, PlyFormat ply_format) {
  cloud.Check();
  const std::string extension = FileExtension(path);
  if (extension == "pcd") {
    std::error_code ignored;
    const std::filesystem::path parent = std::filesystem::path(path).parent_path();
    if (!parent.empty()) std::filesystem::create_directories(parent, ignored);
    WritePcdCloud(path, cloud);
    return;
  }
  SOPE_CHECK(extension == "ply", "cannot write {}: unsupported extension '{}' (expected .ply "
             "or .pcd)", path, extension);
  WriteFileAtomic(path, PlyBytes(cloud, ply_format));
}

}  // namespace sope
