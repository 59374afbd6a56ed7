"""The Dask example (``python/examples/dask_dataset.py``) on a LocalCluster of two worker
processes: every pair blurred once, as ``defocus.blur`` blurs it, and a rerun skipping what
exists. Skipped, with the reason, where dask.distributed is not installed."""

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

import defocus

dask = pytest.importorskip("dask", reason="dask is not installed (pip install 'dask[distributed]')")
distributed = pytest.importorskip(
    "distributed", reason="dask.distributed is not installed (pip install 'dask[distributed]')"
)

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "dask_dataset.py"


def load_example():
    spec = importlib.util.spec_from_file_location("dask_dataset", EXAMPLE)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def make_pairs(folder: Path, n: int):
    folder.mkdir()
    rng = np.random.default_rng(5)
    paths = []
    for i in range(n):
        image = rng.uniform(0.0, 1.0, (48, 64, 3)).astype(np.float32)
        depth = np.where(np.arange(64)[None, :] < 20 + 4 * i, 0.8, 6.0).astype(np.float32)
        depth = np.repeat(depth, 48, axis=0)
        path = folder / f"pair{i:03d}.npz"
        np.savez(path, image=image, depth=depth)
        paths.append(str(path))
    return paths


def test_dask_builds_the_data_set_on_two_workers_and_a_rerun_skips(tmp_path):
    example = load_example()
    pairs = make_pairs(tmp_path / "pairs", 6)
    out = tmp_path / "out"
    with distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None
    ) as cluster, distributed.Client(cluster) as client:
        assert len(client.scheduler_info()["workers"]) == 2
        assert example.build(pairs, str(out), client) == ["written"] * 6
        for path in pairs:
            name = Path(path).stem
            got = np.load(out / f"{name}.npz")
            lens = example.lens_for(name)
            with np.load(path) as pair:
                want = defocus.blur(pair["image"], pair["depth"], "lowrank", **lens)
            np.testing.assert_array_equal(got["blurred"], want)
            assert float(got["focus"]) == lens["focus"] and float(got["fstop"]) == lens["fstop"]
        stamps = {p.name: p.stat().st_mtime_ns for p in out.iterdir()}
        assert example.build(pairs, str(out), client) == ["skipped"] * 6
        assert {p.name: p.stat().st_mtime_ns for p in out.iterdir()} == stamps
        # An output lost (or never finished) is made again by the next run, alone.
        (out / "pair003.npz").unlink()
        outcomes = example.build(pairs, str(out), client)
        assert outcomes == ["skipped"] * 3 + ["written"] + ["skipped"] * 2
    assert sorted(p.name for p in out.iterdir()) == [f"pair{i:03d}.npz" for i in range(6)]
