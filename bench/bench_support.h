// What every benchmark program shares (linked into each by sope_add_bench):
//  - logs (spdlog's default logger) go to stderr, as in the `sope` program (STYLE §8);
//  - DisplayReporter: the reporter --benchmark_format asks for (console, json, csv), for
//    programs that keep their own summary. With json or csv, stdout carries the report
//    alone: once the reporter is made, everything else the process prints on stdout
//    (printf, fmt::print, std::cout, summaries) goes to stderr, so `prog
//    --benchmark_format=json | python3 -m json.tool` parses.
//  - SOPE_BENCHMARK_MAIN(): BENCHMARK_MAIN() with that reporter.
#pragma once

#include <memory>
#include <ostream>
#include <vector>

#include <benchmark/benchmark.h>

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
