#include "core/allocator.h"

#if defined(__GLIBC__)
#include <malloc.h>
#endif

namespace sope {

void ConfigureAllocatorForFrames() {
#if defined(__GLIBC__)
  // 32 MB is the largest mmap threshold glibc accepts on 64-bit (HEAP_MAX_SIZE / 2); setting
  // it also stops glibc from adjusting the threshold itself.
  constexpr int kMmapThreshold = 32 << 20;
  constexpr int kTrimThreshold = 512 << 20;
  mallopt(M_MMAP_THRESHOLD, kMmapThreshold);
  mallopt(M_TRIM_THRESHOLD, kTrimThreshold);
#endif
}

}  // namespace sope
