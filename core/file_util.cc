#include "core/file_util.h"

#include <fcntl.h>
#include <png.h>
#include <pthread.h>
#include <signal.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <csetjmp>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <mutex>
#include <random>
#include <sstream>
#include <thread>
#include <vector>

#include <opencv2/core/persistence.hpp>
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

// ---- staged temporaries and the interrupt policy ----------------------------------------

struct TemporaryRegistry {
  std::mutex mutex;
  std::vector<std::string> paths;
  std::string program = "sope";
  bool installed = false;
  std::atomic<std::atomic<bool>*> cooperative{nullptr};
};

TemporaryRegistry& Registry() {
  static TemporaryRegistry* registry = new TemporaryRegistry;  // never destroyed: the
  return *registry;  // policy thread may use it while static destructors run
}

// Removes `path` recursively; a writer in another thread may still add an entry to a
// staged directory (a rename inside it) while we remove it, so retry a few times.
void RemoveAllPersistently(const std::string& path) {
  constexpr int kAttempts = 20;
  for (int attempt = 0; attempt < kAttempts; ++attempt) {
    std::error_code error;
    fs::remove_all(path, error);
    if (!fs::exists(fs::symlink_status(path, error))) return;
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
}

// Self-pipe: the handler (async-signal-safe: one write(2)) wakes the waiting thread, which
// does the work. A handler rather than sigwait() because libraries start threads before
// main() that would not have the signals blocked and would take the default action.
int interrupt_pipe[2] = {-1, -1};

void OnInterruptSignal(int signal_number) {
  const int saved_errno = errno;
  const unsigned char byte = static_cast<unsigned char>(signal_number);
  ssize_t ignored = ::write(interrupt_pipe[1], &byte, 1);
  (void)ignored;
  errno = saved_errno;
}

[[noreturn]] void InterruptWaiter() {
  TemporaryRegistry& registry = Registry();
  int signal_number = 0;
  while (true) {
    unsigned char byte = 0;
    const ssize_t n = ::read(interrupt_pipe[0], &byte, 1);
    if (n != 1) {
      if (n < 0 && errno == EINTR) continue;
      if (n < 0) std::this_thread::sleep_for(std::chrono::milliseconds(10));
      continue;
    }
    signal_number = byte;
    // A live loop asked to stop cooperatively: the first signal only raises its flag.
    std::atomic<bool>* flag = registry.cooperative.load();
    if (flag != nullptr && !flag->exchange(true)) continue;
    break;
  }
  // Held until _exit: no temporary can be registered (created) after the cleanup.
  registry.mutex.lock();
  for (auto it = registry.paths.rbegin(); it != registry.paths.rend(); ++it) {
    RemoveAllPersistently(*it);
  }
  const std::string line = registry.program + ": error: interrupted\n";
  ssize_t ignored = ::write(STDERR_FILENO, line.data(), line.size());
  (void)ignored;
  ::_exit(128 + signal_number);
}

// PNG check through libpng with error/warning handlers of our own (the default ones print
// "libpng error: ..." on stderr before OpenCV reports a failure).
struct PngReadState {
  const std::string* bytes = nullptr;
  size_t offset = 0;
  std::string error;
  std::jmp_buf jump;
};

void PngError(png_structp png, png_const_charp message) {
  auto* state = static_cast<PngReadState*>(png_get_error_ptr(png));
  state->error = message != nullptr ? message : "unknown libpng error";
  std::longjmp(state->jump, 1);
}

void PngWarning(png_structp, png_const_charp) {}

void PngRead(png_structp png, png_bytep out, png_size_t length) {
  auto* state = static_cast<PngReadState*>(png_get_io_ptr(png));
  if (state->offset + length > state->bytes->size()) {
    png_error(png, "truncated file (ends inside the image data)");
  }
  std::memcpy(out, state->bytes->data() + state->offset, length);
  state->offset += length;
}

// Empty when `bytes` decode completely as a PNG, else libpng's reason.
std::string CheckPng(const std::string& bytes) {
  PngReadState state;
  state.bytes = &bytes;
  png_structp png =
      png_create_read_struct(PNG_LIBPNG_VER_STRING, &state, &PngError, &PngWarning);
  if (png == nullptr) return "cannot allocate the PNG reader";
  png_infop info = png_create_info_struct(png);
  std::vector<png_byte> row;
  if (info == nullptr) {
    png_destroy_read_struct(&png, nullptr, nullptr);
    return "cannot allocate the PNG reader";
  }
  if (setjmp(state.jump) != 0) {
    png_destroy_read_struct(&png, &info, nullptr);
    return state.error;
  }
  png_set_read_fn(png, &state, &PngRead);
  png_read_info(png, info);
  const png_uint_32 width = png_get_image_width(png, info);
  const png_uint_32 height = png_get_image_height(png, info);
  const int passes = png_set_interlace_handling(png);
  png_read_update_info(png, info);
  row.resize(png_get_rowbytes(png, info));
  for (int pass = 0; pass < passes; ++pass) {
    for (png_uint_32 y = 0; y < height; ++y) png_read_row(png, row.data(), nullptr);
  }
  png_read_end(png, nullptr);
  png_destroy_read_struct(&png, &info, nullptr);
  (void)width;
  return "";
}

}  // namespace

