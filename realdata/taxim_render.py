"""Taxim's own renderer on a calibration folder's presses: the baseline the calibrated
`rgb` output is compared with on real images.

    .venv-taxim/bin/python realdata/taxim_render.py DATA OUT [--shadow]
        [--centres OPTICS] [--fit-depth] [--only-every N]

For every press of DATA/presses.json (realdata/gelsight_mini.py writes such a folder),
renders a ball of the press's radius at its annotated centre, pressed to the depth
a^2 / (2 R) of its contact radius a, through Taxim (the `taxim` 1.4.1 package, JAX on the
CPU) with Taxim's own GelSight Mini calibration, and writes OUT/press_NNN.png (8-bit RGB,
the camera's orientation, the size of Taxim's calibration: 640 x 480) and OUT/timing.json
(seconds per frame, median after a warm-up; each press's centre and depth). Prints, per
press, the mean absolute error (colour in [0, 1], all channels) against the real image over
the whole image and within 1.5 contact radii of the centre, for Taxim and for the
background alone. Needs the environment of `make taxim-env`.

`--centres OPTICS` centres each ball at the contact that `tacrom calibrate --mirror`
detected (`calibration.presses[i].contact.centre` of its optics file, in the sensor's
orientation, mirrored back to the camera's), as the project's own renderers are scored.
`--fit-depth` replaces the geometric depth by the one whose render best matches the real
image within 1.5 annotated contact radii of the annotated centre (golden-section search
on the mean absolute error from 0.4 times the cap depth R - sqrt(R^2 - a^2) to the
half-space's depth a/2 ln((R + a) / (R - a)), as `tacrom compare` searches).
`--only-every N` renders only the presses with (index + 1) % N == 0 (the held-out presses
of `--holdout N`). The error region is always the annotated circle.
"""

import argparse
import json
import os
import pathlib
import sys
import time

os.environ.setdefault("JAX_PLATFORMS", "cpu")

import jax  # noqa: E402
import numpy as np  # noqa: E402
from taxim import CALIB_GELSIGHT_MINI, Taxim  # noqa: E402

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from gelsight_mini import read_png, write_png  # noqa: E402

# The region of the contact MAE, in contact radii from the centre.
CONTACT_REGION = 1.5
# --fit-depth: the lower end of the search, in cap depths R - sqrt(R^2 - a^2) (its upper
# end is the half-space's depth, `half_space_depth`), and its golden-section steps after
# the two initial points.
DEPTH_FLOOR = 0.4
DEPTH_STEPS = 12
GOLDEN = (np.sqrt(5.0) - 1.0) / 2.0


def half_space_depth(a: float, radius: float) -> float:
    """The depth to which a rigid sphere of `radius` sinks into an elastic half-space
    when its contact circle has radius `a` (Sneddon: a/2 ln((R + a) / (R - a)), twice the
    cap's depth for a << R): a gel bonded to its window sinks less, so no press of that
    circle lies deeper (`half_space_depth` of crates/tacrom-tools/src/calibrate/gel.rs)."""
    if a >= radius:
        return radius
    return min(0.5 * a * np.log((radius + a) / (radius - a)), radius)


def ball_height_map(shape: tuple[int, int], centre_px, radius_mm: float, pixel_mm: float) -> np.ndarray:
    """The ball's surface in Taxim's height-map convention (mm, smaller is nearer the
    camera): 0 at its lowest point, R - sqrt(R^2 - rho^2) at a distance rho from the
    centre, R beyond its outline. `render(..., press_depth=d)` shifts it so that its lowest
    point lies d below the gel's surface (the gel's highest point, 0)."""
    rows, cols = np.mgrid[: shape[0], : shape[1]].astype(np.float64)
    rho2 = ((cols - centre_px[0]) ** 2 + (rows - centre_px[1]) ** 2) * pixel_mm**2
    return np.where(rho2 < radius_mm**2, radius_mm - np.sqrt(np.maximum(radius_mm**2 - rho2, 0.0)), radius_mm)


