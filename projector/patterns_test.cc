// Placeholder until the pattern tests land.
#include <gtest/gtest.h>