namespace internal {

void RegisterTemporary(const std::string& path, const std::function<void()>& create) {
  TemporaryRegistry& registry = Registry();
  std::lock_guard<std::mutex> lock(registry.mutex);
  create();
  registry.paths.push_back(path);
}

void FinishTemporary(const std::string& path, const std::function<void()>& finish) {
  TemporaryRegistry& registry = Registry();
  std::lock_guard<std::mutex> lock(registry.mutex);
  auto it = std::find(registry.paths.rbegin(), registry.paths.rend(), path);
  if (it != registry.paths.rend()) registry.paths.erase(std::next(it).base());
  finish();
}

size_t RegisteredTemporaryCount() {
  TemporaryRegistry& registry = Registry();
  std::lock_guard<std::mutex> lock(registry.mutex);
  return registry.paths.size();
}

}  // namespace internal

void InstallInterruptPolicy(const std::string& program) {
  TemporaryRegistry& registry = Registry();
  std::lock_guard<std::mutex> lock(registry.mutex);
  registry.program = program;
  if (registry.installed) return;
  SOPE_CHECK(::pipe2(interrupt_pipe, O_CLOEXEC) == 0, "cannot create the signal pipe: {}",
             std::strerror(errno));
  std::thread(InterruptWaiter).detach();
  // Also when inherited as ignored (SIGINT of a shell's background job): an interrupt
  // must still clean up, as the live loops' handlers always did.
  for (int signal_number : {SIGINT, SIGTERM}) {
    struct sigaction action {};
    action.sa_handler = &OnInterruptSignal;
    sigemptyset(&action.sa_mask);
    action.sa_flags = SA_RESTART;
    SOPE_CHECK(::sigaction(signal_number, &action, nullptr) == 0, "cannot handle signal {}: {}",
               signal_number, std::strerror(errno));
  }
  registry.installed = true;
}

bool BeginCooperativeInterrupts(std::atomic<bool>* flag) {
  TemporaryRegistry& registry = Registry();
  std::lock_guard<std::mutex> lock(registry.mutex);
  if (!registry.installed) return false;
  registry.cooperative.store(flag);
  return true;
}

bool EndCooperativeInterrupts() {
  TemporaryRegistry& registry = Registry();
  std::lock_guard<std::mutex> lock(registry.mutex);
  return registry.cooperative.exchange(nullptr) != nullptr;
}

