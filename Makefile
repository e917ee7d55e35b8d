# VoxNeRO: two commands from a fresh clone to a result.
#   make demo   -> set up .venv (system libs, torch, package) and run the pipeline on an analytic scene
#   make test   -> set up .venv and run the default test suite (< 10 min on 2 cores)
PY      ?= python3
VENV    ?= .venv
VPY     := $(VENV)/bin/python
TORCH   ?= torch==2.13.0
STAMP   := $(VENV)/.voxnero-installed
GLTF_VALIDATOR ?= gltf-validator@2.0.0-dev.3.10
DEMO_OUT ?= runs/demo
CORPUS  ?= cache/corpus

.PHONY: setup sysdeps demo test test-all lint clean corpus

setup: $(STAMP)

# System libraries: Open3D needs libusb; headless rendering uses Mesa's software Vulkan.
sysdeps:
	@bash tools/install_sysdeps.sh

$(STAMP): setup.cfg pyproject.toml tools/install_sysdeps.sh Makefile
	@$(MAKE) --no-print-directory sysdeps
	@test -x $(VPY) || $(PY) -m venv $(VENV)
	@# torch first and explicitly: a bare 'torch' requirement would pull a multi-GB CUDA build.
	@$(VPY) -c "import torch" 2>/dev/null || $(VPY) -m pip install -q $(TORCH)
	$(VPY) -m pip install -q -e ".[test]"
	@# The Khronos glTF validator (npm) checks exported model.glb files in the tests.
	@if command -v npm >/dev/null 2>&1; then \
	  npm install --silent --no-audit --no-fund --prefix .node $(GLTF_VALIDATOR); \
	else echo "npm not found: the glTF validator test will be skipped"; fi
	@touch $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/voxnero demo --out $(DEMO_OUT)

# The development corpus of real shapes (tools/corpus): Mitsuba 3 + pybullet's meshes, a
# tools-only extra; libllvm19 for Mitsuba's JIT variant. Cached and resumable (gitignored).
corpus: $(STAMP)
	@bash tools/install_sysdeps.sh libllvm19
	$(VPY) -m pip install -q -e ".[scenes]"
	$(VPY) -m tools.corpus.build --out $(CORPUS)

test: $(STAMP)
	$(VPY) -m pytest -m "not slow" tests

test-all: $(STAMP)
	$(VPY) -m pytest tests

lint: $(STAMP)
	$(VENV)/bin/ruff check voxnero tests tools

clean:
	rm -rf $(VENV) .node runs .pytest_cache
