# The two commands of the README:
#   make demo   installs dependencies, builds, and runs sope on the virtual rig
#   make test   installs dependencies, builds, and runs every test
BUILD ?= build
JOBS ?= 2
CMAKE_FLAGS ?= -DCMAKE_BUILD_TYPE=Release

.PHONY: all deps configure build demo test bench clean

all: build

deps:
	scripts/install-deps.sh

configure: deps
	cmake -S . -B $(BUILD) $(CMAKE_FLAGS)

build: configure
	cmake --build $(BUILD) -j$(JOBS)

demo: build
	scripts/demo.sh $(BUILD)/app/sope out/demo

test: build
	cd $(BUILD) && ctest -j$(JOBS) --output-on-failure

# Heavy benchmark programs (not part of `make test` or CI).
bench: build
	scripts/run-benchmarks.sh $(BUILD)

clean:
	rm -rf $(BUILD) out
