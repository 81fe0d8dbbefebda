# One-command set-up: `make demo` and `make test` create .venv when missing and install surgsplat
# (editable, native kernels compiled) before running.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.surgsplat-installed
NATIVE_SOURCES := $(wildcard csrc/*.cpp csrc/*.h csrc/*/*.cpp csrc/*/*.h) CMakeLists.txt pyproject.toml

.PHONY: demo test install clean

install: $(STAMP)

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip

$(STAMP): $(BIN)/python $(NATIVE_SOURCES)
	$(BIN)/python -m pip install --quiet "scikit-build-core>=0.10" "nanobind>=2.0" "torch==2.13.0"
	$(BIN)/python -m pip install --quiet --no-build-isolation -e ".[test,report,viewer,mesh,batch,sim]"
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/surgsplat demo

test: $(STAMP)
	$(BIN)/python -m pytest -q

clean:
	rm -rf build $(VENV)
