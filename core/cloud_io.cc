// Point-cloud files: PLY by our own reader/writer (binary little-endian by default), PCD
// through PCL's reader/writer.
#include <fcntl.h>
#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <random>
#include <sstream>
#include <vector>

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

// A colour property's value as a byte: clamped to 0..255, 0 for NaN (a float → uint8_t
// cast of anything else is undefined; found by ply_fuzz with an ASCII "uchar" of 1208).
// Colours only tint points, so a file that overflows them is read, not refused.
uint8_t ColourByte(double value) {
  if (!(value > 0.0)) return 0;
  return value >= 255.0 ? uint8_t{255} : static_cast<uint8_t>(value);
}

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
      cloud.colors.emplace_back(ColourByte(row[r]), ColourByte(row[g]), ColourByte(row[b]));
    }
    if (has_normal) cloud.normals.emplace_back(row[nx], row[ny], row[nz]);
  }
  return cloud;
}

// Splits on blanks.
std::vector<std::string> Words(const std::string& line) {
  std::istringstream stream(line);
  std::vector<std::string> words;
  for (std::string word; stream >> word;) words.push_back(word);
  return words;
}

// A whole-token non-negative integer, ≤ `limit`.
uint64_t PcdNumber(const std::string& word, uint64_t limit, const std::string& what,
                   const std::string& path) {
  SOPE_CHECK(!word.empty() && word.size() <= 19 &&
                 word.find_first_not_of("0123456789") == std::string::npos,
             "point cloud {}: PCD header {} '{}' is not a non-negative integer", path, what,
             word);
  const uint64_t value = std::stoull(word);
  SOPE_CHECK(value <= limit, "point cloud {}: PCD header {} {} is beyond the limit {}", path,
             what, value, limit);
  return value;
}