def mae(a: np.ndarray, b: np.ndarray, mask: np.ndarray | None = None) -> float:
    err = np.abs(a.astype(np.float64) - b.astype(np.float64)) / 255.0
    return float(err.mean() if mask is None else err[mask].mean())


def golden_section(f, lo: float, hi: float, steps: int):
    """Minimises f over [lo, hi]: the two interior golden points, then `steps` more
    evaluations, each shrinking the bracket by the golden ratio. Returns the best point
    evaluated, its value and every (x, f(x)) in order."""
    x1, x2 = hi - GOLDEN * (hi - lo), lo + GOLDEN * (hi - lo)
    f1, f2 = f(x1), f(x2)
    seen = [(x1, f1), (x2, f2)]
    for _ in range(steps):
        if f1 <= f2:  # the minimum lies in [lo, x2]
            hi, x2, f2 = x2, x1, f1
            x1 = hi - GOLDEN * (hi - lo)
            f1 = f(x1)
            seen.append((x1, f1))
        else:  # in [x1, hi]
            lo, x1, f1 = x1, x2, f2
            x2 = lo + GOLDEN * (hi - lo)
            f2 = f(x2)
            seen.append((x2, f2))
    best = min(seen, key=lambda xf: xf[1])
    return best[0], best[1], seen


