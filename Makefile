# One-command set-up: `make demo` and `make test` create .venv when missing and install surgsplat
# (editable, native kernels compiled) before running.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.surgsplat-installed
NATIVE_SOURCES := $(wildcard csrc/*.cpp csrc/*.h csrc/*/*.cpp csrc/*/*.h surgsplat/methods/*/csrc/*) \
                  CMakeLists.txt pyproject.toml

.PHONY: demo test test-fast docs install clean aarch64-sysroot x86-64-v4-guest

install: $(STAMP)

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip

$(STAMP): $(BIN)/python $(NATIVE_SOURCES)
	$(BIN)/python -m pip install --quiet "scikit-build-core>=0.10" "nanobind>=2.0" "torch==2.13.0"
	$(BIN)/python -m pip install --quiet --no-build-isolation -e ".[test,report,viewer,mesh,batch,sim,onnx,sfm,docs]"
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/surgsplat demo

# One worker per core (pytest-xdist); the tests of one module stay on one worker, which builds
# the module's fixtures (trained runs) once.
test: $(STAMP)
	$(BIN)/python -m pytest -q -n auto --dist loadscope --durations=20

# Development tier: everything but the tests marked slow (end-to-end runs, faults injected into
# processes of their own, real browsers, ISA variants this CPU only runs under emulation).
test-fast: $(STAMP)
	$(BIN)/python -m pytest -q -n auto --dist loadscope -m "not slow"

# The documentation site (mkdocs.yml, pages under docs/) into build/site, warnings as errors,
# after checking that the pages' generated parts are current: the command references (from the
# CLI) and the benchmark tables (from benchmarks/results/).
docs: $(STAMP)
	$(BIN)/python docs/gen_commands.py --check
	$(BIN)/python benchmarks/readme_tables.py --check
	$(BIN)/mkdocs build --strict

# Debian's arm64 Python 3.11 and NumPy, unpacked (not installed) for tests/render/test_neon_replay.py,
# which runs the cross-compiled NEON kernels under qemu-aarch64 on an x86-64 host (needs root).
AARCH64_SYSROOT := build/aarch64-sysroot
AARCH64_PACKAGES := python3.11-minimal libpython3.11-minimal libpython3.11-stdlib libpython3.11-dev \
	python3-numpy libc6 libgcc-s1 libstdc++6 libgomp1 zlib1g libexpat1 libffi8 libblas3 \
	liblapack3 libgfortran5
aarch64-sysroot:
	dpkg --add-architecture arm64 && apt-get update -qq
	rm -rf $(AARCH64_SYSROOT).partial && mkdir -p $(AARCH64_SYSROOT).partial/debs
	cd $(AARCH64_SYSROOT).partial/debs && apt-get download -qq $(AARCH64_PACKAGES:%=%:arm64)
	for deb in $(AARCH64_SYSROOT).partial/debs/*.deb; do dpkg -x $$deb $(AARCH64_SYSROOT).partial; done
	rm -rf $(AARCH64_SYSROOT).partial/debs $(AARCH64_SYSROOT)
	mv $(AARCH64_SYSROOT).partial $(AARCH64_SYSROOT)

# Debian's x86-64 kernel, for tests/render/test_simd_primitives.py, which boots it in Bochs'
# Skylake-X model to run the AVX-512 check on a CPU without AVX-512.
X86_64_V4_GUEST := build/x86-64-v4-guest
x86-64-v4-guest:
	rm -rf $(X86_64_V4_GUEST).partial && mkdir -p $(X86_64_V4_GUEST).partial
	cd $(X86_64_V4_GUEST).partial && apt-get download -qq \
		$$(apt-cache depends linux-image-amd64 | awk '/Depends: linux-image-/ {print $$2; exit}')
	dpkg --fsys-tarfile $(X86_64_V4_GUEST).partial/linux-image-*.deb \
		| tar -xO --wildcards './boot/vmlinuz-*' > $(X86_64_V4_GUEST).partial/vmlinuz
	rm -f $(X86_64_V4_GUEST).partial/*.deb && rm -rf $(X86_64_V4_GUEST)
	mv $(X86_64_V4_GUEST).partial $(X86_64_V4_GUEST)

clean:
	rm -rf build $(VENV)
