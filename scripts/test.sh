#!/usr/bin/env bash
# The project's test command (README: Quick start and Tests; CI runs it through .ci/run).
# Installs the Python packages two tests use (numpy and safetensors read dataset shards,
# OpenEXR reads an error image of `drape eval`), checks formatting and clippy's lints
# (where the toolchain has rustfmt and clippy), then runs every test in release mode.
set -euo pipefail
cd "$(dirname "$0")/.."
if ! python3 -c "import numpy, safetensors, OpenEXR" 2>/dev/null; then
  python3 -m pip install --quiet --disable-pip-version-check numpy safetensors OpenEXR \
    || python3 -m pip install --quiet --disable-pip-version-check --user numpy safetensors OpenEXR \
    || python3 -m pip install --quiet --disable-pip-version-check --break-system-packages numpy safetensors OpenEXR
fi
python3 -c "import numpy, safetensors, OpenEXR; print('python: numpy', numpy.__version__, 'safetensors', safetensors.__version__, 'OpenEXR', OpenEXR.__version__)"
if cargo fmt --version >/dev/null 2>&1; then cargo fmt --all -- --check; fi
if cargo clippy --version >/dev/null 2>&1; then
  cargo clippy --workspace --all-targets --release --quiet -- -D warnings
fi
cargo test --workspace --release --no-fail-fast
