// Recognition database files (recogniser/database: Database::Open and the accessors of an
// opened file). Raw bytes almost never get past the checksums, so the input is taken in
// two ways:
//  - as it is, when it starts with the file signature "SOPEDB\r\n" (header and table
//    parsing: sizes, section bounds, checksums);
//  - otherwise as the eight section payloads, each prefixed by its byte count (uint32,
//    little-endian; make-seeds.sh cuts seeds from a real database), which this target
//    lays out as a well-formed file (page-aligned sections, correct table, checksums and
//    file size), so the fuzzer reaches the content validation behind the checksums.
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <string>
#include <vector>

#include "core/error.h"
#include "core/point_cloud.h"
#include "fuzz/fuzz_support.h"
#include "recogniser/crc32c.h"
#include "recogniser/database.h"

namespace {

constexpr char kMagic[8] = {'S', 'O', 'P', 'E', 'D', 'B', '\r', '\n'};
constexpr size_t kHeaderBytes = 64;
constexpr size_t kEntryBytes = 40;
constexpr uint64_t kAlignment = 4096;
constexpr const char* kSectionNames[] = {"metadata", "views",  "hasher", "standard",
                                         "codes",    "coarse", "fine",   "clouds"};
constexpr int kNumSections = 8;

template <typename T>
void Put(std::string* file, size_t offset, T value) {
  std::memcpy(&(*file)[offset], &value, sizeof(value));
}

uint64_t AlignUp(uint64_t value) { return (value + kAlignment - 1) / kAlignment * kAlignment; }

std::string LayOut(const uint8_t* data, size_t size) {
  std::vector<std::string> sections(kNumSections);
  size_t at = 0;
  for (int s = 0; s < kNumSections && at < size; ++s) {
    uint32_t length = 0;
    const size_t prefix = std::min<size_t>(sizeof(length), size - at);
    std::memcpy(&length, data + at, prefix);
    at += prefix;
    const size_t take = std::min<size_t>(length, size - at);
    sections[s].assign(reinterpret_cast<const char*>(data + at), take);
    at += take;
  }
  const uint64_t table_end = kHeaderBytes + kEntryBytes * kNumSections;
  uint64_t offset = AlignUp(table_end);
  std::vector<uint64_t> offsets(kNumSections);
  for (int s = 0; s < kNumSections; ++s) {
    offsets[s] = offset;
    offset = AlignUp(offset + sections[s].size());
  }
  std::string file(offset, '\0');
  std::memcpy(&file[0], kMagic, sizeof(kMagic));
  Put<uint32_t>(&file, 8, sope::kDatabaseFormatVersion);
  Put<uint32_t>(&file, 12, static_cast<uint32_t>(table_end));
  Put<uint32_t>(&file, 16, kNumSections);
  Put<uint64_t>(&file, 24, file.size());
  for (int s = 0; s < kNumSections; ++s) {
    const size_t entry = kHeaderBytes + kEntryBytes * s;
    std::strncpy(&file[entry], kSectionNames[s], 16);
    Put<uint64_t>(&file, entry + 16, offsets[s]);
    Put<uint64_t>(&file, entry + 24, sections[s].size());
    Put<uint32_t>(&file, entry + 32, sope::Crc32c(sections[s].data(), sections[s].size()));
    if (!sections[s].empty()) {
      std::memcpy(&file[offsets[s]], sections[s].data(), sections[s].size());
    }
  }
  Put<uint32_t>(&file, 20, sope::Crc32c(file.data(), table_end));
  return file;
}

void Use(const sope::Database& database) {
  sope::PointCloud cloud;
  for (int v = 0; v < database.num_views(); ++v) {
    database.ViewCloud(v, &cloud);
    cloud.Check();
    volatile float sink = database.coarse(v)[0] + database.fine(v)[database.fine_dim() - 1];
    (void)sink;
  }
  const Eigen::VectorXf coarse = Eigen::VectorXf::Zero(database.coarse_dim());
  const Eigen::VectorXf fine = Eigen::VectorXf::Zero(database.fine_dim());
  database.HashInput(database.Standardise(coarse), fine);
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  std::string path;
  if (size >= sizeof(kMagic) && std::memcmp(data, kMagic, sizeof(kMagic)) == 0) {
    path = sope::fuzz::WriteInput(data, size, "raw.sopedb");
  } else {
    const std::string file = LayOut(data, size);
    path = sope::fuzz::WriteInput(reinterpret_cast<const uint8_t*>(file.data()), file.size(),
                                  "laid-out.sopedb");
  }
  try {
    Use(*sope::Database::Open(path));
  } catch (const sope::Error&) {
  }
  return 0;
}
