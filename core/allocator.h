// Process-wide allocator settings for programs that handle camera frames.
#pragma once

namespace sope {

// Lets glibc's malloc keep freed memory for reuse instead of handing it back to the kernel
// and faulting fresh zeroed pages in for the next frame: blocks up to 32 MB (every frame,
// float image and OpenCV scratch buffer) come from the heap rather than from mmap, and up to
// 512 MB of free heap is kept before it is trimmed. A capture → decode loop allocates and
// frees the same few megabytes per frame; with glibc's defaults a calibration test spent a
// third of its CPU time in page faults (1.8 M faults; 0.19 M with these settings, the same
// results). The price: a program keeps its peak heap until it exits. Call once, first thing
// in main(); a no-op where the C library is not glibc (and harmless under sanitizers, which
// replace malloc).
void ConfigureAllocatorForFrames();

}  // namespace sope
