#include "bench/bench_support.h"

#include <unistd.h>

#include <algorithm>
#include <cstdio>
#include <iostream>

#include <ext/stdio_filebuf.h>
#include <opencv2/core.hpp>
#include <spdlog/sinks/stdout_color_sinks.h>
#include <spdlog/spdlog.h>

namespace sope {
namespace bench {
namespace {

// Before main(): library logs on stderr from the first line on.
const bool kLogsOnStderr = [] {
  spdlog::set_default_logger(spdlog::stderr_color_mt("bench"));
  return true;
}();

// The report keeps the real stdout; stdout itself becomes stderr.
std::unique_ptr<std::ostream> TakeStdoutForReport() {
  std::fflush(stdout);
  std::cout.flush();
  const int report_fd = ::dup(STDOUT_FILENO);
  if (report_fd < 0 || ::dup2(STDERR_FILENO, STDOUT_FILENO) < 0) return nullptr;
  struct Stream : std::ostream {
    explicit Stream(int fd) : std::ostream(nullptr), buffer(fd, std::ios::out) { rdbuf(&buffer); }
    __gnu_cxx::stdio_filebuf<char> buffer;
  };
  return std::make_unique<Stream>(report_fd);
}

}  // namespace

DisplayReporter::DisplayReporter() {
  (void)kLogsOnStderr;
  display_ = benchmark::CreateDefaultDisplayReporter();  // a static instance: not owned
  console_ = dynamic_cast<benchmark::ConsoleReporter*>(display_) != nullptr;
  if (!console_) {
    report_stream_ = TakeStdoutForReport();
    if (report_stream_) display_->SetOutputStream(report_stream_.get());
  }
}

DisplayReporter::DisplayReporter(benchmark::ConsoleReporter::OutputOptions console_options)
    : DisplayReporter() {
  if (console_) {
    owned_ = std::make_unique<benchmark::ConsoleReporter>(console_options);
    display_ = owned_.get();
  }
}

DisplayReporter::~DisplayReporter() {
  if (report_stream_) report_stream_->flush();
}

bool DisplayReporter::ReportContext(const Context& context) {
  display_->SetErrorStream(&GetErrorStream());
  if (!report_stream_) display_->SetOutputStream(&GetOutputStream());
  return display_->ReportContext(context);
}

void DisplayReporter::ReportRuns(const std::vector<Run>& runs) { display_->ReportRuns(runs); }

void DisplayReporter::Finalize() {
  display_->Finalize();
  if (report_stream_) report_stream_->flush();
}

double MedianTimesReporter::Times::Counter(const std::string& name) const {
  const auto it = counters.find(name);
  return it == counters.end() ? 0.0 : it->second;
}

void MedianTimesReporter::ReportRuns(const std::vector<Run>& runs) {
  for (const Run& run : runs) {
    if (run.error_occurred) continue;
    std::string key = run.run_name.function_name;
    if (!run.run_name.args.empty()) key += "/" + run.run_name.args;
    const bool median = run.run_type == Run::RT_Aggregate && run.aggregate_name == "median";
    if (median || (run.run_type == Run::RT_Iteration && times_.count(key) == 0)) {
      Times times;
      times.real_ms = run.GetAdjustedRealTime();
      times.cpu_ms = run.GetAdjustedCPUTime();
      for (const auto& [name, counter] : run.counters) times.counters[name] = counter.value;
      times_[key] = std::move(times);
    }
  }
  DisplayReporter::ReportRuns(runs);
}

MedianTimesReporter::Times MedianTimesReporter::Get(const std::string& key) const {
  const auto it = times_.find(key);
  return it == times_.end() ? Times{} : it->second;
}

uint8_t ReadEveryByte(const std::vector<cv::Mat>& images) {
  uint8_t max_level = 0;
  for (const cv::Mat& image : images) {
    const uint8_t* __restrict data = image.ptr<uint8_t>();
    const size_t size = image.total();
    uint8_t local = 0;
    for (size_t i = 0; i < size; ++i) local = std::max(local, data[i]);
    max_level = std::max(max_level, local);
  }
  return max_level;
}

size_t FrameBytes(const std::vector<cv::Mat>& images) {
  size_t bytes = 0;
  for (const cv::Mat& image : images) bytes += image.total() * image.elemSize();
  return bytes;
}

void SetFrameRateCounters(benchmark::State& state, const std::vector<cv::Mat>& images) {
  state.counters["pixels/s"] =
      benchmark::Counter(static_cast<double>(images.empty() ? 0 : images.front().total()),
                         benchmark::Counter::kIsIterationInvariantRate);
  state.counters["frame_bytes/s"] = benchmark::Counter(
      static_cast<double>(FrameBytes(images)), benchmark::Counter::kIsIterationInvariantRate,
      benchmark::Counter::kIs1024);
}

}  // namespace bench
}  // namespace sope
