// Files: clear errors when reading, atomic writes (temporary + rename) so an interrupted
// program never leaves a half-written output behind.
#pragma once

#include <atomic>
#include <functional>
#include <string>

#include <opencv2/core/mat.hpp>

namespace cv {
class FileStorage;
}  // namespace cv

namespace sope {

// Throws sope::Error "<what> <path>: <reason>" unless `path` is an existing readable
// regular file (a FIFO, device or directory is refused before anything opens it).
void RequireReadableFile(const std::string& path, const std::string& what);
// Opens `path` read-only without blocking (a FIFO named as an input would block open(2))
// and returns the descriptor only if it is a regular file; throws sope::Error otherwise.
int OpenRegularFileForReading(const std::string& path, const std::string& what);

// The signal policy, one for the whole program: SIGINT and SIGTERM (even when inherited as
// ignored) go to a handler that only wakes one waiting thread (self-pipe), which removes
// every staged temporary still registered (the `.name.tmp-XXXXXX` files and directories of
// WriteFileAtomic, StagedDirectory and the PCD writer), prints "<program>: error:
// interrupted" as the only line and exits with 128 + signal number. Call it first in
// main(); `program` is e.g. "sope decode".
void InstallInterruptPolicy(const std::string& program);
// Cooperative stops for live loops: between Begin and End the first SIGINT/SIGTERM only sets
// `*flag` (the loop stops between frames and cleans up); a second one ends the process as
// above. Begin returns false, doing nothing, when the policy is not installed (library use:
// the caller then handles signals itself); End returns whether Begin had succeeded.
bool BeginCooperativeInterrupts(std::atomic<bool>* flag);
bool EndCooperativeInterrupts();

namespace internal {
// The registry the policy cleans. RegisterTemporary runs `create` (which makes `path`)
// and records `path` under one lock, so an interrupt sees either neither or both;
// FinishTemporary runs `finish` (a rename or removal of `path`) and forgets `path` the
// same way. Paths are removed recursively on an interrupt, most recent first.
void RegisterTemporary(const std::string& path, const std::function<void()>& create);
void FinishTemporary(const std::string& path, const std::function<void()>& finish);
// Paths registered now (for tests).
size_t RegisteredTemporaryCount();
}  // namespace internal
// Whole file contents; throws sope::Error on failure.
std::string ReadFileToString(const std::string& path, const std::string& what);
// Writes `contents` to `path` atomically: a temporary file in the same directory, fsync,
// rename. Creates missing parent directories. Throws sope::Error on failure.
void WriteFileAtomic(const std::string& path, const std::string& contents);

// Opens an OpenCV FileStorage file (YAML or XML) at `path` for reading into *fs. Every
// failure is one sope::Error "<what> <path>: <reason>": not a readable regular file, the parser's
// exceptions (cv::Exception, and std:: exceptions its YAML parser throws), a file it opens
// as nothing — and, checked before parsing, a "%YAML" directive after the file's start
// (a second YAML document's header): OpenCV 4.6's parser loops forever on some of those
// (found by calibration_yaml_fuzz: "%YAML:1.0\n---%YAML:1\nc0\n--a").
void OpenFileStorageForReading(const std::string& path, const std::string& what,
                               cv::FileStorage* fs);

// Reads an image with cv::imread flags (IMREAD_UNCHANGED by default); throws sope::Error
// naming the file when it is missing or cannot be decoded. EXR is enabled. PNGs are
// checked by libpng with our own error handlers before OpenCV decodes them, so a corrupt
// file gives only the sope::Error (libpng's default handler prints its own stderr line).
cv::Mat ReadImage(const std::string& path, int imread_flags = -1);
// Encodes by the file extension (png, exr, jpg, bmp, tif) and writes atomically.
void WriteImageAtomic(const std::string& path, const cv::Mat& image);
// OpenCV ≥ 4.5.2 disables its OpenEXR codec unless OPENCV_IO_ENABLE_OPENEXR is set; this
// sets it before the codecs initialise. Idempotent; called by ReadImage/WriteImageAtomic.
void EnableOpenExr();

// A directory written as a whole: files go into a hidden sibling `.<name>.tmp-XXXXXX`;
// Commit() renames it over `final_path` (replacing an existing directory only after the
// new one is complete). Without Commit() the destructor removes the temporary directory;
// so does the interrupt policy on SIGINT/SIGTERM.
//
// Never deletes what sope did not write: an existing non-empty `final_path` is replaced
// only when it looks like an earlier output of the same kind — it holds the file `marker`
// (e.g. "frames.json"), or `is_own_output(final_path)` says so — else the constructor
// throws sope::Error naming the directory. With no marker and no predicate only a
// missing or empty directory is replaced.
class StagedDirectory {
 public:
  explicit StagedDirectory(const std::string& final_path, const std::string& marker = "");
  StagedDirectory(const std::string& final_path,
                  const std::function<bool(const std::string&)>& is_own_output);
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
