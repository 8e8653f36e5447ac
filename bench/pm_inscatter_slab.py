"""How well do per-cell angular models hold the light a cloud scatters towards the camera?

A Monte Carlo experiment behind the photon map's view-dependent words (BENCHMARKS.md, "In-
scattering towards the camera"). A homogeneous slab of optical thickness TAU (HG g = 0.857,
albedo 1) is lit by a collimated sun at the held-out stratus's bench geometry (sun direction
(0.25, 0.5, 1), camera direction (0, 1.25, 3.45), slab normal +y: front-lit, 14° between
them). Photons are traced; at every collision after the first scattering (the photon map's
cache: orders >= 1) the incoming direction is recorded by depth. For each depth layer the
exact in-scattered radiance towards the camera, sum of p(d . w_cam), is compared with what
angular models reconstruct from the same photons:
  - two flux lobes (orders < 4 and >= 4; Nimbus' lobes), one flux lobe (Elek Appendix C),
  - HG lobe + isotropic part fitted to the first two moments,
  - spherical harmonics truncated at degree L (convolved with HG: coefficient l times g^l).

Usage: training/.venv/bin/python bench/pm_inscatter_slab.py [TAU] [PHOTONS]
"""

import sys

import numpy as np
from numpy.polynomial import legendre

G = 0.857


def hg(g, mu):
    return (1 - g * g) / (4 * np.pi * (1 + g * g - 2 * g * mu) ** 1.5)


def hg_sample(g, u):
    s = (1 - g * g) / (1 - g + 2 * g * u)
    return (1 + g * g - s * s) / (2 * g)


def rotate(d, mu, phi):
    a = np.where(np.abs(d[:, 0:1]) < 0.9, np.array([[1.0, 0, 0]]), np.array([[0, 1.0, 0]]))
    t = np.cross(d, a)
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    b = np.cross(d, t)
    s = np.sqrt(np.maximum(0, 1 - mu * mu))[:, None]
    return mu[:, None] * d + s * (np.cos(phi)[:, None] * t + np.sin(phi)[:, None] * b)


def trace(tau, n, sun, edges, rng):
    """Incoming directions and scattering orders of the collisions of order >= 1, per layer."""
    y = np.full(n, tau)
    d = np.tile(-sun, (n, 1))
    order = np.zeros(n, int)
    alive = np.ones(n, bool)
    layers = [[] for _ in range(len(edges) - 1)]
    while alive.any():
        idx = np.nonzero(alive)[0]
        ynew = y[idx] + d[idx, 1] * -np.log(1 - rng.random(idx.size))
        out = (ynew < 0) | (ynew > tau)
        alive[idx[out]] = False
        idx = idx[~out]
        y[idx] = ynew[~out]
        layer = np.clip(np.searchsorted(edges, tau - y[idx], side="right") - 1, 0, len(layers) - 1)
        scattered = order[idx] >= 1
        for k in range(len(layers)):
            s = scattered & (layer == k)
            if s.any():
                layers[k].append(np.column_stack([d[idx[s]], order[idx[s]]]))
        mu = hg_sample(G, rng.random(idx.size))
        d[idx] = rotate(d[idx], mu, 2 * np.pi * rng.random(idx.size))
        order[idx] += 1
        alive[idx[order[idx] > 300]] = False
    return layers


def lobe(dirs, cam):
    """One HG lobe along the mean direction, g' = its length (the flux lobe)."""
    if len(dirs) == 0:
        return 0.0
    m = dirs.mean(0)
    gl = min(np.linalg.norm(m), 0.999)
    return len(dirs) * hg(G * gl, (m / max(np.linalg.norm(m), 1e-9)) @ cam)


def lobe_iso(dirs, cam):
    """HG lobe + isotropic part with the first two moments about the mean direction."""
    if len(dirs) == 0:
        return 0.0
    m = dirs.mean(0)
    m1 = min(np.linalg.norm(m), 0.999)
    axis = m / max(np.linalg.norm(m), 1e-9)
    c = dirs @ axis
    p2 = np.mean(1.5 * c * c - 0.5)
    if p2 <= m1 * m1 or m1 < 1e-6:
        gf, f = m1, 1.0
    else:
        gf = min(p2 / m1, 0.999)
        f = m1 / gf
    return len(dirs) * (f * hg(G * gf, axis @ cam) + (1 - f) / (4 * np.pi))


def sh(dirs, cam, degree):
    mu = dirs @ cam
    total = 0.0
    for l in range(degree + 1):
        c = np.zeros(l + 1)
        c[l] = 1
        total += G**l * (2 * l + 1) / (4 * np.pi) * legendre.legval(mu, c).sum()
    return total


def main():
    tau = float(sys.argv[1]) if len(sys.argv) > 1 else 4.0
    n = int(sys.argv[2]) if len(sys.argv) > 2 else 400_000
    sun = np.array([0.25, 0.5, 1.0])
    sun /= np.linalg.norm(sun)
    cam = np.array([0.0, 1.25, 3.45])
    cam /= np.linalg.norm(cam)
    edges = np.linspace(0, tau, 9) if tau <= 8 else np.array([0, 0.5, 1, 1.5, 2, 3, 4, 6, tau])
    layers = trace(tau, n, sun, edges, np.random.default_rng(1))
    print(f"slab tau {tau}, {n} photons; model / exact in-scattering towards the camera")
    print("depth      two lobes  one lobe  lobe+iso   SH 2    SH 4    SH 8")
    for k, rows in enumerate(layers):
        if not rows:
            continue
        a = np.concatenate(rows)
        dirs, order = a[:, :3], a[:, 3]
        exact = hg(G, dirs @ cam).sum()
        two = lobe(dirs[order < 4], cam) + lobe(dirs[order >= 4], cam)
        vals = [two, lobe(dirs, cam), lobe_iso(dirs, cam)] + [sh(dirs, cam, L) for L in (2, 4, 8)]
        print(f"{edges[k]:4.1f}-{edges[k + 1]:4.1f}  " + "  ".join(f"{v / exact:7.3f}" for v in vals))


if __name__ == "__main__":
    main()
