"""Behaviour-cloning datasets: camera frames with the expert's wheel commands, as NPZ shards + JSON.

On disk a dataset is a folder that any NumPy user can read without proxybench::

    dataset.json          what it is: domain, every episode's seed and θ, how it was collected, shard list
    shard-00000.npz       arrays of up to ``shard_size`` samples (see ``ARRAYS``)
    shard-00001.npz       ...

``dataset.json`` is written last, so a folder without it is an interrupted write, never a dataset.
Samples are stored episode by episode, so taking whole episodes (``take``) models collecting fewer
target samples — the quantity a proxy is meant to save.
"""

from __future__ import annotations

import hashlib
import json
import shutil
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from proxybench import __version__

__all__ = ["ARRAYS", "FORMAT", "Dataset", "DatasetError"]

FORMAT = "proxybench-bc-dataset"
#: array name → (dtype, per-sample shape, meaning); images have shape (H, W, 3)
ARRAYS: dict[str, tuple[str, str]] = {
    "images": ("uint8", "camera frame (H, W, 3) RGB"),
    "actions": ("float32", "expert label: wheel PWM (left, right) of pure pursuit on the true pose"),
    "executed": ("float32", "what the robot actually did: the label plus noise, or the learner's command"),
    "episode": ("int32", "episode id (an index into dataset.json's episodes)"),
    "frame": ("int32", "frame index within the episode"),
    "on_policy": ("bool", "True where the learner drove (DAgger), False where the (noisy) expert drove"),
}


class DatasetError(ValueError):
    """A dataset folder is missing, incomplete or inconsistent; the message names the file."""


