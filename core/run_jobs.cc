#include "core/run_jobs.h"

#include <algorithm>
#include <atomic>
#include <exception>
#include <system_error>
#include <thread>
#include <vector>

namespace sope {

void RunJobs(int threads, size_t count, const std::function<void(size_t)>& job) {
  const size_t workers_wanted = std::min<size_t>(std::max(1, threads), count);
  if (workers_wanted <= 1) {
    for (size_t j = 0; j < count; ++j) job(j);
    return;
  }
  std::atomic<size_t> next{0};
  std::vector<std::exception_ptr> errors(workers_wanted);
  const auto work = [&](size_t t) {
    try {
      for (size_t j = next++; j < count; j = next++) job(j);
    } catch (...) {
      errors[t] = std::current_exception();
      next = count;  // the others stop too
    }
  };
  std::vector<std::thread> workers;
  try {
    for (size_t t = 1; t < workers_wanted; ++t) workers.emplace_back(work, t);
  } catch (const std::system_error&) {
    // No more threads: those started and this one take every job.
  }
  work(0);
  for (std::thread& worker : workers) worker.join();
  for (const std::exception_ptr& error : errors) {
    if (error) std::rethrow_exception(error);
  }
}

}  // namespace sope