int OpenRegularFileForReading(const std::string& path, const std::string& what) {
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC | O_NONBLOCK);
  SOPE_CHECK(fd >= 0, "cannot open {} {}: {}", what, path,
             errno == ENOENT ? std::string("no such file") : std::string(std::strerror(errno)));
  struct stat st {};
  if (::fstat(fd, &st) != 0 || !S_ISREG(st.st_mode)) {
    ::close(fd);
    SOPE_THROW("{} {}: not a regular file", what, path);
  }
  // Back to blocking reads (O_NONBLOCK only mattered for open(2) on a FIFO).
  const int flags = ::fcntl(fd, F_GETFL);
  if (flags >= 0) ::fcntl(fd, F_SETFL, flags & ~O_NONBLOCK);
  return fd;
}

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
  const int fd = OpenRegularFileForReading(path, what);
  std::string contents;
  struct stat st {};
  if (::fstat(fd, &st) == 0 && st.st_size > 0) contents.reserve(static_cast<size_t>(st.st_size));
  char buffer[1 << 16];
  while (true) {
    const ssize_t n = ::read(fd, buffer, sizeof(buffer));
    if (n < 0 && errno == EINTR) continue;
    if (n < 0) {
      const std::string reason = std::strerror(errno);
      ::close(fd);
      SOPE_THROW("{} {}: read error ({})", what, path, reason);
    }
    if (n == 0) break;
    contents.append(buffer, static_cast<size_t>(n));
  }
  ::close(fd);
  return contents;
}

void OpenFileStorageForReading(const std::string& path, const std::string& what,
                               cv::FileStorage* fs) {
  const std::string text = ReadFileToString(path, what);
  SOPE_CHECK(text.find("%YAML", 1) == std::string::npos,
             "{} {}: a %YAML directive after the start of the file (one YAML document only)",
             what, path);
  try {
    fs->open(path, cv::FileStorage::READ);
  } catch (const std::exception&) {  // cv::Exception, and std::length_error from its parser
    SOPE_THROW("{} {}: not a readable OpenCV YAML/XML file", what, path);
  }
  SOPE_CHECK(fs->isOpened(), "{} {}: not a readable OpenCV YAML/XML file", what, path);
}

