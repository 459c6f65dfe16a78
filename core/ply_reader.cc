#include "core/ply_reader.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <sstream>

#include "core/error.h"
#include "core/file_util.h"

namespace sope {
namespace internal {
namespace {

enum class Encoding { kAscii, kLittle, kBig };

PlyType ParseType(const std::string& type, const std::string& path) {
  if (type == "char" || type == "int8") return PlyType::kInt8;
  if (type == "uchar" || type == "uint8") return PlyType::kUint8;
  if (type == "short" || type == "int16") return PlyType::kInt16;
  if (type == "ushort" || type == "uint16") return PlyType::kUint16;
  if (type == "int" || type == "int32") return PlyType::kInt32;
  if (type == "uint" || type == "uint32") return PlyType::kUint32;
  if (type == "float" || type == "float32") return PlyType::kFloat32;
  if (type == "double" || type == "float64") return PlyType::kFloat64;
  SOPE_THROW("PLY {}: unknown property type '{}'", path, type);
}

size_t TypeSize(PlyType type) {
  switch (type) {
    case PlyType::kInt8:
    case PlyType::kUint8: return 1;
    case PlyType::kInt16:
    case PlyType::kUint16: return 2;
    case PlyType::kInt32:
    case PlyType::kUint32:
    case PlyType::kFloat32: return 4;
    case PlyType::kFloat64: return 8;
  }
  return 0;
}

class BinaryCursor {
 public:
  BinaryCursor(const std::string& data, size_t offset, bool big_endian, const std::string& path)
      : data_(data), offset_(offset), big_endian_(big_endian), path_(path) {}

  double Read(PlyType type) {
    const size_t size = TypeSize(type);
    SOPE_CHECK(offset_ + size <= data_.size(), "PLY {}: truncated (ends inside the data)",
               path_);
    unsigned char bytes[8];
    std::memcpy(bytes, data_.data() + offset_, size);
    offset_ += size;
    if (big_endian_) std::reverse(bytes, bytes + size);
    switch (type) {
      case PlyType::kInt8: return static_cast<int8_t>(bytes[0]);
      case PlyType::kUint8: return bytes[0];
      case PlyType::kInt16: return Load<int16_t>(bytes);
      case PlyType::kUint16: return Load<uint16_t>(bytes);
      case PlyType::kInt32: return Load<int32_t>(bytes);
      case PlyType::kUint32: return Load<uint32_t>(bytes);
      case PlyType::kFloat32: return Load<float>(bytes);
      case PlyType::kFloat64: return Load<double>(bytes);
    }
    return 0.0;
  }

 private:
  template <typename T>
  static double Load(const unsigned char* bytes) {
    T value;
    std::memcpy(&value, bytes, sizeof(T));
    return static_cast<double>(value);
  }
  const std::string& data_;
  size_t offset_;
  bool big_endian_;
  const std::string& path_;
};

class AsciiCursor {
 public:
  AsciiCursor(const std::string& data, size_t offset, const std::string& path)
      : stream_(data.substr(offset)), path_(path) {}
  double Read(PlyType) {
    double value;
    SOPE_CHECK(static_cast<bool>(stream_ >> value),
               "PLY {}: truncated or non-numeric ASCII data", path_);
    return value;
  }

