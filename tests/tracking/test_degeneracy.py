"""Shape degeneracy (service.tracking.geometry.degeneracy): a body of revolution turned about its own axis leaves
its point-to-plane residuals unchanged (one weak direction); three faces of a box leave none."""

import numpy as np

from service.tracking.geometry import degeneracy


def _cylinder(rng, n=3000, r=0.035, half=0.1):
    """Closed cylinder along x: side and two caps."""
    th = rng.uniform(-np.pi, np.pi, n)
    x = rng.uniform(-half, half, n)
    P = np.c_[x, r * np.cos(th), r * np.sin(th)]
    N = np.c_[np.zeros(n), np.cos(th), np.sin(th)]
    nc = n // 8
    rr, tc = r * np.sqrt(rng.uniform(0, 1, nc)), rng.uniform(-np.pi, np.pi, nc)
    for sgn in (-1.0, 1.0):
        P = np.r_[P, np.c_[np.full(nc, sgn * half), rr * np.cos(tc), rr * np.sin(tc)]]
        N = np.r_[N, np.tile([sgn, 0.0, 0.0], (nc, 1))]
    return P, N


def _box(rng, n=3000, h=0.05):
    P, N = [], []
    for ax in range(3):
        for sgn in (-1.0, 1.0):
            q = rng.uniform(-h, h, (n // 6, 3))
            q[:, ax] = sgn * h
            nn = np.zeros((n // 6, 3))
            nn[:, ax] = sgn
            P.append(q)
            N.append(nn)
    return np.concatenate(P), np.concatenate(N)


def _visible(P, N, cam):
    return ((cam - P) * N).sum(1) > 0


def test_degeneracy_eigenvalues():
    rng = np.random.default_rng(0)
    P, N = _cylinder(rng)
    vis = _visible(P, N, np.array([0.3, 0.0, 0.5]))  # side and one cap
    lam = degeneracy(P[vis], N[vis])
    assert lam[0] < 1e-6 and lam[1] > 0.02, lam  # exactly one weak direction: the roll about the axis
    P, N = _box(rng)
    vis = _visible(P, N, np.array([0.4, 0.3, 0.5]))
    assert degeneracy(P[vis], N[vis])[0] > 0.05  # three faces: nothing weak