def read_centres(path: pathlib.Path, presses: list, width: int) -> list:
    """The detected contact centres of a `tacrom calibrate --mirror` optics file, in the
    camera's orientation ([column, row], pixel c centred at c)."""
    cal = json.loads(path.read_text())["calibration"]
    listed = cal["presses"]
    if len(listed) != len(presses):
        raise SystemExit(f"{path}: {len(listed)} presses, presses.json has {len(presses)}")
    if not cal.get("mirror", False):
        raise SystemExit(f"{path}: not calibrated with --mirror; its centres would not need mirroring")
    centres = []
    for i, (c, p) in enumerate(zip(listed, presses)):
        if c["image"] != p["image"]:
            raise SystemExit(f"{path}: press {i} is {c['image']}, presses.json has {p['image']}")
        column, row = c["contact"]["centre"]
        centres.append([width - 1 - column, row])
    return centres


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data", type=pathlib.Path)
    ap.add_argument("out", type=pathlib.Path)
    ap.add_argument("--shadow", action="store_true", help="Taxim's shadows (with_shadow=True)")
    ap.add_argument("--centres", type=pathlib.Path, metavar="OPTICS",
                    help="ball centres from the detected contacts of a `tacrom calibrate --mirror` optics file")
    ap.add_argument("--fit-depth", action="store_true",
                    help="each press's depth by golden-section search on the contact-region error")
    ap.add_argument("--only-every", type=int, default=1, metavar="N",
                    help="render only the presses with (index + 1) %% N == 0")
    args = ap.parse_args()
    if args.only_every < 1:
        raise SystemExit("--only-every: N must be at least 1")

    listing = json.loads((args.data / "presses.json").read_text())
    background = read_png(args.data / listing.get("background", "background.png"))
    taxim = Taxim(calib_folder=CALIB_GELSIGHT_MINI, backend="jax", device="cpu")
    shape = (taxim.height, taxim.width)
    if background.shape[:2] != shape:
        raise SystemExit(f"{args.data}: images of {background.shape[1]} x {background.shape[0]} px, "
                         f"Taxim's calibration is {shape[1]} x {shape[0]}")
    args.out.mkdir(parents=True, exist_ok=True)

    presses = listing["presses"]
    if args.centres is not None:
        centres = read_centres(args.centres, presses, shape[1])
    else:
        centres = [p["center_px"] for p in presses]
    chosen = [i for i in range(len(presses)) if (i + 1) % args.only_every == 0]

    def render(p, centre, depth):
        hm = jax.numpy.asarray(ball_height_map(shape, centre, p["ball_radius_mm"], p["pixel_size_mm"]))
        jax.block_until_ready(hm)
        start = time.perf_counter()
        img = taxim.render_direct(hm, with_shadow=args.shadow, press_depth=depth)
        img = jax.block_until_ready(img)
        elapsed = time.perf_counter() - start
        return np.round(np.clip(np.asarray(img), 0.0, 1.0) * 255.0).astype(np.uint8), elapsed

    render(presses[0], centres[0], 0.1)  # warm-up: compiles the renderer
    seconds, rows, depths, fits = [], [], [], []
    print(f"{'press':>5} {'depth mm':>8} {'taxim all':>9} {'contact':>8} {'bg all':>8} {'contact':>8} {'s':>6}")
    rows_px, cols_px = np.mgrid[: shape[0], : shape[1]]
    for i in chosen:
        p = presses[i]
        real = read_png(args.data / p["image"])
        r = CONTACT_REGION * p["contact_radius_px"]
        near = (cols_px - p["center_px"][0]) ** 2 + (rows_px - p["center_px"][1]) ** 2 <= r * r
        a_mm = p["contact_radius_px"] * p["pixel_size_mm"]
        radius = p["ball_radius_mm"]
        if args.fit_depth:
            cap = radius - np.sqrt(radius**2 - a_mm**2)
            lo, hi = DEPTH_FLOOR * cap, half_space_depth(a_mm, radius)
            start = time.perf_counter()
            depth, _, seen = golden_section(lambda d: mae(render(p, centres[i], d)[0], real, near), lo, hi, DEPTH_STEPS)
            fits.append({"press": i, "cap_mm": float(cap), "bracket_mm": [float(lo), float(hi)],
                         "seconds": round(time.perf_counter() - start, 3),
                         "evaluations": [[round(float(x), 6), round(float(e), 6)] for x, e in seen]})
        else:
            depth = a_mm**2 / (2.0 * radius)
        out, dt = render(p, centres[i], depth)
        seconds.append(dt)
        depths.append(float(depth))
        write_png(args.out / p["image"], out)
        row = (mae(out, real), mae(out, real, near), mae(background, real), mae(background, real, near))
        rows.append(row)
        print(f"{i:>5} {depth:>8.4f} {row[0]:>9.4f} {row[1]:>8.4f} {row[2]:>8.4f} {row[3]:>8.4f} {dt:>6.3f}")
    m = np.mean(rows, axis=0)
    print(f"{'mean':>5} {'':>8} {m[0]:>9.4f} {m[1]:>8.4f} {m[2]:>8.4f} {m[3]:>8.4f} {np.median(seconds):>6.3f}")
    timing = {
        "renderer": "taxim 1.4.1, jax " + jax.__version__ + ", cpu",
        "calibration": "gelsight_mini",
        "shadow": args.shadow,
        "centres": str(args.centres) if args.centres is not None else "annotated",
        "depth": "fit" if args.fit_depth else "geometric a^2 / (2 R)",
        "frames": len(seconds),
        "presses": chosen,
        "seconds_per_frame_median": float(np.median(seconds)),
        "seconds_per_frame": [round(s, 5) for s in seconds],
        "cpu_count": os.cpu_count(),
        "centres_px": [[round(float(c), 4) for c in centres[i]] for i in chosen],
        "depths_mm": [round(d, 6) for d in depths],
        "mae_contact": [round(r[1], 6) for r in rows],
        "mae_contact_mean": float(np.mean([r[1] for r in rows])),
    }
    if args.fit_depth:
        timing["depth_fit"] = {"floor_caps": DEPTH_FLOOR, "ceiling": "half-space", "steps": DEPTH_STEPS,
                               "error": "mean absolute (colour in [0, 1], all channels) within 1.5 annotated contact radii of the annotated centre",
                               "presses": fits}
    (args.out / "timing.json").write_text(json.dumps(timing, indent=1) + "\n")


if __name__ == "__main__":
    main()
