// Files: clear errors when reading, atomic writes (temporary + rename) so an interrupted
// program never leaves a half-written output behind.
#pragma once

#include <string>

#include <opencv2/core/mat.hpp>

namespace sope {

// Throws sope::Error "<what> <path>: <reason>" unless `path` is an existing readable
// regular file.
void RequireReadableFile(const std::string& path, const std::string& what);
// Whole file contents; throws sope::Error on failure.
std::string ReadFileToString(const std::string& path, const std::string& what);
// Writes `contents` to `path` atomically: a temporary file in the same directory, fsync,
// rename. Creates missing parent directories. Throws sope::Error on failure.
void WriteFileAtomic(const std::string& path, const std::string& contents);

// Reads an image with cv::imread flags (IMREAD_UNCHANGED by default); throws sope::Error
// naming the file when it is missing or cannot be decoded. EXR is enabled.
cv::Mat ReadImage(const std::string& path, int imread_flags = -1);
// Encodes by the file extension (png, exr, jpg, bmp, tif) and writes atomically.
void WriteImageAtomic(const std::string& path, const cv::Mat& image);
// OpenCV ≥ 4.5.2 disables its OpenEXR codec unless OPENCV_IO_ENABLE_OPENEXR is set; this
// sets it before the codecs initialise. Idempotent; called by ReadImage/WriteImageAtomic.
void EnableOpenExr();

// A directory written as a whole: files go into a hidden sibling `.<name>.tmp-XXXXXX`;
// Commit() renames it over `final_path` (replacing an existing directory only after the
// new one is complete). Without Commit() the destructor removes the temporary directory.
class StagedDirectory {
 public:
  explicit StagedDirectory(const std::string& final_path);
  ~StagedDirectory();
  StagedDirectory(const StagedDirectory&) = delete;
  StagedDirectory& operator=(const StagedDirectory&) = delete;

  // Where to write the files now.
  const std::string& path() const { return staging_path_; }
  void Commit();

 private:
  std::string final_path_;
  std::string staging_path_;
  bool committed_ = false;
};

// Joins path components with '/'.
std::string JoinPath(const std::string& a, const std::string& b);
// Lower-case extension without the dot ("PLY" → "ply"), empty if none.
std::string FileExtension(const std::string& path);

}  // namespace sope