void ValidatePcdHeader(const std::string& data, const std::string& path) {
  constexpr size_t kMaxFields = 256;
  constexpr uint64_t kMaxCount = 1 << 16;
  constexpr uint64_t kMaxPoints = uint64_t{1} << 32;
  SOPE_CHECK(!data.empty(), "point cloud {}: empty file (not a PCD file)", path);
  std::vector<std::string> fields;
  std::vector<uint64_t> sizes, counts;
  std::vector<char> types;
  uint64_t width = 0, height = 1, points = 0;
  bool have_width = false, have_points = false;
  std::string encoding;
  size_t offset = 0;
  int line_number = 0;
  while (encoding.empty()) {
    SOPE_CHECK(offset < data.size(), "point cloud {}: PCD header ends before its DATA line",
               path);
    size_t end = data.find('\n', offset);
    if (end == std::string::npos) end = data.size();
    std::string line = data.substr(offset, end - offset);
    offset = end + 1;
    ++line_number;
    // PCL's reader skips only truly empty lines: one of blanks or a lone carriage return
    // makes PCDReader::read dereference null (found by pcd_fuzz; PCL 1.13).
    SOPE_CHECK(line.empty() || line.find_first_not_of(" \t\r\v\f") != std::string::npos,
               "point cloud {}: PCD header line {} is blank but not empty (only spaces or a "
               "carriage return)",
               path, line_number);
    if (!line.empty() && line.back() == '\r') line.pop_back();
    const std::vector<std::string> words = Words(line);
    if (words.empty() || words[0][0] == '#') continue;
    const std::string& key = words[0];
    const size_t n = words.size() - 1;
    if (key == "VERSION") {
      SOPE_CHECK(n == 1, "point cloud {}: malformed PCD header line '{}'", path, line);
    } else if (key == "FIELDS") {
      SOPE_CHECK(n >= 1 && n <= kMaxFields, "point cloud {}: PCD header has {} fields", path, n);
      fields.assign(words.begin() + 1, words.end());
    } else if (key == "SIZE") {
      for (size_t i = 1; i <= n; ++i) {
        const uint64_t size = PcdNumber(words[i], 8, "SIZE", path);
        SOPE_CHECK(size == 1 || size == 2 || size == 4 || size == 8,
                   "point cloud {}: PCD field size {} (expected 1, 2, 4 or 8)", path, size);
        sizes.push_back(size);
      }
    } else if (key == "TYPE") {
      for (size_t i = 1; i <= n; ++i) {
        SOPE_CHECK(words[i] == "F" || words[i] == "I" || words[i] == "U",
                   "point cloud {}: PCD field type '{}' (expected F, I or U)", path, words[i]);
        types.push_back(words[i][0]);
      }
    } else if (key == "COUNT") {
      for (size_t i = 1; i <= n; ++i) {
        const uint64_t count = PcdNumber(words[i], kMaxCount, "COUNT", path);
        SOPE_CHECK(count >= 1, "point cloud {}: PCD field count 0", path);
        counts.push_back(count);
      }
    } else if (key == "WIDTH") {
      SOPE_CHECK(n == 1, "point cloud {}: malformed PCD header line '{}'", path, line);
      width = PcdNumber(words[1], kMaxPoints, "WIDTH", path);
      have_width = true;
    } else if (key == "HEIGHT") {
      SOPE_CHECK(n == 1, "point cloud {}: malformed PCD header line '{}'", path, line);
      height = PcdNumber(words[1], kMaxPoints, "HEIGHT", path);
    } else if (key == "VIEWPOINT") {
      SOPE_CHECK(n == 7, "point cloud {}: PCD VIEWPOINT needs 7 numbers", path);
    } else if (key == "POINTS") {
      SOPE_CHECK(n == 1, "point cloud {}: malformed PCD header line '{}'", path, line);
      points = PcdNumber(words[1], kMaxPoints, "POINTS", path);
      have_points = true;
    } else if (key == "DATA") {
      SOPE_CHECK(n == 1 && (words[1] == "ascii" || words[1] == "binary" ||
                            words[1] == "binary_compressed"),
                 "point cloud {}: PCD DATA must be ascii, binary or binary_compressed", path);
      encoding = words[1];
    } else {
      SOPE_THROW("point cloud {}: not a PCD file (unexpected header line '{}')", path,
                 line.substr(0, 40));
    }
  }
  SOPE_CHECK(!fields.empty() && have_width,
             "point cloud {}: PCD header lacks FIELDS or WIDTH", path);
  if (counts.empty()) counts.assign(fields.size(), 1);
  SOPE_CHECK(sizes.size() == fields.size() && types.size() == fields.size() &&
                 counts.size() == fields.size(),
             "point cloud {}: PCD header has {} fields but {} sizes, {} types, {} counts", path,
             fields.size(), sizes.size(), types.size(), counts.size());
  for (size_t i = 0; i < fields.size(); ++i) {
    SOPE_CHECK(types[i] != 'F' || sizes[i] == 4 || sizes[i] == 8,
               "point cloud {}: PCD field {} is F of size {}", path, fields[i], sizes[i]);
  }
  SOPE_CHECK(height >= 1 && width <= kMaxPoints / height,
             "point cloud {}: PCD WIDTH {} x HEIGHT {} is invalid", path, width, height);
  if (!have_points) points = width * height;
  SOPE_CHECK(points == width * height, "point cloud {}: PCD POINTS {} but WIDTH x HEIGHT = {}",
             path, points, width * height);
  uint64_t point_step = 0, values = 0;
  for (size_t i = 0; i < fields.size(); ++i) {
    point_step += sizes[i] * counts[i];
    values += counts[i];
  }
  const uint64_t body = offset <= data.size() ? data.size() - offset : 0;
  if (encoding == "binary") {
    SOPE_CHECK(points <= body / point_step,
               "point cloud {}: PCD data truncated ({} points of {} bytes need {} bytes, {} "
               "present)", path, points, point_step, points * point_step, body);
  } else if (encoding == "binary_compressed") {
    SOPE_CHECK(body >= 8, "point cloud {}: PCD compressed data truncated", path);
    uint32_t compressed = 0, uncompressed = 0;
    std::memcpy(&compressed, data.data() + offset, 4);
    std::memcpy(&uncompressed, data.data() + offset + 4, 4);
    SOPE_CHECK(compressed <= body - 8 && uncompressed == points * point_step,
               "point cloud {}: PCD compressed data sizes ({} compressed, {} uncompressed) do "
               "not match the header ({} points of {} bytes, {} bytes present)",
               path, compressed, uncompressed, points, point_step, body - 8);
  } else {
    // ASCII: every value takes at least one character and one separator.
    SOPE_CHECK(points <= (body + 1) / (2 * values),
               "point cloud {}: PCD ASCII data truncated ({} points of {} values cannot fit "
               "in {} bytes)", path, points, values, body);
  }
}

PointCloud ReadPcdCloud(const std::string& path) {
  // PCL's reader dereferences a header it has not checked (an empty file or "hello world"
  // crashes it): validate the header and the data size against it first.
  ValidatePcdHeader(ReadFileToString(path, "point cloud"), path);
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
  // PCL writes in place: write a registered temporary beside the target (removed on an
  // interrupt like WriteFileAtomic's), then rename it.
  const std::filesystem::path target(path);
  static thread_local std::mt19937_64 engine(std::random_device{}());
  const std::string temporary =
      (target.parent_path() /
       fmt::format(".{}.tmp-{:06x}", target.filename().string(), engine() & 0xffffff))
          .string();
  int fd = -1;
  internal::RegisterTemporary(temporary, [&] {
    fd = ::open(temporary.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0644);
  });
  if (fd < 0) {
    const std::string reason = std::strerror(errno);
    internal::FinishTemporary(temporary, [] {});
    SOPE_THROW("cannot write {}: {}", path, reason);
  }
  ::close(fd);
  pcl::PCDWriter writer;
  const int result = writer.writeBinary(temporary, blob);
  bool renamed = false;
  internal::FinishTemporary(temporary, [&] {
    renamed = result == 0 && std::rename(temporary.c_str(), path.c_str()) == 0;
    if (!renamed) std::remove(temporary.c_str());
  });
  SOPE_CHECK(renamed, "cannot write {}", path);
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
