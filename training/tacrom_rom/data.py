"""Paired data written by `tacrom gen-data` (src/datagen.rs) and the network inputs.

A data directory holds `dataset.json` and per sample `sample-NNNNNN.npy` (float32
[3, ny, nx], metres: coarse depth, rigid penetration, reference depth on the surface
lattice) with `sample-NNNNNN.json` (family, parameters, solver reports).

The features here are computed exactly as in src/rom/features.rs: keep the two
in step. tests/test_feature_parity.py checks it on presses written by `tacrom rom-features`.
"""
from __future__ import annotations

import dataclasses
import glob
import json
import os

import numpy as np
import torch


@dataclasses.dataclass
class Spec:
    size: tuple  # (Lx, Ly, T), m
    nx: int
    ny: int
    encoder_stride: int = 4
    patch: int = 5
    patch_step: int = 2
    depth_scale: float = 1000.0
    # {"poisson": [lo, hi], "friction": [lo, hi]} for a model conditioned on the gel's
    # material (two inputs appended to the encoder input and to every query); None otherwise.
    conditioning: dict | None = None

    @property
    def material_inputs(self):
        return 2 if self.conditioning else 0

    def material(self, poisson, friction):
        """The two material inputs (Conditioning::inputs in src/rom/features.rs): each value
        mapped linearly from its range onto [-1, 1] (0 for a range of one value)."""
        out = []
        for (lo, hi), v in ((self.conditioning["poisson"], poisson), (self.conditioning["friction"], friction)):
            out.append((2.0 * v - lo - hi) / (hi - lo) if hi > lo else 0.0)
        return out

    @property
    def pitch(self):
        return self.size[0] / self.nx

    @property
    def encoder_offset(self):
        return self.encoder_stride // 2

    def encoder_dims(self):
        s, o = self.encoder_stride, self.encoder_offset
        return len(range(o, self.ny, s)), len(range(o, self.nx, s))

    @property
    def encoder_len(self):
        r, c = self.encoder_dims()
        return 2 * r * c + self.material_inputs

    @property
    def query_len(self):
        return 2 + 2 * self.patch * self.patch + self.material_inputs

    @property
    def coarse_index(self):
        return 2 + (self.patch * self.patch) // 2

    def to_json(self):
        return dict(size=list(self.size), nx=self.nx, ny=self.ny, encoder_stride=self.encoder_stride,
                    patch=self.patch, patch_step=self.patch_step, depth_scale=self.depth_scale)


def conditioning_of(ds):
    """The material ranges of a data set that draws Poisson's ratio or friction per sample
    (gen-data --poisson LO,HI / --friction LO,HI), else None."""
    if "poisson_range" not in ds and "friction_range" not in ds:
        return None
    return {"poisson": list(ds.get("poisson_range") or [ds["poisson"]] * 2),
            "friction": list(ds.get("friction_range") or [ds["friction"]] * 2)}


def load_dir(path, drop_unconverged=True, conditioned=True, conditioning=None):
    """(spec, dataset meta, arrays [S, C, ny, nx] in model units, list of sample metas).
    C is 3 (coarse, penetration, reference), and 5 for a data set with per-sample materials:
    two constant channels of material inputs (Spec.material) follow. With `conditioned`
    False such a data set loads without them (a model that reads the material from the
    coarse channel alone); with "poisson", the friction range collapses to its midpoint, so
    that its input is always 0 (a model of Poisson's ratio alone). `conditioning` (ranges as
    `conditioning_of` gives them) maps the materials instead of the data set's own ranges:
    for a data set trained beside another (`train --also`), whose ranges the model takes."""
    with open(os.path.join(path, "dataset.json")) as f:
        ds = json.load(f)
    ny, nx = ds["lattice"]
    if conditioning is None:
        conditioning = conditioning_of(ds) if conditioned else None
    elif not conditioned:
        conditioning = None
    if conditioning and conditioned == "poisson":
        conditioning["friction"] = [sum(conditioning["friction"]) / 2] * 2
    spec = Spec(size=tuple(ds["size"]), nx=nx, ny=ny, conditioning=conditioning)
    arrays, metas = [], []
    for npy in sorted(glob.glob(os.path.join(path, "sample-*.npy"))):
        js = npy[:-4] + ".json"
        if not os.path.exists(js):
            continue
        with open(js) as f:
            meta = json.load(f)
        if drop_unconverged and not meta["reference"]["converged"]:
            continue
        a = np.load(npy).astype(np.float32) * spec.depth_scale
        if not np.isfinite(a).all():
            continue
        if spec.conditioning:
            m = spec.material(meta.get("poisson", ds["poisson"]), meta.get("friction", ds["friction"]))
            a = np.concatenate([a, np.broadcast_to(np.array(m, np.float32)[:, None, None], (2,) + a.shape[1:])])
        # The spacing of the sample's reference (`overlay_references` updates it).
        meta["reference_dx"] = ds.get("fine_dx")
        arrays.append(a)
        metas.append(meta)
    if not arrays:
        raise SystemExit(f"no usable samples in {path}")
    return spec, ds, np.stack(arrays), metas


