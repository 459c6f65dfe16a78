# The two commands of the README:
#   make demo   installs dependencies, builds, and runs sope on the virtual rig
#   make test   installs dependencies, builds, and runs every test
# Before each stop (not in CI, README "Tests"):
#   make sanitize   the whole suite built with ASan + UBSan, in build-asan/
#   make fuzz       every parser's libFuzzer target for FUZZ_SECONDS each, in build-fuzz/
BUILD ?= build
JOBS ?= 2
CMAKE_FLAGS ?= -DCMAKE_BUILD_TYPE=Release
SANITIZE_BUILD ?= build-asan
SANITIZERS ?= address,undefined
FUZZ_BUILD ?= build-fuzz
FUZZ_SECONDS ?= 60
FUZZ_JOBS ?= 1
FUZZ_CC ?= clang-14
FUZZ_CXX ?= clang++-14

.PHONY: all deps configure build demo test bench sanitize fuzz clean

all: build

deps:
	scripts/install-deps.sh

# A new build tree uses Ninja when it is installed (install-deps installs it; chosen after
# deps ran, so a fresh machine gets it too): it keeps both cores compiling where make's
# recursive target scheduling idles one (README "Build and test time"). GENERATOR=... picks
# another; an existing tree keeps the generator it was made with.
GENERATOR ?=

configure: deps
	@if [ -f $(BUILD)/CMakeCache.txt ]; then \
	  set -x; cmake -S . -B $(BUILD) $(CMAKE_FLAGS); \
	else \
	  generator="$(GENERATOR)"; \
	  if [ -z "$$generator" ]; then \
	    if command -v ninja >/dev/null; then generator=Ninja; else generator="Unix Makefiles"; fi; \
	  fi; \
	  set -x; cmake -S . -B $(BUILD) -G "$$generator" $(CMAKE_FLAGS); \
	fi

build: configure
	cmake --build $(BUILD) -j$(JOBS)

demo: build
	scripts/demo.sh $(BUILD)/app/sope out/demo

test: build
	cd $(BUILD) && ctest -j$(JOBS) --output-on-failure

# Heavy benchmark programs (not part of `make test` or CI).
bench: build
	cmake --build $(BUILD) -j$(JOBS) --target sope_benches
	scripts/run-benchmarks.sh $(BUILD)

# Every test under AddressSanitizer + UndefinedBehaviorSanitizer (no benchmarks).
sanitize: deps
	cmake -S . -B $(SANITIZE_BUILD) $(CMAKE_FLAGS) -DSOPE_SANITIZE=$(SANITIZERS) \
	  -DSOPE_BUILD_BENCH=OFF
	cmake --build $(SANITIZE_BUILD) -j$(JOBS)
	cd $(SANITIZE_BUILD) && ctest -j$(JOBS) --output-on-failure

# libFuzzer targets (clang, ASan + UBSan); the regular build's `sope` makes the database seed.
fuzz: build
	@command -v $(FUZZ_CXX) >/dev/null || { echo "make fuzz: needs $(FUZZ_CXX) and" \
	  "libFuzzer (Debian: apt-get install clang-14 libfuzzer-14-dev)" >&2; exit 1; }
	cmake -S . -B $(FUZZ_BUILD) $(CMAKE_FLAGS) -DCMAKE_C_COMPILER=$(FUZZ_CC) \
	  -DCMAKE_CXX_COMPILER=$(FUZZ_CXX) -DSOPE_FUZZ=ON -DSOPE_BUILD_TESTS=OFF -DSOPE_BUILD_BENCH=OFF
	cmake --build $(FUZZ_BUILD) -j$(JOBS) --target sope_fuzzers
	FUZZ_SECONDS=$(FUZZ_SECONDS) FUZZ_JOBS=$(FUZZ_JOBS) SOPE=$(BUILD)/app/sope \
	  fuzz/run-fuzzers.sh $(FUZZ_BUILD)

clean:
	rm -rf $(BUILD) $(SANITIZE_BUILD) $(FUZZ_BUILD) out
