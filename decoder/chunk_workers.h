// The decoders' thread loop (Gray and phase): pixel chunks split over worker threads.
#pragma once

#include <algorithm>
#include <cstddef>
#include <system_error>
#include <thread>
#include <utility>
#include <vector>

namespace sope {
namespace internal {

// Workers for `num_chunks` chunks of pixels with up to `num_threads` threads (at least one).
inline size_t NumChunkWorkers(int num_threads, size_t num_chunks) {
  return std::max<size_t>(1, std::min(static_cast<size_t>(num_threads), num_chunks));
}

// The chunks [first, last) of worker `worker` in RunChunksOnWorkers.
inline std::pair<size_t, size_t> WorkerChunks(size_t worker, size_t num_chunks,
                                              size_t num_workers) {
  return {num_chunks * worker / num_workers, num_chunks * (worker + 1) / num_workers};
}

// The decoders' thread loop: chunks 0 … num_chunks − 1 split into contiguous ranges, one per
// worker (each streams its own part of every frame), `decode_chunk(worker, chunk)` for each.
// Worker 0 is the calling thread; when no more threads can be started, the caller decodes
// the remaining shares itself. Allocate what the workers need before calling, so that no
// worker can fail.
template <typename DecodeChunk>
void RunChunksOnWorkers(size_t num_chunks, size_t num_workers, const DecodeChunk& decode_chunk) {
  auto run = [&](size_t worker) {
    const auto [first, last] = WorkerChunks(worker, num_chunks, num_workers);
    for (size_t chunk = first; chunk < last; ++chunk) decode_chunk(worker, chunk);
  };
  std::vector<std::thread> threads;
  size_t started = 1;
  try {
    for (; started < num_workers; ++started) threads.emplace_back(run, started);
  } catch (const std::system_error&) {
    // No more threads: the caller decodes the remaining shares itself.
  }
  for (size_t worker = started; worker < num_workers; ++worker) run(worker);
  run(0);
  for (std::thread& thread : threads) thread.join();
}

}  // namespace internal
}  // namespace sope
