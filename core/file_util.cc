#include "core/file_util.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <random>
#include <sstream>
#include <vector>

#include <opencv2/imgcodecs.hpp>

#include "core/error.h"

namespace sope {
namespace fs = std::filesystem;
namespace {

std::string RandomSuffix() {
  static thread_local std::mt19937_64 engine(std::random_device{}() ^
                                             static_cast<uint64_t>(::getpid()));
  static constexpr char kAlphabet[] = "abcdefghijklmnopqrstuvwxyz0123456789";
  std::string suffix(6, 'x');
  for (char& c : suffix) c = kAlphabet[engine() % (sizeof(kAlphabet) - 1)];
  return suffix;
}

}  // namespace

void RequireReadableFile(const std::string& path, const std::string& what) {
  std::error_code error;
  const fs::file_status status = fs::status(path, error);
  SOPE_CHECK(!error && fs::exists(status), "{} {}: no such file", what, path);
  SOPE_CHECK(fs::is_regular_file(status), "{} {}: not a regular file", what, path);
  SOPE_CHECK(::access(path.c_str(), R_OK) == 0, "{} {}: not readable ({})", what, path,
             std::strerror(errno));
}

std::string ReadFileToString(const std::string& path, const std::string& what) {
  RequireReadableFile(path, what);
  std::ifstream stream(path, std::ios::binary);
  SOPE_CHECK(stream.good(), "{} {}: cannot open", what, path);
  std::ostringstream contents;
  contents << stream.rdbuf();
  SOPE_CHECK(!stream.bad(), "{} {}: read error", what, path);
  return contents.str();
}

void WriteFileAtomic(const std::string& path, const std::string& contents) {
  const fs::path target(path);
  const fs::path parent = target.has_parent_path() ? target.parent_path() : fs::path(".");
  std::error_code error;
  fs::create_directories(parent, error);
  SOPE_CHECK(!error, "cannot create directory {}: {}", parent.string(), error.message());
  const std::string temporary =
      (parent / ("." + target.filename().string() + ".tmp-" + RandomSuffix())).string();
  const int fd = ::open(temporary.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0644);
  SOPE_CHECK(fd >= 0, "cannot write {}: {}", path, std::strerror(errno));
  size_t written = 0;
  while (written < contents.size()) {
    const ssize_t n = ::write(fd, contents.data() + written, contents.size() - written);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) {
      const std::string reason = std::strerror(errno);
      ::close(fd);
      ::unlink(temporary.c_str());
      SOPE_THROW("cannot write {}: {}", path, reason);
    }
    written += static_cast<size_t>(n);
  }
  if (::fsync(fd) != 0 || ::close(fd) != 0) {
    const std::string reason = std::strerror(errno);
    ::unlink(temporary.c_str());
    SOPE_THROW("cannot write {}: {}", path, reason);
  }
  if (::rename(temporary.c_str(), path.c_str()) != 0) {
    const std::string reason = std::strerror(errno);
    ::unlink(temporary.c_str());
    SOPE_THROW("cannot write {}: {}", path, reason);
  }
}

void EnableOpenExr() {
  static const bool enabled = [] {
    ::setenv("OPENCV_IO_ENABLE_OPENEXR", "1", /*overwrite=*/0);
    return true;
  }();
  (void)enabled;
}

cv::Mat ReadImage(const std::string& path, int imread_flags) {
  EnableOpenExr();
  RequireReadableFile(path, "image");
  cv::Mat image;
  try {
    image = cv::imread(path, imread_flags);
  } catch (const cv::Exception&) {
    image.release();
  }
  SOPE_CHECK(!image.empty(), "image {}: cannot decode (corrupt or unsupported format)", path);
  return image;
}

void WriteImageAtomic(const std::string& path, const cv::Mat& image) {
  EnableOpenExr();
  SOPE_CHECK(!image.empty(), "cannot write {}: empty image", path);
  const std::string extension = FileExtension(path);
  SOPE_CHECK(!extension.empty(), "cannot write {}: no file extension", path);
  std::vector<uchar> bytes;
  bool ok = false;
  try {
    ok = cv::imencode("." + extension, image, bytes);
  } catch (const cv::Exception& e) {
    SOPE_THROW("cannot encode {}: {}", path, e.err);
  }
  SOPE_CHECK(ok, "cannot encode {}", path);
  WriteFileAtomic(path, std::string(bytes.begin(), bytes.end()));
}

StagedDirectory::StagedDirectory(const std::string& final_path) : final_path_(final_path) {
  fs::path target = fs::path(final_path).lexically_normal();
  if (target.filename().empty()) target = target.parent_path();
  final_path_ = target.string();
  const fs::path parent = target.has_parent_path() ? target.parent_path() : fs::path(".");
  std::error_code error;
  fs::create_directories(parent, error);
  SOPE_CHECK(!error, "cannot create directory {}: {}", parent.string(), error.message());
  std::error_code status_error;
  SOPE_CHECK(!fs::exists(target, status_error) || fs::is_directory(target, status_error),
             "output {} exists and is not a directory", final_path_);
  staging_path_ =
      (parent / ("." + target.filename().string() + ".tmp-" + RandomSuffix())).string();
  fs::create_directory(staging_path_, error);
  SOPE_CHECK(!error, "cannot create directory {}: {}", staging_path_, error.message());
}

StagedDirectory::~StagedDirectory() {
  if (!committed_) {
    std::error_code ignored;
    fs::remove_all(staging_path_, ignored);
  }
}

void StagedDirectory::Commit() {
  SOPE_CHECK(!committed_, "directory {} committed twice", final_path_);
  std::error_code error;
  if (fs::exists(final_path_, error)) {
    // rename(2) cannot replace a non-empty directory: move the old one aside first.
    const std::string old_path = staging_path_ + ".old";
    fs::rename(final_path_, old_path, error);
    SOPE_CHECK(!error, "cannot replace {}: {}", final_path_, error.message());
    fs::rename(staging_path_, final_path_, error);
    if (error) {
      std::error_code ignored;
      fs::rename(old_path, final_path_, ignored);
      SOPE_THROW("cannot write {}: {}", final_path_, error.message());
    }
    fs::remove_all(old_path, error);
  } else {
    fs::rename(staging_path_, final_path_, error);
    SOPE_CHECK(!error, "cannot write {}: {}", final_path_, error.message());
  }
  committed_ = true;
}

std::string JoinPath(const std::string& a, const std::string& b) {
  return (fs::path(a) / b).string();
}

std::string FileExtension(const std::string& path) {
  std::string extension = fs::path(path).extension().string();
  if (!extension.empty() && extension[0] == '.') extension.erase(0, 1);
  std::transform(extension.begin(), extension.end(), extension.begin(),
                 [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  return extension;
}

}  // namespace sope
