"""Build a defocus data set from many (image, depth) pairs with Dask, on one machine or many.

Each pair is a ``.npz`` file holding ``image`` (HxWx3 float32 linear, or uint8 sRGB) and
``depth`` (HxW, metres). Each task blurs one pair with a lens drawn from a seed of its own (the
pair's name), so the data set is the same however the tasks are spread over workers, and
writes ``OUT/<name>.npz`` holding ``blurred``, ``image``, ``depth``, ``focus`` and ``fstop``.
An output is written to a temporary name and renamed, so it exists whole or not at all, and a
rerun skips the pairs whose output exists: an interrupted run resumes.

On one machine (a ``LocalCluster`` of worker processes)::

    python dask_dataset.py pairs/ out/ --workers 4

On a cluster, give the scheduler's address instead (``--scheduler tcp://host:8786``), started
by ``dask-jobqueue`` (SLURM, PBS, ...), the Dask Helm chart or operator on Kubernetes, or
``dask scheduler`` / ``dask worker`` by hand. Every worker needs ``pip install defocus`` and
the input and output folders on a shared file system (or paths that fsspec reads, such as
s3://, with the reading and writing below changed to use it). The code is the same: Dask does
the scheduling.
"""

from __future__ import annotations

import argparse
import hashlib
import os
import tempfile
from pathlib import Path
from typing import Dict, List, Sequence

import numpy as np

import defocus


def lens_for(name: str, seed: int = 0) -> Dict[str, float]:
    """The lens of one pair, drawn from a seed of its own: the focus uniform in dioptres over
    0.5-10 m and the f-number uniform in stops over f/1.4-f/4 (as ``RandomDefocus`` draws)."""
    digest = hashlib.sha256(f"{seed}:{name}".encode()).digest()
    rng = np.random.default_rng(int.from_bytes(digest[:8], "little"))
    dioptres = rng.uniform(1 / 10.0, 1 / 0.5)
    stops = rng.uniform(2 * np.log2(1.4), 2 * np.log2(4.0))
    return {"focus": float(1.0 / dioptres), "fstop": float(2 ** (stops / 2))}


def blur_pair(pair: str, out_dir: str, method: str = "lowrank", seed: int = 0) -> str:
    """Blurs one pair into ``out_dir`` unless its output exists; returns ``"written"`` or
    ``"skipped"``. Runs on a worker."""
    name = Path(pair).stem
    target = Path(out_dir) / f"{name}.npz"
    if target.exists():
        return "skipped"
    with np.load(pair) as data:
        image, depth = data["image"], data["depth"]
    lens = lens_for(name, seed)
    blurred = defocus.blur(image, depth, method, **lens)
    fd, tmp = tempfile.mkstemp(prefix=f".{name}.", suffix=".npz", dir=out_dir)
    try:
        with os.fdopen(fd, "wb") as f:
            np.savez(f, blurred=blurred, image=image, depth=depth, **lens)
        os.replace(tmp, target)
    except BaseException:
        os.unlink(tmp)
        raise
    return "written"


def build(pairs: Sequence[str], out_dir: str, client, method: str = "lowrank",
          seed: int = 0) -> List[str]:
    """Blurs every pair on the Dask ``client``'s workers; the outcome of each, in order."""
    import dask.bag as db

    os.makedirs(out_dir, exist_ok=True)
    if __name__ != "__main__":
        # Imported as a module: the workers import it by name too, so they get this file.
        # (Run as a script, its functions travel by value instead.)
        client.upload_file(__file__)
    bag = db.from_sequence(list(pairs), npartitions=max(1, min(len(pairs), 64)))
    return client.compute(bag.map(blur_pair, out_dir=out_dir, method=method, seed=seed)).result()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("pairs", help="folder of .npz pairs (image, depth)")
    parser.add_argument("out", help="output folder")
    parser.add_argument("--method", default="lowrank")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--workers", type=int, default=2, help="local worker processes")
    parser.add_argument("--scheduler", help="address of a running Dask scheduler")
    args = parser.parse_args()

    from dask.distributed import Client, LocalCluster

    pairs = sorted(str(p) for p in Path(args.pairs).glob("*.npz"))
    if args.scheduler:
        client = Client(args.scheduler)
    else:
        # One thread a worker: each call already uses every core of its machine with rayon.
        client = Client(LocalCluster(n_workers=args.workers, threads_per_worker=1,
                                     processes=True))
    with client:
        outcomes = build(pairs, args.out, client, args.method, args.seed)
    print(f"{outcomes.count('written')} written, {outcomes.count('skipped')} skipped")


if __name__ == "__main__":
    main()