def overlay_references(path, spec, ds, arrays, metas):
    """Replaces the reference channel of `arrays` with the finer reference in `path`, for
    each sample that `path` holds (same index, converged, finite).

    `path` must hold the same presses (`tacrom gen-data` with the same seed, lattice and
    coarse spacing, and another `--fine-dx`): a sample whose coarse channel differs from the
    base one is refused. Every meta gets `reference_dx`, the spacing of its reference now.
    Returns `path`'s dataset.json and the number of samples replaced.
    """
    meta_path = os.path.join(path, "dataset.json")
    if not os.path.isfile(meta_path):
        raise SystemExit(f"{path}: no dataset.json; `tacrom gen-data --out {path} ...` writes one")
    with open(meta_path) as f:
        fine = json.load(f)
    for key in ("size", "lattice", "seed", "coarse_dx", "young", "poisson", "pitch"):
        if fine.get(key) != ds.get(key):
            raise SystemExit(f"{path}: dataset.json {key} = {fine.get(key)!r}, "
                             f"but the base data set has {ds.get(key)!r}")
    replaced = 0
    for a, meta in zip(arrays, metas):
        meta["reference_dx"] = ds.get("fine_dx")
        stem = os.path.join(path, f"sample-{meta['index']:06d}")
        if not (os.path.exists(stem + ".npy") and os.path.exists(stem + ".json")):
            continue
        with open(stem + ".json") as f:
            m = json.load(f)
        if not m["reference"]["converged"]:
            continue
        b = np.load(stem + ".npy").astype(np.float32) * spec.depth_scale
        if b.shape != a[:3].shape or not np.isfinite(b).all():
            continue
        diff = float(np.abs(b[0] - a[0]).max())
        if diff > 1e-6:
            raise SystemExit(f"{stem}.npy: coarse channel differs from the base data set's by "
                             f"{diff:.3g} mm: not the same press")
        a[2] = b[2]
        meta["reference_dx"] = fine.get("fine_dx")
        replaced += 1
    return fine, replaced


def encoder_input(spec: Spec, lattice: torch.Tensor) -> torch.Tensor:
    """lattice [B, >=2, ny, nx] (coarse, pen, reference, then the material channels of a
    conditioned spec) -> [B, encoder_len]."""
    s, o = spec.encoder_stride, spec.encoder_offset
    sub = lattice[:, :2, o::s, o::s]
    flat = sub.reshape(sub.shape[0], -1)
    if spec.material_inputs:
        flat = torch.cat([flat, lattice[:, 3 : 3 + spec.material_inputs, 0, 0]], dim=1)
    return flat


def positions(spec: Spec):
    """Normalised (x, y) of every lattice point: two [ny, nx] arrays."""
    lx, ly = spec.size[0], spec.size[1]
    x = -0.5 * lx + (np.arange(spec.nx) + 0.5) * lx / spec.nx
    y = 0.5 * ly - (np.arange(spec.ny) + 0.5) * ly / spec.ny
    X, Y = np.meshgrid(x / (0.5 * lx), y / (0.5 * ly))
    return X.astype(np.float32), Y.astype(np.float32)


class QueryBuilder:
    """Decoder query features at lattice points, batched."""

    def __init__(self, spec: Spec, device="cpu"):
        self.spec = spec
        h = spec.patch // 2
        self.R = h * spec.patch_step
        off = torch.arange(-h, h + 1, device=device) * spec.patch_step
        self.dr = off[:, None].expand(-1, spec.patch).reshape(-1)
        self.dc = off[None, :].expand(spec.patch, -1).reshape(-1)
        X, Y = positions(spec)
        self.X = torch.from_numpy(X).to(device)
        self.Y = torch.from_numpy(Y).to(device)

    def pad(self, lattice):
        """[B, C, ny, nx] -> coarse, penetration (and the material channels of a conditioned
        spec), zero padded by the window radius."""
        keep = [0, 1] + list(range(3, 3 + self.spec.material_inputs))
        return torch.nn.functional.pad(lattice[:, keep], (self.R, self.R, self.R, self.R))

    def __call__(self, padded, b, rows, cols):
        """padded from pad(); b, rows, cols: index tensors of one shape S -> [S..., F]."""
        r = rows[..., None] + self.R + self.dr
        c = cols[..., None] + self.R + self.dc
        bb = b[..., None].expand_as(r)
        coarse = padded[bb, 0, r, c]
        pen = padded[bb, 1, r, c]
        pos = torch.stack([self.X[rows, cols], self.Y[rows, cols]], dim=-1)
        parts = [pos, coarse, pen]
        if self.spec.material_inputs:
            # Constant channels: their value at the first lattice point.
            parts.append(torch.stack([padded[b, 2 + k, self.R, self.R]
                                      for k in range(self.spec.material_inputs)], dim=-1))
        return torch.cat(parts, dim=-1)


def region_mask(lattice: np.ndarray, grow: int, eps_mm: float = 1e-3) -> np.ndarray:
    """Where the surface can be deformed: coarse depth or penetration above eps (mm),
    grown by `grow` lattice steps. lattice [..., C, ny, nx] -> bool [..., ny, nx].
    Matches `region` in src/rom/features.rs."""
    m = (lattice[..., 0, :, :] > eps_mm) | (lattice[..., 1, :, :] > 0)
    for _ in range(grow):
        g = m.copy()
        g[..., 1:, :] |= m[..., :-1, :]
        g[..., :-1, :] |= m[..., 1:, :]
        g[..., :, 1:] |= m[..., :, :-1]
        g[..., :, :-1] |= m[..., :, 1:]
        m = g
    return m
