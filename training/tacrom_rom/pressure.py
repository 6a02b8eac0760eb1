"""The contact pressure head of a trained model: the reference's normal contact pressure
from the decoder's own inputs, so that rom's force and pressure come from the fine level.

    python -m tacrom_rom.pressure --data data/rom-p0.5 --model models/rom-default [--steps N]
        [--seed 0] [--threads 2] [--out DIR]

The head is g_p(z, q, w): the same latent `z` (the model's encoder, frozen) and the same
query features `q` as the decoder (data.QueryBuilder; src/rom/features.rs), then `w`, the
coarse gel's contact load at the point's window (the decoder's window offsets, zero
outside the lattice; `load_window` in src/rom/features.rs) in the head's own units;
hidden [256, 128] with LayerNorm and ReLU, one output per lattice point (manifest
`pressure.units = coarse_force`): the point's load (pressure times its area) over the
coarse gel's normal force shared equally among the deformable region's points (so of
order 1), so that the head corrects the coarse load (which carries the gel's Poisson's
ratio and Young's modulus) rather than replacing it. Presses whose coarse force is below
FORCE_FLOOR_N are left out of training and validation. At run time the output is
max(0, g_p), and the normal force its sum over the region times the coarse force over the
region's points. (The pressure over Young's modulus, p / E, was tried as the output and
could not see the gel's material: docs/rom.md.)

Trained on the pressure companions `sample-NNNNNN-pressure.npy` of a `tacrom gen-data`
data set (channel 0 the coarse gel's pressure, channel 1 the reference's; see
src/datagen.rs), on every lattice point
of each press's deformable region (where the reference carries its load; the head is not
run elsewhere). Losses, per press, in the head's units:
* the field: the squared error of the output where the reference presses and of
  max(0, output) where it does not (zero pressure there; a negative output costs
  nothing), summed over the points and divided by the reference's sum of squares (a
  relative error, so that a small contact counts as much as a large one);
* the force: the relative error of the summed output (the normal force) squared, with a
  floor of FORCE_FLOOR_N in the denominator, weight FORCE_WEIGHT.
The 8 lattice symmetries augment the presses, as for the autoencoder.

Writes `pressure.onnx` (z [1, r], query [N, F + patch^2] -> pressure [N, 1]) and the head's weights
into the model's directory (or --out, a copy of it), and adds `files.pressure` and a
`pressure` record (data, training, held-out force errors) to its manifest.
"""
from __future__ import annotations

import argparse
import json
import os
import shlex
import shutil
import sys
import time

import numpy as np
import torch
from torch import nn

from . import data as D
from .export import OPSET, _export
from .model import Autoencoder, Mlp, hidden_of
from .train import REGION_EPS_MM, REGION_GROW, augment, gen_command, split

HIDDEN = (256, 128)
FORCE_WEIGHT = 1.0
FORCE_FLOOR_N = 1e-3


class PressureHead(nn.Module):
    """(z [1, r], query [N, F]) -> p / E [N, 1]."""

    def __init__(self, latent: int, n_query: int):
        super().__init__()
        self.latent = latent
        self.mlp = Mlp(latent + n_query, 1, HIDDEN)
        # Start from no pressure anywhere.
        nn.init.zeros_(self.mlp.out.weight)
        nn.init.zeros_(self.mlp.out.bias)

    def forward_batched(self, z, q):
        """z [B, r], q [B, N, F] -> [B, N]."""
        zz = z[:, None, :].expand(-1, q.shape[1], -1)
        return self.mlp(torch.cat([zz, q], dim=-1))[..., 0]

    def forward(self, z, query):
        return self.mlp(torch.cat([z.expand(query.shape[0], -1), query], dim=-1))


UNITS = "coarse_force"


def load_pressure(path, metas):
    """[S, 2, ny, nx] coarse and reference pressure (Pa) of each sample in `metas`."""
    out = []
    for m in metas:
        f = os.path.join(path, f"sample-{m['index']:06d}-pressure.npy")
        if not os.path.exists(f):
            raise SystemExit(f"{f}: missing; data sets written before the pressure was recorded "
                             "have none (tacrom gen-data writes it now)")
        out.append(np.load(f).astype(np.float32))
    return np.stack(out)