void WriteFileAtomic(const std::string& path, const std::string& contents) {
  const fs::path target(path);
  const fs::path parent = target.has_parent_path() ? target.parent_path() : fs::path(".");
  const std::string temporary =
      (parent / ("." + target.filename().string() + ".tmp-" + RandomSuffix())).string();
  // Everything this creates (missing parents too) is created under the registry lock, so
  // nothing reappears inside a staged directory after the interrupt policy removed it.
  std::error_code error;
  int fd = -1;
  int open_errno = 0;
  internal::RegisterTemporary(temporary, [&] {
    fs::create_directories(parent, error);
    if (error) return;
    fd = ::open(temporary.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0644);
    open_errno = errno;
  });
  if (error) {
    internal::FinishTemporary(temporary, [] {});
    SOPE_THROW("cannot create directory {}: {}", parent.string(), error.message());
  }
  if (fd < 0) {
    internal::FinishTemporary(temporary, [] {});
    SOPE_THROW("cannot write {}: {}", path, std::strerror(open_errno));
  }
  auto fail = [&](const std::string& reason) {
    internal::FinishTemporary(temporary, [&] { ::unlink(temporary.c_str()); });
    SOPE_THROW("cannot write {}: {}", path, reason);
  };
  size_t written = 0;
  while (written < contents.size()) {
    const ssize_t n = ::write(fd, contents.data() + written, contents.size() - written);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) {
      const std::string reason = n < 0 ? std::strerror(errno) : "no space written";
      ::close(fd);
      fail(reason);
    }
    written += static_cast<size_t>(n);
  }
  if (::fsync(fd) != 0) {
    const std::string reason = std::strerror(errno);
    ::close(fd);
    fail(reason);
  }
  if (::close(fd) != 0) fail(std::strerror(errno));
  int rename_errno = 0;
  internal::FinishTemporary(temporary, [&] {
    if (::rename(temporary.c_str(), path.c_str()) != 0) {
      rename_errno = errno;
      ::unlink(temporary.c_str());
    }
  });
  SOPE_CHECK(rename_errno == 0, "cannot write {}: {}", path, std::strerror(rename_errno));
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
  static constexpr unsigned char kPngSignature[8] = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1a, '\n'};
  cv::Mat image;
  if (FileExtension(path) == "png") {
    const std::string bytes = ReadFileToString(path, "image");
    SOPE_CHECK(bytes.size() >= sizeof(kPngSignature) &&
                   std::memcmp(bytes.data(), kPngSignature, sizeof(kPngSignature)) == 0,
               "image {}: cannot decode (not a PNG file: no PNG signature)", path);
    const std::string problem = CheckPng(bytes);
    SOPE_CHECK(problem.empty(), "image {}: cannot decode (corrupt PNG: {})", path, problem);
    try {
      image = cv::imdecode(cv::Mat(1, static_cast<int>(bytes.size()), CV_8UC1,
                                   const_cast<char*>(bytes.data())),
                           imread_flags);
    } catch (const cv::Exception&) {
      image.release();
    }
  } else {
    try {
      image = cv::imread(path, imread_flags);
    } catch (const cv::Exception&) {
      image.release();
    }
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

StagedDirectory::StagedDirectory(const std::string& final_path, const std::string& marker)
    : StagedDirectory(final_path, [marker](const std::string& existing) {
        std::error_code ignored;
        return !marker.empty() && fs::is_regular_file(fs::path(existing) / marker, ignored);
      }) {}

StagedDirectory::StagedDirectory(const std::string& final_path,
                                 const std::function<bool(const std::string&)>& is_own_output)
    : final_path_(final_path) {
  fs::path target = fs::path(final_path).lexically_normal();
  if (target.filename().empty()) target = target.parent_path();
  final_path_ = target.string();
  const fs::path parent = target.has_parent_path() ? target.parent_path() : fs::path(".");
  std::error_code error;
  fs::create_directories(parent, error);
  SOPE_CHECK(!error, "cannot create directory {}: {}", parent.string(), error.message());
  std::error_code status_error;
  if (fs::exists(fs::symlink_status(target, status_error))) {
    SOPE_CHECK(fs::is_directory(fs::symlink_status(target, status_error)),
               "output {} exists and is not a directory", final_path_);
    const bool empty = fs::is_empty(target, status_error);
    SOPE_CHECK(empty || (is_own_output && is_own_output(final_path_)),
               "output {} is a non-empty directory that sope did not write; refusing to "
               "replace it (choose another output or remove it)",
               final_path_);
  }
  staging_path_ =
      (parent / ("." + target.filename().string() + ".tmp-" + RandomSuffix())).string();
  internal::RegisterTemporary(staging_path_,
                              [&] { fs::create_directory(staging_path_, error); });
  if (error) {
    internal::FinishTemporary(staging_path_, [] {});
    SOPE_THROW("cannot create directory {}: {}", staging_path_, error.message());
  }
}

StagedDirectory::~StagedDirectory() {
  if (!committed_) {
    internal::FinishTemporary(staging_path_, [&] {
      std::error_code ignored;
      fs::remove_all(staging_path_, ignored);
    });
  }
}

void StagedDirectory::Commit() {
  SOPE_CHECK(!committed_, "directory {} committed twice", final_path_);
  std::error_code error;
  if (fs::exists(final_path_, error)) {
    // rename(2) cannot replace a non-empty directory: move the old one aside first (under
    // the registry lock, so an interrupt finds either the old or the new output in place).
    const std::string old_path = staging_path_ + ".old";
    std::string failure;
    internal::RegisterTemporary(old_path, [&] {
      fs::rename(final_path_, old_path, error);
      if (error) {
        failure = fmt::format("cannot replace {}: {}", final_path_, error.message());
        return;
      }
      fs::rename(staging_path_, final_path_, error);
      if (error) {
        std::error_code ignored;
        fs::rename(old_path, final_path_, ignored);
        failure = fmt::format("cannot write {}: {}", final_path_, error.message());
      }
    });
    if (!failure.empty()) {
      internal::FinishTemporary(old_path, [] {});
      SOPE_THROW("{}", failure);
    }
    internal::FinishTemporary(staging_path_, [] {});
    committed_ = true;
    std::error_code ignored;
    fs::remove_all(old_path, ignored);
    internal::FinishTemporary(old_path, [] {});
  } else {
    internal::FinishTemporary(staging_path_, [&] { fs::rename(staging_path_, final_path_, error); });
    if (error) {
      // Still ours to clean up (the destructor removes it).
      internal::RegisterTemporary(staging_path_, [] {});
      SOPE_THROW("cannot write {}: {}", final_path_, error.message());
    }
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
