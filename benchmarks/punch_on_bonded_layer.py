"""The normal force of a rigid flat punch pressed into an elastic layer bonded to a rigid
base, frictionless, in linear elasticity, independent of every solver of the plugin: the
layer's surface compliance in Fourier space (exact for a layer of infinite lateral extent)
and the pressure under the punch solved by conjugate gradients on an FFT grid.

    .venv/bin/python benchmarks/punch_on_bonded_layer.py square 14      # flat_slab's face
    .venv/bin/python benchmarks/punch_on_bonded_layer.py disk 3         # cylinder's face

(side or radius in mm; the default gel: E 1.19e5 Pa, Poisson 0.43, 4 mm thick; 0.1 mm
deep). Prints the force at three grid spacings and their Richardson extrapolation (the
error halves with the spacing: the pressure is singular at the punch's edge).

The surface displacement under a pressure of wavenumber k is `2 (1 - nu^2) / (E k) A(kh)`
with `A(t) = (2 kappa sinh 2t - 4t) / (2 kappa cosh 2t + 4t^2 + kappa^2 + 1)`, `kappa = 3 -
4 nu`: it tends to the half-space's at large `kh` and to the confined compression `h / M`
(`M` the P-wave modulus) at `k = 0`. A layer of finite extent with free sides is the
infinite one with material taken away, so under a frictionless punch driven to a given
depth it carries at most this force: an upper bound for the gel of the benchmark, exact
as its sides move away.
"""
import argparse

import numpy as np


def punch_force(shape, size, spacing, period, depth=1e-4, young=1.19e5, poisson=0.43, h=4e-3):
    n = int(round(period / spacing))
    x = (np.arange(n) - n // 2) * spacing
    X, Y = np.meshgrid(x, x, indexing="ij")
    if shape == "square":
        inside = (np.abs(X) < size / 2) & (np.abs(Y) < size / 2)
    else:
        inside = X**2 + Y**2 < size**2
    k1 = 2 * np.pi * np.fft.fftfreq(n, spacing)
    k = np.hypot(k1[:, None], k1[None, :])
    kappa, t = 3 - 4 * poisson, k * h
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        a = (2 * kappa * np.sinh(2 * t) - 4 * t) / (2 * kappa * np.cosh(2 * t) + 4 * t**2 + kappa**2 + 1)
        g = 2 * (1 - poisson**2) / young * np.where(t > 30, 1.0, a) / k
    g[0, 0] = h * (1 + poisson) * (1 - 2 * poisson) / (young * (1 - poisson))

    def sink(p):  # surface sinking under pressure p on the cells under the punch
        full = np.zeros((n, n))
        full[inside] = p
        return np.real(np.fft.ifft2(g * np.fft.fft2(full)))[inside]

    b = np.full(inside.sum(), depth)
    p = np.zeros_like(b)
    r = b - sink(p)
    d = r.copy()
    rr = r @ r
    for _ in range(5000):
        q = sink(d)
        alpha = rr / (d @ q)
        p += alpha * d
        r -= alpha * q
        rr, last = r @ r, rr
        if np.sqrt(rr) < 1e-10 * np.sqrt(b @ b):
            break
        d = r + rr / last * d
    return p.sum() * spacing**2


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("shape", choices=["square", "disk"])
    parser.add_argument("size_mm", type=float, help="the square's side or the disk's radius (mm)")
    parser.add_argument("--period-mm", type=float, default=64.0)
    args = parser.parse_args()
    forces = []
    for spacing in (0.2e-3, 0.1e-3, 0.05e-3):
        f = punch_force(args.shape, args.size_mm * 1e-3, spacing, args.period_mm * 1e-3)
        forces.append(f)
        print(f"spacing {spacing * 1e3:.2f} mm: {f:.4f} N", flush=True)
    print(f"extrapolated: {2 * forces[-1] - forces[-2]:.4f} N")


if __name__ == "__main__":
    main()