 private:
  std::istringstream stream_;
  const std::string& path_;
};

template <typename Cursor>
void ReadBody(Cursor& cursor, const std::vector<std::string>& wanted,
              std::vector<PlyElement>* elements, const std::string& path) {
  for (PlyElement& element : *elements) {
    const bool keep = std::find(wanted.begin(), wanted.end(), element.name) != wanted.end();
    size_t scalar_count = 0;
    for (const PlyProperty& p : element.properties) scalar_count += !p.is_list;
    if (keep) {
      element.rows.assign(element.count, std::vector<double>(scalar_count));
      element.lists.resize(element.count);
    }
    for (size_t i = 0; i < element.count; ++i) {
      size_t column = 0;
      bool list_taken = false;
      for (const PlyProperty& p : element.properties) {
        if (!p.is_list) {
          const double value = cursor.Read(p.type);
          if (keep) element.rows[i][column] = value;
          ++column;
          continue;
        }
        const double count = cursor.Read(p.list_count_type);
        SOPE_CHECK(count >= 0 && count < 1e6, "PLY {}: invalid list length {}", path, count);
        for (int k = 0; k < static_cast<int>(count); ++k) {
          const double value = cursor.Read(p.type);
          // List entries are indices: a value int64 cannot hold (or NaN) is refused, not
          // cast (undefined; found by ply_fuzz with an ASCII 1e98).
          SOPE_CHECK(std::abs(value) < 9.0e18, "PLY {}: list entry {} is not an index", path,
                     value);
          if (keep && !list_taken) element.lists[i].push_back(static_cast<int64_t>(value));
        }
        list_taken = true;
      }
    }
  }
}

}  // namespace

int PlyElement::Column(const std::string& property_name) const {
  int column = 0;
  for (const PlyProperty& p : properties) {
    if (p.is_list) continue;
    if (p.name == property_name) return column;
    ++column;
  }
  return -1;
}

std::vector<PlyElement> ReadPly(const std::string& path, const std::vector<std::string>& wanted) {
  const std::string data = ReadFileToString(path, "PLY");
  SOPE_CHECK(data.rfind("ply", 0) == 0, "PLY {}: missing 'ply' magic", path);
  const size_t header_end = data.find("end_header");
  SOPE_CHECK(header_end != std::string::npos, "PLY {}: no end_header", path);
  size_t body = data.find('\n', header_end);
  SOPE_CHECK(body != std::string::npos, "PLY {}: truncated header", path);
  ++body;
  std::istringstream header(data.substr(0, header_end));
  std::string line;
  Encoding encoding = Encoding::kAscii;
  bool have_format = false;
  std::vector<PlyElement> elements;
  while (std::getline(header, line)) {
    if (!line.empty() && line.back() == '\r') line.pop_back();
    std::istringstream words(line);
    std::string keyword;
    words >> keyword;
    if (keyword == "format") {
      std::string name;
      words >> name;
      if (name == "ascii") encoding = Encoding::kAscii;
      else if (name == "binary_little_endian") encoding = Encoding::kLittle;
      else if (name == "binary_big_endian") encoding = Encoding::kBig;
      else SOPE_THROW("PLY {}: unknown format '{}'", path, name);
      have_format = true;
    } else if (keyword == "element") {
      PlyElement element;
      long long count = -1;
      words >> element.name >> count;
      SOPE_CHECK(!element.name.empty() && count >= 0, "PLY {}: malformed line '{}'", path, line);
      element.count = static_cast<size_t>(count);
      elements.push_back(element);
    } else if (keyword == "property") {
      SOPE_CHECK(!elements.empty(), "PLY {}: property before any element", path);
      PlyProperty property;
      std::string type;
      words >> type;
      if (type == "list") {
        std::string count_type, item_type;
        words >> count_type >> item_type >> property.name;
        property.is_list = true;
        property.list_count_type = ParseType(count_type, path);
        property.type = ParseType(item_type, path);
      } else {
        property.type = ParseType(type, path);
        words >> property.name;
      }
      SOPE_CHECK(!property.name.empty(), "PLY {}: malformed line '{}'", path, line);
      elements.back().properties.push_back(property);
    }
  }
  SOPE_CHECK(have_format, "PLY {}: no format line", path);
  // Counts against the file size before anything is allocated or looped over: a binary
  // row takes at least the bytes of its scalars and list counts, an ASCII row at least two
  // characters per scalar or list count (a digit and a separator).
  const size_t body_bytes = data.size() - std::min(body, data.size());
  size_t needed = 0;
  for (const PlyElement& element : elements) {
    size_t row_bytes = 0;
    for (const PlyProperty& p : element.properties) {
      row_bytes += encoding == Encoding::kAscii ? 2 : TypeSize(p.is_list ? p.list_count_type : p.type);
    }
    // An element without properties takes no bytes: bound its count by the file size.
    const size_t per_row = std::max<size_t>(row_bytes, 1);
    const size_t slack = encoding == Encoding::kAscii ? 1 : 0;
    SOPE_CHECK(element.count <= (body_bytes + slack - std::min(needed, body_bytes + slack)) / per_row,
               "PLY {}: truncated or corrupt: element '{}' claims {} rows, more than the {} "
               "bytes of data can hold",
               path, element.name, element.count, body_bytes);
    needed += element.count * per_row;
  }
  if (encoding == Encoding::kAscii) {
    AsciiCursor cursor(data, body, path);
    ReadBody(cursor, wanted, &elements, path);
  } else {
    BinaryCursor cursor(data, body, encoding == Encoding::kBig, path);
    ReadBody(cursor, wanted, &elements, path);
  }
  return elements;
}

}  // namespace internal
}  // namespace sope
