"""Read a drape dataset (made by `drape gen`) with numpy.

Needs `pip install numpy safetensors`. As a library:

    from drape_dataset import open_dataset, samples
    ds = open_dataset("data/tiny")          # manifest + static arrays
    for s in samples(ds, "train"):         # one shard in memory at a time
        body, M, G = s["body"], s["warped"], s["draped"]   # float32 [Nb,3], [N,3], [N,3]
        faces = ds["static"]["garment_triangles"]          # uint32 [F,3]

As a program, `python3 drape_dataset.py DIR [SPLIT]` prints one JSON line per shard of the
split: its file, ids, tensor shapes and float64 sums of each tensor (the tests compare
these with what the Rust reader sees).
"""

import hashlib
import json
import os
import sys

from safetensors.numpy import load_file

SHARD_TENSORS = ("id", "body", "warped", "draped", "shape", "pose", "root")


def open_dataset(path):
    """The manifest and the static arrays (template, faces, canonical body)."""
    with open(os.path.join(path, "manifest.json")) as f:
        manifest = json.load(f)
    static = load_file(os.path.join(path, "static.safetensors"))
    return {"path": path, "manifest": manifest, "static": static}


def read_shard(ds, shard):
    """All tensors of one shard (a manifest entry), after checking its sha256."""
    file = os.path.join(ds["path"], shard["file"])
    with open(file, "rb") as f:
        digest = hashlib.sha256(f.read()).hexdigest()
    if digest != shard["sha256"]:
        raise ValueError(f"{file}: sha256 differs from the manifest (truncated or altered)")
    return load_file(file)


def samples(ds, split):
    """Yields dicts of one sample's arrays, shard by shard."""
    for shard in ds["manifest"]["shards"]:
        if shard["split"] != split:
            continue
        t = read_shard(ds, shard)
        for k in range(t["id"].shape[0]):
            yield {name: t[name][k] for name in SHARD_TENSORS}


def main():
    path = sys.argv[1]
    split = sys.argv[2] if len(sys.argv) > 2 else "train"
    ds = open_dataset(path)
    for shard in ds["manifest"]["shards"]:
        if shard["split"] != split:
            continue
        t = read_shard(ds, shard)
        print(json.dumps({
            "file": shard["file"],
            "ids": [int(i) for i in t["id"]],
            "shapes": {k: list(t[k].shape) for k in SHARD_TENSORS},
            "sums": {k: float(t[k].astype("float64").sum()) for k in SHARD_TENSORS if k != "id"},
        }))


if __name__ == "__main__":
    main()