def unit_of(area, coarse_force, points):
    """Pascals per unit of the head's output at one lattice point of `area` (m^2), for a
    press whose deformable region has `points` lattice points."""
    return coarse_force / (points * area)


def load_model(model_dir):
    with open(os.path.join(model_dir, "manifest.json")) as f:
        manifest = json.load(f)
    lat = manifest["lattice"]
    spec = D.Spec(size=tuple(lat["size"]), nx=lat["nx"], ny=lat["ny"], encoder_stride=lat["encoder_stride"],
                  patch=lat["patch"], patch_step=lat["patch_step"], depth_scale=lat["depth_scale"],
                  conditioning=manifest.get("conditioning"))
    model = Autoencoder(spec.encoder_len, spec.query_len, spec.coarse_index, manifest["latent"],
                        hidden_of(manifest))
    model.load_state_dict(torch.load(os.path.join(model_dir, "weights.pt"), weights_only=True))
    model.eval()
    return manifest, spec, model


def load_windows(qb, load, s, rows, cols):
    """The window of `load` [S, ny, nx] (zero outside) at each (rows, cols) of sample s:
    [N, patch^2], row offset outer (as QueryBuilder's windows)."""
    padded = torch.nn.functional.pad(load[s], (qb.R, qb.R, qb.R, qb.R))
    return padded[rows[:, None] + qb.R + qb.dr, cols[:, None] + qb.R + qb.dc]


class Presses:
    """Every press's region points, their head queries (the decoder's query, then the
    coarse load window) and reference pressure, with z. `load` and `pressure` [S, ny, nx]
    in the head's units."""

    def __init__(self, spec, model, arrays, load, pressure):
        region = D.region_mask(arrays, REGION_GROW, REGION_EPS_MM)
        qb = D.QueryBuilder(spec)
        lat = torch.from_numpy(arrays)
        load = torch.from_numpy(np.ascontiguousarray(load))
        with torch.no_grad():
            self.z = model.encoder(D.encoder_input(spec, lat))
        padded = qb.pad(lat)
        self.q, self.p = [], []
        for s in range(len(arrays)):
            flat = torch.from_numpy(np.flatnonzero(region[s]))
            rows, cols = flat // spec.nx, flat % spec.nx
            q = qb(padded, torch.full_like(rows, s), rows, cols)
            self.q.append(torch.cat([q, load_windows(qb, load, s, rows, cols)], dim=-1))
            self.p.append(torch.from_numpy(pressure[s].reshape(-1)[flat.numpy()]))
        # Load outside the region (the head is not run there): should be none.
        self.outside = [float(pressure[s][~region[s]].sum()) for s in range(len(arrays))]

    def batch(self, idx):
        """Padded [B, N, F] queries, [B, N] targets and a [B, N] mask of real points."""
        n = max(len(self.p[i]) for i in idx)
        F = self.q[idx[0]].shape[-1]
        q = torch.zeros(len(idx), n, F)
        p = torch.zeros(len(idx), n)
        mask = torch.zeros(len(idx), n)
        for k, i in enumerate(idx):
            m = len(self.p[i])
            q[k, :m], p[k, :m], mask[k, :m] = self.q[i], self.p[i], 1.0
        return self.z[idx], q, p, mask


def losses(head, presses, idx, floor):
    """The field and force losses of the presses `idx`; `floor[i]`: FORCE_FLOOR_N in
    press i's units."""
    z, q, p, mask = presses.batch(idx)
    floor = torch.as_tensor(floor[idx], dtype=p.dtype)
    out = head.forward_batched(z, q)
    pos = (p > 0).float()
    err = pos * (out - p) ** 2 + (1 - pos) * torch.relu(out) ** 2
    # A press's field error relative to its own field (floored: a 100-point contact
    # carrying FORCE_FLOOR_N).
    norm = (p**2 * mask).sum(1) + floor**2 / 100
    field = ((err * mask).sum(1) / norm).mean()
    f_hat = (torch.relu(out) * mask).sum(1)
    f = (p * mask).sum(1)
    force = (((f_hat - f) / (f + floor)) ** 2).mean()
    return field, force


