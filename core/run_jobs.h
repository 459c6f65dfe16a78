// Independent jobs on a few threads, handed out one at a time: the recogniser's pose
// stages and the scene recogniser's clusters and hypotheses.
#pragma once

#include <cstddef>
#include <functional>

namespace sope {

// Runs job(0) … job(count − 1) on `threads` threads (the calling one and threads − 1
// more; all on the calling thread when threads ≤ 1), each job once, handed out one at a
// time (the jobs' costs differ). When no more threads can be started, the started ones and
// the caller share the jobs. The first exception a job throws is rethrown here after
// every thread has stopped. (decoder/chunk_workers.h splits pixel chunks into fixed
// contiguous shares instead: equal chunks, per-worker workspaces.)
void RunJobs(int threads, size_t count, const std::function<void(size_t)>& job);

}  // namespace sope
