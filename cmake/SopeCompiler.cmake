# Compiler set-up for every target: ccache, warnings, -march=native, sanitizers and the
# libFuzzer instrumentation (SOPE_SANITIZE, SOPE_FUZZ in the top-level CMakeLists.txt).

# ccache when installed, unless a launcher was given (-DCMAKE_CXX_COMPILER_LAUNCHER=...).
# CCACHE_BASEDIR: paths under the source tree are hashed relative to it, so a clone at
# another path (CI's checkout, a second worktree) reuses the cache; the sloppiness lets
# ccache cache the files compiled with the tests' precompiled header (SOPE_TEST_PCH).
find_program(CCACHE_PROGRAM ccache)
if(CCACHE_PROGRAM AND NOT CMAKE_CXX_COMPILER_LAUNCHER)
  set(CMAKE_CXX_COMPILER_LAUNCHER
      "${CMAKE_COMMAND};-E;env;CCACHE_BASEDIR=${PROJECT_SOURCE_DIR}"
      "CCACHE_SLOPPINESS=pch_defines,time_macros"
      "${CCACHE_PROGRAM}")
endif()

# The linker: lld, else gold, else the default (GNU ld). Linking the ~30 programs with
# GNU ld was a large part of a fresh build (README "Build time"); SOPE_LINKER=default
# keeps GNU ld.
set(SOPE_LINKER auto CACHE STRING "Linker: auto (lld, else gold), lld, gold or default")
if(NOT SOPE_LINKER STREQUAL "default")
  include(CheckLinkerFlag)
  set(candidates lld gold)
  if(NOT SOPE_LINKER STREQUAL "auto")
    set(candidates ${SOPE_LINKER})
  endif()
  foreach(linker IN LISTS candidates)
    check_linker_flag(CXX "-fuse-ld=${linker}" SOPE_HAVE_LD_${linker})
    if(SOPE_HAVE_LD_${linker})
      add_link_options(-fuse-ld=${linker})
      message(STATUS "sope: linking with ${linker}")
      break()
    elseif(NOT SOPE_LINKER STREQUAL "auto")
      message(FATAL_ERROR "SOPE_LINKER=${SOPE_LINKER}: -fuse-ld=${linker} does not work")
    endif()
  endforeach()
endif()

add_compile_options(-Wall -Wextra -Wno-unused-parameter)
if(SOPE_NATIVE)
  add_compile_options(-march=native)
endif()

# SOPE_WIDE_VECTORS: compile options for the hot loops that GCC vectorises (per source
# file). With AVX-512 GCC prefers 256-bit vectors; these loops run faster in 512-bit ones
# (triangulation.cc, phase_decoder.cc: the figures are in their CMakeLists). Empty when the
# compiler does not know the flag; no effect on CPUs without AVX-512.
include(CheckCXXCompilerFlag)
check_cxx_compiler_flag(-mprefer-vector-width=512 SOPE_HAVE_PREFER_VECTOR_WIDTH)
set(SOPE_WIDE_VECTORS "")
if(SOPE_HAVE_PREFER_VECTOR_WIDTH)
  set(SOPE_WIDE_VECTORS -mprefer-vector-width=512)
endif()

# SOPE_SANITIZE: ON means address,undefined; otherwise the list is -fsanitize='s argument.
set(SOPE_SANITIZERS "")
if(SOPE_SANITIZE)
  if(SOPE_SANITIZE MATCHES "^(ON|on|On|TRUE|true|YES|yes|1)$")
    set(SOPE_SANITIZERS address,undefined)
  else()
    string(REPLACE ";" "," SOPE_SANITIZERS "${SOPE_SANITIZE}")
  endif()
endif()
if(SOPE_FUZZ)
  if(NOT CMAKE_CXX_COMPILER_ID MATCHES "Clang")
    message(FATAL_ERROR "SOPE_FUZZ=ON needs clang with libFuzzer (e.g. "
                        "-DCMAKE_C_COMPILER=clang-14 -DCMAKE_CXX_COMPILER=clang++-14); "
                        "this build uses ${CMAKE_CXX_COMPILER_ID}")
  endif()
  if(SOPE_SANITIZERS STREQUAL "")
    set(SOPE_SANITIZERS address,undefined)  # fuzzing finds memory errors through ASan
  endif()
endif()
if(NOT SOPE_SANITIZERS STREQUAL "")
  string(REPLACE "," ";" sanitizer_list "${SOPE_SANITIZERS}")
  foreach(sanitizer IN LISTS sanitizer_list)
    if(NOT sanitizer MATCHES "^(address|undefined|leak|thread|memory)$")
      message(FATAL_ERROR "SOPE_SANITIZE: unknown sanitizer '${sanitizer}' in "
                          "'${SOPE_SANITIZE}' (address, undefined, leak, thread, memory)")
    endif()
  endforeach()
  if("address" IN_LIST sanitizer_list AND "thread" IN_LIST sanitizer_list)
    message(FATAL_ERROR "SOPE_SANITIZE: address and thread cannot be combined")
  endif()
  message(STATUS "sope: building with -fsanitize=${SOPE_SANITIZERS}")
  # Undefined behaviour stops the program (a test fails) instead of printing and going on;
  # line tables (-g1) give the reports file:line without a full debug build.
  add_compile_options(-fsanitize=${SOPE_SANITIZERS} -fno-sanitize-recover=all
                      -fno-omit-frame-pointer -g1)
  add_link_options(-fsanitize=${SOPE_SANITIZERS})
endif()
if(SOPE_FUZZ)
  # Coverage instrumentation everywhere; only the fuzz targets link libFuzzer's main.
  add_compile_options(-fsanitize=fuzzer-no-link)
endif()

# Every executable of a sanitizer build gets the runtime defaults of
# cmake/sanitizer_options.cc (suppressions for third-party leaks, UBSan stack traces), so
# ctest, a direct run and the CLI tests' `sope` subprocesses all behave alike.
function(sope_add_sanitizer_defaults)
  if(SOPE_SANITIZERS STREQUAL "")
    return()
  endif()
  set(directories "${PROJECT_SOURCE_DIR}")
  set(executables "")
  while(directories)
    list(POP_FRONT directories directory)
    get_property(subdirectories DIRECTORY "${directory}" PROPERTY SUBDIRECTORIES)
    list(APPEND directories ${subdirectories})
    get_property(targets DIRECTORY "${directory}" PROPERTY BUILDSYSTEM_TARGETS)
    foreach(target IN LISTS targets)
      get_target_property(type ${target} TYPE)
      if(type STREQUAL "EXECUTABLE")
        target_sources(${target} PRIVATE "${PROJECT_SOURCE_DIR}/cmake/sanitizer_options.cc")
      endif()
    endforeach()
  endwhile()
endfunction()
