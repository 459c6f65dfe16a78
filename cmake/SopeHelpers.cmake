# sope_add_library(NAME name SRCS ... [DEPS ...] [PRIVATE_DEPS ...])
#   One static library per module folder; the include root is the repository root, so
#   headers are included as "decoder/decoder.h".
function(sope_add_library)
  cmake_parse_arguments(ARG "" "NAME" "SRCS;DEPS;PRIVATE_DEPS" ${ARGN})
  add_library(${ARG_NAME} STATIC ${ARG_SRCS})
  target_include_directories(${ARG_NAME} PUBLIC ${PROJECT_SOURCE_DIR})
  target_link_libraries(${ARG_NAME} PUBLIC ${ARG_DEPS} PRIVATE ${ARG_PRIVATE_DEPS})
endfunction()

# sope_add_test(NAME name SRCS ... [DEPS ...] [LABELS ...] [SANITIZER_ENV ...] [PER_CASE])
#   A GoogleTest binary: one CTest entry named after it that runs all its tests in one
#   process, so a suite's shared set-up (a database built, a scene rendered) is paid once,
#   not once per test. PER_CASE (long, independent tests: calibrate_e2e_test) or
#   -DSOPE_CTEST_PER_CASE=ON (every binary, e.g. to `ctest -R` one test) makes each TEST
#   its own entry instead, discovered before test time so the build does not run them.
#   SANITIZER_ENV: VAR=value settings for the test's run in a sanitizer build only.
set(SOPE_TEST_OPTIMIZATION -O1 CACHE STRING
    "Optimisation flag of the test files (empty: the build type's)")
option(SOPE_CTEST_PER_CASE "One CTest entry per GoogleTest case (default: per binary)" OFF)
# Sanitizer builds run 3-10x slower (calibrate_e2e_test's cases ~9 min each under ASan on an
# idle 2-core machine), so their timeouts are scaled; the limits catch hangs, not slowness.
# SOPE_SANITIZERS (SopeCompiler.cmake) is the list in effect: SOPE_SANITIZE's, or ASan +
# UBSan in a fuzzing build, whose tests then get the same timeouts and environments.
if(NOT SOPE_SANITIZERS STREQUAL "")
  set(SOPE_TEST_TIMEOUT_SCALE 3)
else()
  set(SOPE_TEST_TIMEOUT_SCALE 1)
endif()
# The test files' flags (see sope_add_test).
function(sope_test_compile_options target)
  if(SOPE_TEST_OPTIMIZATION)
    # (GCC 12 at -O1 reports Eigen's AVX-512 packets, _mm512_undefined_pd in
    # avx512fintrin.h, as uninitialised: a false positive that floods the log.)
    target_compile_options(${target} PRIVATE ${SOPE_TEST_OPTIMIZATION}
                           $<$<CXX_COMPILER_ID:GNU>:-Wno-uninitialized>
                           $<$<CXX_COMPILER_ID:GNU>:-Wno-maybe-uninitialized>)
  endif()
endfunction()

# One precompiled header for every test binary: GoogleTest, Eigen, OpenCV, nlohmann-json
# and fmt, which most test files include and which were most of their compile time (a
# test file: ~7 of its ~9 s parsing headers). Built once with the test files' flags and
# reused (REUSE_FROM) by every test target; a target whose flags or macros differ (e.g.
# PCL_NO_PRECOMPILE) has GCC fall back to the headers themselves, as before.
option(SOPE_TEST_PCH "Compile the tests with one shared precompiled header" ON)
function(sope_test_pch_target out)
  if(NOT TARGET sope_test_pch)
    add_library(sope_test_pch STATIC ${PROJECT_SOURCE_DIR}/tests/test_pch.cc)
    target_link_libraries(sope_test_pch PRIVATE sope_core GTest::gtest
                          nlohmann_json::nlohmann_json fmt::fmt)
    sope_test_compile_options(sope_test_pch)
    target_precompile_headers(sope_test_pch PRIVATE
      <algorithm> <cmath> <cstdint> <cstdio> <filesystem> <fstream> <functional> <limits>
      <map> <memory> <optional> <random> <sstream> <string> <vector>
      <gtest/gtest.h> <Eigen/Core> <Eigen/Geometry> <opencv2/core.hpp>
      <opencv2/imgproc.hpp> <nlohmann/json.hpp> <fmt/format.h>)
  endif()
  set(${out} sope_test_pch PARENT_SCOPE)
