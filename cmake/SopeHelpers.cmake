# sope_add_library(NAME name SRCS ... [DEPS ...] [PRIVATE_DEPS ...])
#   One static library per module folder; the include root is the repository root, so
#   headers are included as "decoder/decoder.h".
function(sope_add_library)
  cmake_parse_arguments(ARG "" "NAME" "SRCS;DEPS;PRIVATE_DEPS" ${ARGN})
  add_library(${ARG_NAME} STATIC ${ARG_SRCS})
  target_include_directories(${ARG_NAME} PUBLIC ${PROJECT_SOURCE_DIR})
  target_link_libraries(${ARG_NAME} PUBLIC ${ARG_DEPS} PRIVATE ${ARG_PRIVATE_DEPS})
endfunction()

# sope_add_test(NAME name SRCS ... [DEPS ...] [LABELS ...])
#   A GoogleTest binary; each TEST becomes one CTest entry (discovered before test time,
#   so the build does not run the binaries).
function(sope_add_test)
  if(NOT SOPE_BUILD_TESTS)
    return()
  endif()
  cmake_parse_arguments(ARG "" "NAME" "SRCS;DEPS;LABELS" ${ARGN})
  add_executable(${ARG_NAME} ${ARG_SRCS})
  target_link_libraries(${ARG_NAME} PRIVATE ${ARG_DEPS} sope_test_support GTest::gtest
                        GTest::gtest_main)
  set(properties TIMEOUT 900)
  if(ARG_LABELS)
    list(APPEND properties LABELS "${ARG_LABELS}")
  endif()
  # Listing the tests runs the program once before ctest starts it: on a loaded or
  # freshly booted machine loading its libraries can take longer than CMake's default 5 s
  # (core_test once timed out there, failing the whole run), so allow a minute.
  gtest_discover_tests(${ARG_NAME} DISCOVERY_MODE PRE_TEST DISCOVERY_TIMEOUT 60
                       PROPERTIES ${properties})
endfunction()

# sope_add_bench(NAME name SRCS ... [DEPS ...])
#   A Google Benchmark program with bench/bench_support.cc (logs on stderr; the reporter
#   --benchmark_format asks for, alone on stdout).
function(sope_add_bench)
  if(NOT SOPE_BUILD_BENCH)
    return()
  endif()
  cmake_parse_arguments(ARG "" "NAME" "SRCS;DEPS" ${ARGN})
  add_executable(${ARG_NAME} ${ARG_SRCS} ${PROJECT_SOURCE_DIR}/bench/bench_support.cc)
  target_link_libraries(${ARG_NAME} PRIVATE ${ARG_DEPS} benchmark::benchmark spdlog::spdlog)
endfunction()
