# graspd: `make demo` (first run installs everything), `make test`, `make serve`, `make bench`.
VENV := .venv/bin
PY := $(VENV)/python
export PYTHONUNBUFFERED := 1

.PHONY: setup demo serve test lint typecheck docs test-slow bench openapi clean

setup:
	@bash scripts/setup.sh

demo: setup
	$(VENV)/graspd demo --out out/demo

serve: setup
	$(VENV)/graspd serve --host $${GRASPD_HOST:-127.0.0.1} --port $${GRASPD_PORT:-8000}

lint: setup
	$(VENV)/ruff check service client tests bench

typecheck: setup
	$(VENV)/mypy

# The documentation site (mkdocs.yml, docs/): strict, so a broken link or a missing page fails; offline.
docs: setup
	NO_MKDOCS_2_WARNING=1 $(VENV)/mkdocs build --strict -d out/site

test: lint typecheck docs
	$(VENV)/pytest

test-slow: setup
	$(VENV)/pytest -m slow

bench: setup
	$(PY) bench/perf.py

openapi: setup
	PYTHONPATH=service:client $(PY) -m graspd.server.openapi > openapi/openapi.json

clean:
	rm -rf out .pytest_cache .mypy_cache .ruff_cache

.PHONY: image
image:  # the container image (podman or docker; scripts/image.sh prepares podman where no registry is reachable)
	bash scripts/image.sh $${IMAGE:-graspd:latest}