@dataclass
class Dataset:
    """Arrays of equal length (see ``ARRAYS``) and metadata: ``meta["episodes"]`` (id, seed, θ index,
    robot, on_policy), ``meta["thetas"]`` (θ dicts), ``meta["domain"]`` and ``meta["collect"]``.
    """

    arrays: dict[str, np.ndarray]
    meta: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        missing = [k for k in ARRAYS if k not in self.arrays]
        if missing:
            raise DatasetError(f"dataset lacks array(s) {', '.join(missing)}")
        n = {k: len(v) for k, v in self.arrays.items()}
        if len(set(n.values())) > 1:
            raise DatasetError(f"arrays differ in length: {n}")
        self.meta.setdefault("episodes", [])
        self.meta.setdefault("thetas", [])

    def __len__(self) -> int:
        return len(self.arrays["actions"])

    @property
    def images(self) -> np.ndarray:
        return self.arrays["images"]

    @property
    def actions(self) -> np.ndarray:
        return self.arrays["actions"]

    @property
    def image_size(self) -> tuple[int, int]:
        """(width, height) [px]."""
        return int(self.images.shape[2]), int(self.images.shape[1])

    @property
    def on_policy_count(self) -> int:
        return int(self.arrays["on_policy"].sum())

    # -- selection -----------------------------------------------------------------------------

    def select(self, idx: np.ndarray) -> Dataset:
        """The samples at ``idx`` (a copy), with the metadata of the episodes they come from."""
        arrays = {k: v[idx] for k, v in self.arrays.items()}
        keep = set(np.unique(arrays["episode"]).tolist())
        meta = {**self.meta, "episodes": [e for e in self.meta["episodes"] if e["id"] in keep]}
        return Dataset(arrays, meta)

    def take(self, n: int, seed: int = 0) -> Dataset:
        """``n`` samples made of whole episodes in a seeded random order (the last one cut short).

        Different seeds give different subsets; for one seed a smaller ``n`` is a prefix of a larger one,
        so learning curves over ``n`` compare nested data sets.
        """
        if n > len(self):
            raise DatasetError(f"asked for {n} samples, the dataset has {len(self)}")
        ep = self.arrays["episode"]
        ids = np.unique(ep)
        order = np.random.default_rng(seed).permutation(ids)
        rank = np.empty(int(ids.max()) + 1, dtype=np.int64)
        rank[order] = np.arange(order.size)
        idx = np.lexsort((self.arrays["frame"], rank[ep]))[:n]
        return self.select(np.sort(idx))

    @staticmethod
    def concat(parts: Sequence[Dataset]) -> Dataset:
        """One dataset from several; episode ids and θ indices are renumbered to stay unique."""
        if not parts:
            raise DatasetError("nothing to concatenate")
        arrays: dict[str, list[np.ndarray]] = {k: [] for k in ARRAYS}
        episodes: list[dict[str, Any]] = []
        thetas: list[dict[str, Any]] = []
        next_id = 0
        for d in parts:
            remap = {e["id"]: next_id + k for k, e in enumerate(d.meta["episodes"])}
            for e in d.meta["episodes"]:
                episodes.append({**e, "id": remap[e["id"]], "theta": e["theta"] + len(thetas)})
            for k in ARRAYS:
                a = d.arrays[k]
                if k == "episode":
                    lut = np.full(max(remap, default=-1) + 2, -1, dtype=np.int32)
                    for old, new in remap.items():
                        lut[old] = new
                    a = lut[a]
                arrays[k].append(a)
            thetas.extend(d.meta["thetas"])
            next_id += len(remap)
        meta = {**parts[0].meta, "episodes": episodes, "thetas": thetas,
                "parts": [p.meta.get("domain", {}).get("name") for p in parts]}
        return Dataset({k: np.concatenate(v) for k, v in arrays.items()}, meta)

    # -- files ---------------------------------------------------------------------------------

    def save(self, folder: str | Path, shard_size: int = 4096, compress: bool = True) -> Path:
        """Write NPZ shards, then ``dataset.json`` (so its presence means the folder is complete)."""
        folder = Path(folder)
        if folder.exists():
            shutil.rmtree(folder)
        folder.mkdir(parents=True)
        save = np.savez_compressed if compress else np.savez
        shards = []
        for k, lo in enumerate(range(0, max(len(self), 1), shard_size)):
            name = f"shard-{k:05d}.npz"
            save(folder / name, **{a: v[lo:lo + shard_size] for a, v in self.arrays.items()})
            shards.append({"file": name, "samples": min(shard_size, len(self) - lo),
                           "sha256": hashlib.sha256((folder / name).read_bytes()).hexdigest()})
        side = {"format": FORMAT, "version": 1, "proxybench_version": __version__, "samples": len(self),
                "image_shape": list(self.images.shape[1:]),
                "arrays": {k: {"dtype": dt, "meaning": m} for k, (dt, m) in ARRAYS.items()},
                "shards": shards, **self.meta}
        tmp = folder / ".dataset.json.tmp"
        tmp.write_text(json.dumps(side, indent=1, default=_jsonable))
        tmp.replace(folder / "dataset.json")
        return folder

    @classmethod
    def load(cls, folder: str | Path, verify: bool = False) -> Dataset:
        """Read a folder written by :meth:`save`; ``verify`` also checks every shard's SHA-256."""
        folder = Path(folder)
        side_path = folder / "dataset.json"
        if not side_path.exists():
            raise DatasetError(f"{folder}: no dataset.json (not a dataset, or an interrupted write)")
        side = json.loads(side_path.read_text())
        if side.get("format") != FORMAT:
            raise DatasetError(f"{side_path}: format {side.get('format')!r}, expected {FORMAT!r}")
        parts: dict[str, list[np.ndarray]] = {k: [] for k in ARRAYS}
        for s in side["shards"]:
            path = folder / s["file"]
            if verify and hashlib.sha256(path.read_bytes()).hexdigest() != s["sha256"]:
                raise DatasetError(f"{path}: checksum mismatch")
            with np.load(path) as z:
                for k in ARRAYS:
                    parts[k].append(z[k])
        arrays = {k: np.concatenate(v) for k, v in parts.items()}
        if len(arrays["actions"]) != side["samples"]:
            raise DatasetError(f"{folder}: {len(arrays['actions'])} samples in shards, dataset.json says "
                               f"{side['samples']}")
        skip = {"format", "version", "samples", "image_shape", "arrays", "shards", "proxybench_version"}
        return cls(arrays, {k: v for k, v in side.items() if k not in skip})


def _jsonable(obj: Any) -> Any:
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    return str(obj)
