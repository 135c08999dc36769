#!/usr/bin/env bash
# The project's test command (README: Quick start and Tests; CI runs it through .ci/run).
# Installs the two Python packages one test uses to read dataset shards from Python
# (numpy, safetensors), checks formatting, then runs every test in release mode.
set -euo pipefail
cd "$(dirname "$0")/.."
if ! python3 -c "import numpy, safetensors" 2>/dev/null; then
  python3 -m pip install --quiet --disable-pip-version-check numpy safetensors \
    || python3 -m pip install --quiet --disable-pip-version-check --user numpy safetensors \
    || python3 -m pip install --quiet --disable-pip-version-check --break-system-packages numpy safetensors
fi
python3 -c "import numpy, safetensors; print('python: numpy', numpy.__version__, 'safetensors', safetensors.__version__)"
if cargo fmt --version >/dev/null 2>&1; then cargo fmt --all -- --check; fi
cargo test --workspace --release
