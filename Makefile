# voxlat: two set-up commands on a fresh Debian machine.
#   make run   installs missing Debian packages, builds Release, runs the default recipe
#   make test  installs, builds, runs every test
#   make sanitize  the whole test suite under ASan + UBSan (CI runs it after make test)
#   make fuzz  builds the libFuzzer harnesses with clang and runs each for FUZZ_SECONDS (default 60)
#   make bench runs the benchmarks in bench/ (installs their reference tools too)
#   make install PREFIX=DIR  installs voxlat, its data and docs under DIR (default /usr/local)

BUILD ?= build
JOBS ?= $(shell nproc)
RECIPE ?= data/recipes/gyroid.yaml
OUT ?= out

DEB_PACKAGES := cmake ninja-build g++ pkg-config libopenvdb-dev libboost-iostreams-dev libtbb-dev libopenmesh-dev \
	libopenexr-dev libyaml-cpp-dev libcli11-dev nlohmann-json3-dev libgtest-dev libpng-dev libzip-dev libsleef-dev \
	lib3mf-dev libcgal-dev nettle-dev clang-format pybind11-dev python3-dev python3-numpy python3-jsonschema python3-yaml python3-scipy \
	libjs-three chromium python3-pip python3-venv python3-setuptools python3-wheel
BENCH_PACKAGES := python3 python3-numpy python3-openvdb python3-scipy python3-skimage prusa-slicer time
SUDO := $(shell [ "$$(id -u)" = 0 ] || echo sudo)
CCACHE := $(shell command -v ccache 2>/dev/null)

.PHONY: all deps bench-deps build run test sanitize fuzz bench format docs-keys clean install check-pip-scratch

all: build

# Installs only what is missing (apt-get update first: a fresh machine has no package lists).
define install_missing
	@missing=$$(for p in $(1); do dpkg-query -W -f='$${Status}\n' $$p 2>/dev/null | grep -q 'ok installed' || echo $$p; done); \
	if [ -n "$$missing" ]; then \
	  echo "installing Debian packages:" $$missing; \
	  $(SUDO) apt-get update -qq && DEBIAN_FRONTEND=noninteractive $(SUDO) apt-get install -y -qq --no-install-recommends $$missing; \
	fi
endef

deps:
	$(call install_missing,$(DEB_PACKAGES))

bench-deps:
	$(call install_missing,$(BENCH_PACKAGES))

build: deps
	cmake -S . -B $(BUILD) -G Ninja -DCMAKE_BUILD_TYPE=Release $(if $(CCACHE),-DCMAKE_CXX_COMPILER_LAUNCHER=ccache)
	cmake --build $(BUILD) -j $(JOBS)

run: build
	$(BUILD)/voxlat run $(RECIPE) --out $(OUT)
	@echo "outputs are in $(abspath $(OUT)): the mesh, a preview picture (NAME.stl.preview.png), report.json and report.html"

PREFIX ?= /usr/local
install: build
	cmake --install $(BUILD) --prefix $(PREFIX)

test: build
	cd $(BUILD) && ctest --output-on-failure -j $(JOBS)

# `pip install .` as a new user runs it: a copy of the checkout with no build folder, no
# VOXLAT_BUILD_DIR (setup.py compiles the copy's build/), then docs/python.md's first example in
# the venv. Minutes (ccache reuses this checkout's objects), so not part of `make test`.
check-pip-scratch: build
	/usr/bin/python3 tests/scripts/check_pip_install.py --from-scratch $(BUILD) .

# The whole test suite under AddressSanitizer + UndefinedBehaviorSanitizer (its own build folder).
# The Python module is loaded by /usr/bin/python3, which is not built with ASan: its tests run with
# the ASan runtime preloaded.
SANITIZE_BUILD ?= build-sanitize
sanitize: deps
	cmake -S . -B $(SANITIZE_BUILD) -G Ninja -DCMAKE_BUILD_TYPE=Debug -DVOXLAT_SANITIZE=ON $(if $(CCACHE),-DCMAKE_CXX_COMPILER_LAUNCHER=ccache)
	cmake --build $(SANITIZE_BUILD) -j $(JOBS)
	cd $(SANITIZE_BUILD) && ASAN_OPTIONS=detect_leaks=1:strict_string_checks=1 \
	  LSAN_OPTIONS=suppressions=$(CURDIR)/tests/lsan.supp UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1 \
	  ctest --output-on-failure -j $(JOBS)

# libFuzzer harnesses (tests/fuzz/), clang with ASan + UBSan, seeded from data/.
FUZZ_BUILD ?= build-fuzz
FUZZ_SECONDS ?= 60
fuzz: deps
	$(call install_missing,clang)
	cmake -S . -B $(FUZZ_BUILD) -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo -DCMAKE_CXX_COMPILER=clang++ -DVOXLAT_FUZZ=ON \
	  $(if $(CCACHE),-DCMAKE_CXX_COMPILER_LAUNCHER=ccache)
	cmake --build $(FUZZ_BUILD) -j $(JOBS) --target fuzz_recipe fuzz_equation fuzz_mesh fuzz_wireframe fuzz_values fuzz_profile fuzz_properties
	FUZZ_SECONDS=$(FUZZ_SECONDS) tests/fuzz/run_fuzz.sh $(CURDIR) $(FUZZ_BUILD)

bench: build bench-deps
	/usr/bin/python3 bench/run.py --voxlat $(BUILD)/voxlat

format:
	clang-format -i $$(git ls-files '*.cpp' '*.h')

# The key reference at the end of docs/recipes.md, from the node-type table.
docs-keys: build
	/usr/bin/python3 tests/scripts/update_key_reference.py $(BUILD)/voxlat .

clean:
	rm -rf $(BUILD) $(OUT)
