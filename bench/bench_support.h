// What every benchmark program shares (linked into each by sope_add_bench):
//  - logs (spdlog's default logger) go to stderr, as in the `sope` program (STYLE §8);
//  - DisplayReporter: the reporter --benchmark_format asks for (console, json, csv), for
//    programs that keep their own summary. With json or csv, stdout carries the report
//    alone: once the reporter is made, everything else the process prints on stdout
//    (printf, fmt::print, std::cout, summaries) goes to stderr, so `prog
//    --benchmark_format=json | python3 -m json.tool` parses.
//  - MedianTimesReporter: a DisplayReporter that also keeps each benchmark's real and CPU
//    time and counters (the median over repetitions where there are some) for a summary;
//  - ReadEveryByte(): the memory-bandwidth bound of a decoder (every frame byte read once);
//  - SOPE_BENCHMARK_MAIN(): BENCHMARK_MAIN() with that reporter.
#pragma once

#include <cstddef>
#include <cstdint>
#include <map>
#include <memory>
#include <ostream>
#include <string>
#include <vector>

#include <benchmark/benchmark.h>

namespace cv {
class Mat;
}  // namespace cv

namespace sope {
namespace bench {

class DisplayReporter : public benchmark::BenchmarkReporter {
 public:
  // After benchmark::Initialize (it reads --benchmark_format and --benchmark_color).
  DisplayReporter();
  // Console options for the console format (ignored for json and csv).
  explicit DisplayReporter(benchmark::ConsoleReporter::OutputOptions console_options);
  ~DisplayReporter() override;

  bool ReportContext(const Context& context) override;
  void ReportRuns(const std::vector<Run>& runs) override;
  void Finalize() override;
  // Whether the report is the human-readable table (stdout is shared with other output).
  bool console() const { return console_; }

 private:
  std::unique_ptr<benchmark::BenchmarkReporter> owned_;
  benchmark::BenchmarkReporter* display_ = nullptr;
  bool console_ = true;
  std::unique_ptr<std::ostream> report_stream_;
};

// Keeps the real and CPU time (ms) and the counters of every benchmark for a summary: the
// median over the repetitions where there are some, else the first run. Keys are
// "BM_Name" or "BM_Name/arg:1/…" (the run name without aggregate suffix).
class MedianTimesReporter : public DisplayReporter {
 public:
  struct Times {
    double real_ms = 0.0;
    double cpu_ms = 0.0;  // of the benchmark's main thread
    std::map<std::string, double> counters;
    // A counter's value; 0 when the benchmark did not set it.
    double Counter(const std::string& name) const;
  };
  using DisplayReporter::DisplayReporter;

  void ReportRuns(const std::vector<Run>& runs) override;
  // Zeros when the benchmark did not run (filtered out).
  Times Get(const std::string& key) const;

 private:
  std::map<std::string, Times> times_;
};

// Reads every byte of `images` once (8-bit frames; their maximum, so that the loop cannot
// be optimised away): the memory-bandwidth bound of a decoder that reads each frame byte
// once. Returns the largest level seen.
uint8_t ReadEveryByte(const std::vector<cv::Mat>& images);

// The bytes of `images` (every frame, whatever its depth and channels).
size_t FrameBytes(const std::vector<cv::Mat>& images);
// Rate counters of a decoder benchmark that reads `images` once per iteration: pixels/s
// (one frame's pixels) and frame_bytes/s (every frame's bytes, in 1024 units).
void SetFrameRateCounters(benchmark::State& state, const std::vector<cv::Mat>& images);

}  // namespace bench
}  // namespace sope

#define SOPE_BENCHMARK_MAIN()                                                \
  int main(int argc, char** argv) {                                          \
    ::benchmark::Initialize(&argc, argv);                                    \
    if (::benchmark::ReportUnrecognizedArguments(argc, argv)) return 1;      \
    ::sope::bench::DisplayReporter reporter;                                 \
    ::benchmark::RunSpecifiedBenchmarks(&reporter);                          \
    ::benchmark::Shutdown();                                                 \
    return 0;                                                                \
  }                                                                          \
  int main(int, char**)
