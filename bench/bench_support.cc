#include "bench/bench_support.h"

#include <unistd.h>

#include <cstdio>
#include <iostream>

#include <ext/stdio_filebuf.h>
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

}  // namespace bench
}  // namespace sope
