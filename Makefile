# Everything a fresh machine needs: `make demo` and `make test` set up .venv themselves.
PY ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
TORCH_VERSION ?= 2.13.0
DEMO_DIR ?= demo_out

.PHONY: setup browser demo test lint bench clean

setup: $(VENV)/.installed

$(VENV)/.installed: pyproject.toml constraints.txt
	$(PY) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	# CPU wheel pinned; if a CUDA build of torch is already in the venv, pip keeps it (same version range).
	$(BIN)/python -c "import torch" 2>/dev/null || $(BIN)/pip install -q torch==$(TORCH_VERSION)
	# the plain OpenCV wheels share the cv2 folder with the contrib build the package needs: removed first
	$(BIN)/pip uninstall -y -q opencv-python-headless opencv-python 2>/dev/null || true
	# the numerical libraries at the versions the results were measured with (constraints.txt)
	$(BIN)/pip install -q -c constraints.txt -e ".[dev]"
	# the CPU kernels compiled now (numba caches them beside the package) rather than in the first run
	$(BIN)/python -m trackingworld.optim.warmup
	touch $@

demo: setup
	$(BIN)/python -m trackingworld.demo --out $(DEMO_DIR)

# Chromium and ChromeDriver for the viewer's browser test, from Debian's packages where this machine allows it
# (root or password-less sudo); without them that one test skips.
browser:
	@command -v chromium >/dev/null && command -v chromedriver >/dev/null || { \
	  SUDO=$$( [ "$$(id -u)" = 0 ] && echo "" || echo "sudo -n" ); \
	  command -v apt-get >/dev/null && \
	  ( $$SUDO apt-get install -y -q chromium chromium-driver >/dev/null 2>&1 || \
	    ( $$SUDO apt-get update -q >/dev/null 2>&1 && $$SUDO apt-get install -y -q chromium chromium-driver >/dev/null 2>&1 ) ) \
	  || echo "note: could not install chromium + chromium-driver; the browser test will skip"; }

test: setup browser
	$(BIN)/python -m pytest

lint: setup
	$(BIN)/ruff check src tests benchmarks

clean:
	rm -rf $(VENV) $(DEMO_DIR) .pytest_cache
