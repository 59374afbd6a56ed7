"""Shared by the comparison scripts: the disc kernel `benches/lowrank.rs` uses, and a median timer."""

import time

import numpy as np


def disc_kernel(n: int, ss: int = 8) -> np.ndarray:
    """A disc of diameter n pixels, ss x ss samples per pixel, summing to 1."""
    r = n / 2.0
    offs = (np.arange(ss) + 0.5) / ss
    xs = (np.arange(n)[:, None] + offs[None, :]).ravel() - r
    inside = (xs[None, :] ** 2 + xs[:, None] ** 2) <= r * r
    k = inside.reshape(n, ss, n, ss).mean(axis=(1, 3)).astype(np.float32)
    return k / k.sum()


def median_ms(f, runs: int = 5) -> float:
    times = []
    for _ in range(runs):
        t = time.perf_counter()
        f()
        times.append((time.perf_counter() - t) * 1e3)
    return float(np.median(times))