endfunction()

function(sope_add_test)
  if(NOT SOPE_BUILD_TESTS)
    return()
  endif()
  cmake_parse_arguments(ARG "PER_CASE" "NAME" "SRCS;DEPS;LABELS;SANITIZER_ENV" ${ARGN})
  add_executable(${ARG_NAME} ${ARG_SRCS})
  target_link_libraries(${ARG_NAME} PRIVATE ${ARG_DEPS} sope_test_support GTest::gtest
                        sope_test_main)
  if(SOPE_TEST_PCH)
    sope_test_pch_target(pch)
    target_precompile_headers(${ARG_NAME} REUSE_FROM ${pch})
  endif()
  # Test files are mostly GoogleTest macros and set-up; the work they time is in the
  # libraries, which keep the build type's optimisation. -O1 compiles them in ~2/3 of
  # -O3's time (README "Build and test time"); a test binary's several files compile as
  # one (unity build), so their common headers are parsed once.
  sope_test_compile_options(${ARG_NAME})
  list(LENGTH ARG_SRCS source_count)
  if(source_count GREATER 1)
    set_target_properties(${ARG_NAME} PROPERTIES UNITY_BUILD ON UNITY_BUILD_BATCH_SIZE 0)
  endif()
  if(ARG_PER_CASE OR SOPE_CTEST_PER_CASE)
    # COST: with no timings from an earlier run, ctest starts the costliest first, so these
    # long cases do not trail at the end of a parallel run.
    math(EXPR timeout "900 * ${SOPE_TEST_TIMEOUT_SCALE}")
    set(properties TIMEOUT ${timeout})
    if(ARG_PER_CASE)
      list(APPEND properties COST 1000)
    endif()
    if(ARG_LABELS)
      list(APPEND properties LABELS "${ARG_LABELS}")
    endif()
    if(NOT SOPE_SANITIZERS STREQUAL "" AND ARG_SANITIZER_ENV)
      list(APPEND properties ENVIRONMENT "${ARG_SANITIZER_ENV}")
    endif()
    # Listing the tests runs the program once before ctest starts it: on a loaded or
    # freshly booted machine loading its libraries can take longer than CMake's default
    # 5 s (core_test once timed out there, failing the whole run), so allow a minute.
    gtest_discover_tests(${ARG_NAME} DISCOVERY_MODE PRE_TEST DISCOVERY_TIMEOUT 60
                         PROPERTIES ${properties})
  else()
    # The whole binary: its slowest (pipeline_test, ~90 s; ~4 min under ASan) well inside.
    add_test(NAME ${ARG_NAME} COMMAND ${ARG_NAME})
    math(EXPR timeout "1800 * ${SOPE_TEST_TIMEOUT_SCALE}")
    set_tests_properties(${ARG_NAME} PROPERTIES TIMEOUT ${timeout})
    if(ARG_LABELS)
      set_tests_properties(${ARG_NAME} PROPERTIES LABELS "${ARG_LABELS}")
    endif()
    if(NOT SOPE_SANITIZERS STREQUAL "" AND ARG_SANITIZER_ENV)
      set_tests_properties(${ARG_NAME} PROPERTIES ENVIRONMENT "${ARG_SANITIZER_ENV}")
    endif()
  endif()
endfunction()

# sope_add_bench(NAME name SRCS ... [DEPS ...])
#   A Google Benchmark program with bench/bench_support.cc (logs on stderr; the reporter
#   --benchmark_format asks for, alone on stdout), built only through the sope_benches
#   target (`make bench`), not by the default build.
function(sope_add_bench)
  if(NOT SOPE_BUILD_BENCH)
    return()
  endif()
  cmake_parse_arguments(ARG "" "NAME" "SRCS;DEPS" ${ARGN})
  # Not part of the default build (`make test`, `make demo`): `make bench` builds them
  # through the sope_benches target (README "Build and test time").
  add_executable(${ARG_NAME} EXCLUDE_FROM_ALL ${ARG_SRCS}
                 ${PROJECT_SOURCE_DIR}/bench/bench_support.cc)
  target_link_libraries(${ARG_NAME} PRIVATE ${ARG_DEPS} benchmark::benchmark spdlog::spdlog)
  if(NOT TARGET sope_benches)
    add_custom_target(sope_benches)
  endif()
  add_dependencies(sope_benches ${ARG_NAME})
endfunction()
