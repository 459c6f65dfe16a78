// main() of every GoogleTest binary (instead of gtest_main): the tests run with the
// allocator settings of the `sope` program (core/allocator.h).
#include <gtest/gtest.h>

#include "core/allocator.h"

int main(int argc, char** argv) {
  sope::ConfigureAllocatorForFrames();
  ::testing::InitGoogleTest(&argc, argv);
  return RUN_ALL_TESTS();
}
