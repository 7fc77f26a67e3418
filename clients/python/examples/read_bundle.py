#!/usr/bin/env python3
"""Loads a softarm model bundle (or learner checkpoint) folder with ``safetensors`` + numpy and
prints its tensors' names, shapes and dtypes.

    python3 read_bundle.py FOLDER [--json] [--no-verify]

A bundle (``models/model/src/bundle.rs``) is ``<stem>.toml`` (metadata) plus the tensors file it
names, ``<stem>-<fnv64>.safetensors``; the TOML's ``[tensors]`` section gives the file, its size
and its FNV-1a 64 hash, which this script checks (``--no-verify`` skips the hash). Stems:
``model`` (``model.toml``, ``kind = "softarm-model"``, written by ``softarm train``; the config's
model folder) and ``learner`` (``learner.toml``, ``kind = "softarm-learner"``, the learner's
checkpoint in the state folder). A folder without either TOML has its ``*.safetensors`` files
read as they are. All tensors are little-endian, row-major (numpy's order).

Model tensors (format 2; K = ``basis_functions``, J = ``primitives`` from ``model.toml``):

- ``promp.actuation.{j}.mean`` F64 [6K], ``promp.actuation.{j}.cov`` F64 [6K, 6K]: the ProMP of
  demonstration class j over the 6 actuators (weights DoF-major: K per actuator), j < J.
- ``promp.task.{j}.mean`` F64 [3K], ``promp.task.{j}.cov`` F64 [3K, 3K]: the same class's ProMP
  of the end-effector position (x, y, z).
- ``forward.centres`` F64 [C, 6]: the RBF forward model's centres in actuation space.
- ``forward.weights`` F64 [C + 7, 3]: its output weights: C Gaussian features (width
  ``forward_sigma``), then a bias and the 6 actuations (linear part).
- ``kinematics.weights`` F64 [terms, 3]: the polynomial kinematics (degree
  ``kinematics_degree``) whose Jacobian steers the online corrections.
- ``actor.keys`` U64 [N], ``actor.weights`` F64 [N, 6]: the pre-trained CACLA actor, weights at
  the occupied lattice cells (keys) of a sparse lattice.
- ``critic.keys`` U64 [M], ``critic.weights`` F64 [M]: the critic, likewise.
- ``memory`` F64 [P, 9]: per conditioning point, ``present, visits, target xyz, position xyz,
  error`` (a row of zeros where nothing is remembered).

A learner checkpoint holds only ``actor.*``, ``critic.*`` and ``memory``.

Needs ``pip install safetensors numpy`` (not iceoryx2).
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from pathlib import Path

import numpy as np
from safetensors.numpy import load_file

try:
    import tomllib  # Python 3.11+
except ImportError:  # pragma: no cover
    tomllib = None

STEMS = ("model", "learner")


def fnv64(data: bytes) -> str:
    """FNV-1a 64 of ``data``, hex (as ``bundle::fnv64``)."""
    h = 0xCBF29CE484222325
    for b in data:
        h ^= b
        h = (h * 0x100000001B3) & 0xFFFFFFFFFFFFFFFF
    return f"{h:016x}"


def read_meta(path: Path) -> dict:
    text = path.read_text()
    if tomllib is not None:
        return tomllib.loads(text)
    # Python < 3.11: only the [tensors] reference is needed.
    section = text.split("[tensors]", 1)[-1]
    ref = dict(re.findall(r'^(\w+)\s*=\s*"?([^"\n]*)"?', section, re.M))
    return {"tensors": {"file": ref["file"], "bytes": int(ref["bytes"]), "fnv64": ref["fnv64"]}}


def bundles(folder: Path, verify: bool) -> list[dict]:
    """Each bundle in ``folder``: its metadata file, tensors file and tensors."""
    found = []
    for stem in STEMS:
        toml = folder / f"{stem}.toml"
        if not toml.exists():
            continue
        meta = read_meta(toml)
        ref = meta.get("tensors")
        if not ref or "/" in ref["file"] or ".." in ref["file"]:
            raise SystemExit(f"{toml}: no valid [tensors] section")
        path = folder / ref["file"]
        data = path.read_bytes()
        if len(data) != ref["bytes"]:
            raise SystemExit(f"{path}: {len(data)} bytes, {toml.name} says {ref['bytes']}")
        if verify and fnv64(data) != ref["fnv64"]:
            raise SystemExit(f"{path}: content hash differs from {toml.name}'s {ref['fnv64']}")
        meta.pop("tensors")
        found.append({"meta_file": toml, "file": path, "meta": meta, "tensors": load_file(path)})
    if not found:
        for path in sorted(folder.glob("*.safetensors")):
            found.append({"meta_file": None, "file": path, "meta": {}, "tensors": load_file(path)})
    return found


def describe(t: np.ndarray) -> dict:
    d = {"shape": list(t.shape), "dtype": str(t.dtype)}
    if t.size and np.issubdtype(t.dtype, np.floating):
        d["min"] = float(t.min())
        d["max"] = float(t.max())
    return d


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("folder", type=Path, help="a model folder (model.toml) or state folder")
    ap.add_argument("--json", action="store_true", help="one JSON object")
    ap.add_argument("--no-verify", action="store_true", help="skip the FNV-1a hash check")
    args = ap.parse_args()
    if not args.folder.is_dir():
        print(f"{args.folder} is not a folder", file=sys.stderr)
        return 2
    found = bundles(args.folder, not args.no_verify)
    if not found:
        print(f"no bundle or .safetensors file in {args.folder}", file=sys.stderr)
        return 1
    if args.json:
        out = {
            b["file"].name: {
                "meta": {k: v for k, v in b["meta"].items() if not isinstance(v, dict)},
                "tensors": {n: describe(t) for n, t in sorted(b["tensors"].items())},
            }
            for b in found
        }
        print(json.dumps(out))
        return 0
    for b in found:
        meta = b["meta"]
        head = f"{b['file'].name}"
        if meta:
            head += f" ({meta.get('kind', '?')}, format {meta.get('format', '?')})"
        print(head)
        for k in ("primitives", "basis_functions", "kinematics_degree", "demo_duration_s", "model"):
            if k in meta:
                print(f"  {k} = {meta[k]}")
        width = max(len(n) for n in b["tensors"]) if b["tensors"] else 0
        for name, t in sorted(b["tensors"].items()):
            shape = "[" + ", ".join(str(s) for s in t.shape) + "]"
            print(f"  {name:<{width}}  {str(t.dtype):<7} {shape}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
