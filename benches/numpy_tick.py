"""The per-tick Eq. 11 computation as a researcher would write it in NumPy: the baseline the
Rust tick engine is compared with. Not part of the build.

    pip install numpy && python3 benches/numpy_tick.py

Same sizes as the engine's bench (N = 5 groups, M = 3 primitives, D = 6, K = 15, 10 s at
500 Hz): each tick takes the active groups' marginals (precomputed, as the engine does),
inverts each covariance, sums the a_j-weighted precisions and solves for the blended mean.
"""
import time

import numpy as np

rng = np.random.default_rng(1)
N, M, D, K = 5, 3, 6, 15
TICKS = 5001

# Precomputed marginals per group, primitive and tick (random SPD covariances stand in for the
# ProMP marginals: the arithmetic per tick is what is timed).
means = rng.uniform(0.2, 0.8, size=(N, M, TICKS, D))
A = rng.normal(size=(N, M, D, D)) * 0.05
covs = np.einsum("nmij,nmkj->nmik", A, A) + 1e-3 * np.eye(D)

t_cond = np.array([1.0, 3.0, 5.0, 7.0, 9.0])
Q = np.array([0, 1, 2, 1, 0])
floor, window, fade = 1e-3, 0.2, 0.3


def activations(t):
    # b: the window's group, or the two handing over (cosine) between windows.
    b = np.zeros(N)
    half = window / 2
    for i in range(N - 1):
        end, start = t_cond[i] + half, t_cond[i + 1] - half
        if t <= end:
            b[i] = 1
            break
        if t < start:
            f = 0.5 - 0.5 * np.cos(np.pi * (t - end) / (start - end))
            b[i], b[i + 1] = 1 - f, f
            break
    else:
        b[N - 1] = 1
    a = np.full(M, floor)
    owner = np.argmin(np.abs(t_cond - t))
    a[Q[owner]] = 1.0
    return a, b


def tick(k):
    t = k / 500.0
    a, b = activations(t)
    v = np.zeros(D)
    for i in np.nonzero(b)[0]:
        lam = np.zeros((D, D))
        eta = np.zeros(D)
        for j in range(M):
            s = covs[i, j] + 1e-6 * np.eye(D)
            p = np.linalg.inv(s)
            lam += a[j] * p
            eta += a[j] * p @ means[i, j, k]
        v += b[i] * np.linalg.solve(lam, eta)
    return v


samples = []
for k in range(20000):
    t0 = time.perf_counter_ns()
    tick(k % TICKS)
    samples.append(time.perf_counter_ns() - t0)
samples.sort()
q = lambda p: samples[int(round((len(samples) - 1) * p))] / 1e3
print(f"NumPy Eq. 11 tick: p50 {q(0.5):.1f} µs  p99 {q(0.99):.1f} µs  (numpy {np.__version__})")