@torch.no_grad()
def forces(head, presses, idx, scale):
    """(predicted, reference) normal force (N) of each press in idx; `scale[i]`: newtons per
    unit of summed output of press i."""
    pred, ref = [], []
    for i in idx:
        out = head(presses.z[i : i + 1], presses.q[i])[:, 0]
        pred.append(float(torch.relu(out).sum()) * scale[i])
        ref.append(float(presses.p[i].sum()) * scale[i])
    return np.array(pred), np.array(ref)


def force_errors(pred, ref, min_force=FORCE_FLOOR_N):
    """Median, 90th percentile and mean of the relative force error (%) over presses above
    min_force."""
    keep = ref > min_force
    e = 100 * np.abs(pred[keep] - ref[keep]) / ref[keep]
    if not len(e):
        return {}
    return {"presses": int(keep.sum()), "median_pct": float(np.median(e)),
            "p90_pct": float(np.percentile(e, 90)), "mean_pct": float(e.mean())}


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--data", required=True, help="a gen-data set with pressure companions")
    p.add_argument("--model", required=True, help="the trained model the head joins")
    p.add_argument("--out", default=None, help="write into a copy of --model here (default: --model itself)")
    p.add_argument("--steps", type=int, default=3000, help="optimizer steps (cosine learning-rate schedule over them)")
    p.add_argument("--batch", type=int, default=8, help="presses per step")
    p.add_argument("--lr", type=float, default=1e-3, help="Adam learning rate at the start")
    p.add_argument("--seed", type=int, default=0, help="seed of the head's weights and the batches")
    p.add_argument("--threads", type=int, default=1, help="torch CPU threads")
    a = p.parse_args(argv)
    torch.set_num_threads(a.threads)
    torch.manual_seed(a.seed)
    rng = np.random.default_rng(a.seed)

    manifest, spec, model = load_model(a.model)
    dspec, ds, arrays, metas = D.load_dir(a.data, conditioned=spec.conditioning is not None)
    if (dspec.nx, dspec.ny, tuple(dspec.size)) != (spec.nx, spec.ny, tuple(spec.size)):
        raise SystemExit(f"{a.data}: lattice {dspec.nx} x {dspec.ny} of {dspec.size}, the model's "
                         f"{spec.nx} x {spec.ny} of {spec.size}")
    if (ds.get("recipe") or {}).get("solver") != manifest["recipe"]["solver"] or ds["coarse_dx"] != manifest["coarse_dx"]:
        raise SystemExit(f"{a.data}: coarse solve {ds.get('recipe')}, the model's {manifest['recipe']}")
    area = (spec.size[0] / spec.nx) * (spec.size[1] / spec.ny)
    both_pressures = load_pressure(a.data, metas)
    coarse_force = np.array([((m.get("coarse") or {}).get("force") or [0, 0, np.nan])[2] for m in metas])
    if not np.isfinite(coarse_force).all():
        raise SystemExit(f"{a.data}: samples without a recorded coarse force")
    # Newtons per unit of summed output, per press.
    points = D.region_mask(arrays, REGION_GROW, REGION_EPS_MM).sum(axis=(1, 2))
    scale = np.array([unit_of(area, f, n) * area for f, n in zip(coarse_force, points)])
    tr, va = split(metas, set(ds["held_out"]))
    n_va = len(va)
    # Where the coarse gel carries (almost) no load, the sensor keeps the coarse force.
    tr = tr[coarse_force[tr] >= FORCE_FLOOR_N]
    va = va[coarse_force[va] >= FORCE_FLOOR_N]
    # Coarse load and reference pressure in the head's units.
    both_units = (both_pressures * area / scale[:, None, None, None]).astype(np.float32)
    both = np.concatenate([arrays, both_units], axis=1)
    aug, n_aug = augment(both[tr])
    train = Presses(spec, model, np.ascontiguousarray(aug[:, :-2]), aug[:, -2], aug[:, -1])
    held = Presses(spec, model, arrays[va], both_units[va, 0], both_units[va, 1])
    tr_scale, va_scale = np.repeat(scale[tr], n_aug), scale[va]
    floor = FORCE_FLOOR_N / tr_scale
    outside = max([o * s for o, s in zip(train.outside, tr_scale)] + [o * s for o, s in zip(held.outside, va_scale)])
    print(f"{len(metas)} presses: {len(tr)} train (x{n_aug} symmetries), {len(va)} held out; "
          f"largest load outside a region {outside:.2e} N", flush=True)

    n_query = spec.query_len + spec.patch * spec.patch
    head = PressureHead(manifest["latent"], n_query)
    opt = torch.optim.Adam(head.parameters(), lr=a.lr)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, a.steps)
    t0 = time.time()
    for step in range(1, a.steps + 1):
        idx = rng.choice(len(train.p), size=a.batch, replace=False)
        field, force = losses(head, train, idx, floor)
        total = field + FORCE_WEIGHT * force
        opt.zero_grad()
        total.backward()
        opt.step()
        sched.step()
        if step % 250 == 0 or step == 1:
            print(f"step {step} field {field.item():.3e} force {force.item():.3e} ({time.time() - t0:.0f}s)",
                  flush=True)
    seconds = time.time() - t0
    head.eval()

    val_pred, val_ref = forces(head, held, range(len(va)), va_scale)
    tr_idx = np.arange(0, len(train.p), n_aug)[:64]
    tr_pred, tr_ref = forces(head, train, tr_idx, tr_scale)
    validation = {"held_out": force_errors(val_pred, val_ref),
                  "held_out_left_out": n_va - len(va),
                  "train_subset": force_errors(tr_pred, tr_ref)}
    recorded = [[(metas[i].get(k) or {}).get("force") for k in ("coarse", "reference")] for i in va]
    if recorded and all(c and r for c, r in recorded):
        coarse, ref = (np.array([x[k][2] for x in recorded]) for k in (0, 1))
        validation["held_out_coarse"] = force_errors(coarse, val_ref)
        # How far the lattice's pressure integrates from the solve's recorded force.
        validation["lattice_vs_recorded_reference_max_pct"] = float(
            100 * np.max(np.abs(val_ref - ref) / np.maximum(ref, FORCE_FLOOR_N)))
    print("validation", json.dumps(validation, indent=1), flush=True)

    out = a.out or a.model
    if out != a.model:
        shutil.copytree(a.model, out, dirs_exist_ok=True)
    r, F = manifest["latent"], n_query
    with torch.no_grad():
        _export(head, (torch.zeros(1, r), torch.zeros(7, F)), os.path.join(out, "pressure.onnx"),
                ["z", "query"], ["pressure"], {"query": {0: "points"}, "pressure": {0: "points"}})
    torch.save(head.state_dict(), os.path.join(out, "pressure.pt"))
    manifest["files"]["pressure"] = {"path": "pressure.onnx", "inputs": {"z": [1, r], "query": [-1, F]},
                                     "outputs": {"pressure": [-1, 1]}}
    all_idx = sorted(int(f[7:13]) for f in os.listdir(a.data)
                     if f.startswith("sample-") and f.endswith(".json"))
    manifest["pressure"] = {
        "units": UNITS,
        "query": "the decoder's query, then the coarse load's window in the head's units",
        "reference_dx": ds["fine_dx"],
        "data": {"command": gen_command(a.data, ds), "path": a.data, "generated": len(all_idx),
                 "train": int(len(tr)), "validation": int(len(va))},
        "training": {"command": "python -m tacrom_rom.pressure " + " ".join(
                         shlex.quote(x) for x in (argv if argv is not None else sys.argv[1:])),
                     "steps": a.steps, "seconds": round(seconds, 1), "threads": a.threads,
                     "batch": a.batch, "hidden": list(HIDDEN), "lr": a.lr, "seed": a.seed,
                     "losses": {"field": 1.0, "force": FORCE_WEIGHT, "force_floor_n": FORCE_FLOOR_N},
                     "opset": OPSET, "torch": torch.__version__},
        "validation": validation,
    }
    with open(os.path.join(out, "manifest.json"), "w") as f:
        json.dump(manifest, f, indent=1)
    print(f"wrote {out}/pressure.onnx in {seconds:.0f}s of training", flush=True)


if __name__ == "__main__":
    main()
