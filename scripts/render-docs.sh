#!/usr/bin/env bash
# Renders the reference images in docs/body/ with the drape program. Rerun after changing
# the body model, the pose library or the renderer, look at the images, commit them.
set -euo pipefail
cd "$(dirname "$0")/.."
cargo build --release --quiet
drape=target/release/drape
out=docs/body
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
mkdir -p "$out"

$drape body -o "$tmp/b.obj" --png "$out/default.png"
$drape body --pose t-pose -o "$tmp/b.obj" --png "$out/t-pose.png"
# Four extreme shapes: the corners of the parameter space, well outside the sampling range.
$drape body --gender 0 --weight 1 --muscle 0.3 -o "$tmp/b.obj" --png "$out/shape-heavy-woman.png"
$drape body --gender 1 --muscle 1 --weight 0.6 -o "$tmp/b.obj" --png "$out/shape-muscular-man.png"
$drape body --gender 1 --weight 0 --muscle 0 --height 0.8 -o "$tmp/b.obj" --png "$out/shape-thin-tall-man.png"
$drape body --gender 0 --age 1 --height 0.2 --proportions 0 -o "$tmp/b.obj" --png "$out/shape-old-short-woman.png"
# Eight poses of the prior (seeds 9 to 16 cover the three families) on the default body.
$drape body gallery --samples 8 --seed 9 --columns 4 --cell-height 300 -o "$out/sampled-poses.png" | tee "$out/sampled-poses.txt"

# The simulator: the garment-like tube on the default body, morphed to two poses of the prior.
mkdir -p docs/sim
for seed in 9 11; do
  $drape sim --garment tube --pose "random:$seed" -o "$tmp/d.obj" --png "docs/sim/tube-random-$seed.png" --report "docs/sim/tube-random-$seed.json"
done

# Strain maps of the 10k T-shirt in random:9 (docs/sim.md): one stretch sweep per substep
# and five, both settling at the morph's 10 substeps with the elastic push-out, as before
# session 16; then five sweeps settling at 20 substeps with the inelastic push-out (the
# default before the strain polish of session 24).
printf 'stretch_iterations = 1\nsettle_substeps = 10\nelastic_pushout = true\n' > "$tmp/one-sweep.toml"
printf 'settle_substeps = 10\nelastic_pushout = true\n' > "$tmp/settle-10.toml"
$drape sim --garment tshirt --pose random:9 --config "$tmp/one-sweep.toml" -o "$tmp/d.obj" --strain-png docs/sim/strain-tshirt-random-9.png
$drape sim --garment tshirt --pose random:9 --config "$tmp/settle-10.toml" -o "$tmp/d.obj" --strain-png docs/sim/strain-tshirt-random-9-five-sweeps.png
printf 'polish_sweeps = 0\n' > "$tmp/no-polish.toml"
$drape sim --garment tshirt --pose random:9 --config "$tmp/no-polish.toml" -o "$tmp/d.obj" --strain-png docs/sim/strain-tshirt-random-9-settle-20.png
# The strain polish (session 24): the 10k sweater in random:10 without it and with it (the default).
$drape sim --garment sweater --pose random:10 --config "$tmp/no-polish.toml" -o "$tmp/d.obj" --strain-png docs/sim/strain-sweater-random-10-no-polish.png
$drape sim --garment sweater --pose random:10 -o "$tmp/d.obj" --strain-png docs/sim/strain-sweater-random-10-polish.png

# Garments: each template on the canonical body, then its DQS warp and its drape on three
# sampled bodies and poses (samples 0 to 2 of `drape garment check`).
mkdir -p docs/garments
for g in tshirt sweater dress jeans; do
  $drape garment gallery "$g" --samples 3 --seed 0 --cell-height 200 -o "docs/garments/$g.png" | tee "docs/garments/$g.txt"
done
