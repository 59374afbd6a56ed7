"""OpenEXR's side of the EXR read/write comparison (issue #27): the OpenEXR C++ library,
through its Python binding (`pip install OpenEXR`), on the same files as `defocus blur
--timings`, interleaved with it.

Reads a colour EXR and a depth EXR (the time `io/read` covers: both files decoded to float
pixels), then writes the colour as RGBA float32 with no compression, ZIP and PIZ (the time
`io/write` covers), both as it is and followed by an fsync of the file, the guarantee our
writes give before their rename. Prints the least of `--runs` runs of each, and the same
for `defocus blur --method hammon --timings json --exr-compression C` on the same files, with
and without `--no-fsync`.

    python benches/external/openexr_io.py COLOR.exr DEPTH.exr [--runs 5] [--binary target/release/defocus]

Make the files with, for example:

    defocus render --scene railing --method pinhole --width 1920 --height 1080 \\
        --out c.exr --depth-out z.exr --exr-compression zip
"""

import argparse
import json
import os
import subprocess
import tempfile
import time

import numpy as np
import OpenEXR


def read_both(color, depth):
    with OpenEXR.File(color) as c:
        rgba = {k: np.asarray(v.pixels, dtype=np.float32) for k, v in c.channels().items()}
    with OpenEXR.File(depth) as d:
        z = {k: np.asarray(v.pixels, dtype=np.float32) for k, v in d.channels().items()}
    return rgba, z


def write(rgba, path, compression):
    header = {"compression": compression, "type": OpenEXR.scanlineimage}
    channels = {"RGBA": np.ascontiguousarray(rgba, dtype=np.float32)}
    with OpenEXR.File(header, channels) as f:
        f.write(path)


def flush(path):
    """Waits until the file's bytes are on the disk, as our write does before its rename."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def ours(binary, color, depth, out, compression, fsync=True):
    done = subprocess.run(
        [binary, "blur", "--color", color, "--depth", depth, "--method", "hammon",
         "--focus", "2.5", "--out", out, "--timings", "json", "--exr-compression", compression]
        + ([] if fsync else ["--no-fsync"]),
        check=True, capture_output=True, text=True)
    passes = {p["name"]: p["ms"] for p in json.loads(done.stdout)["passes"]}
    return passes["io/read"], passes["io/write"]


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("color")
    p.add_argument("depth")
    p.add_argument("--runs", type=int, default=5)
    p.add_argument("--binary", default=os.path.join("target", "release", "defocus"))
    a = p.parse_args()
    best = {}

    def keep(name, ms):
        best[name] = min(best.get(name, float("inf")), ms)

    with tempfile.TemporaryDirectory() as tmp:
        rgba = None
        for _ in range(a.runs):
            t = time.perf_counter()
            channels, _ = read_both(a.color, a.depth)
            keep("OpenEXR read colour + depth", 1e3 * (time.perf_counter() - t))
            rgba = channels.get("RGBA")
            if rgba is None:
                rgba = np.stack([channels[k] for k in ("R", "G", "B", "A")], axis=-1)
            for name, comp in (("none", OpenEXR.NO_COMPRESSION), ("zip", OpenEXR.ZIP_COMPRESSION),
                               ("piz", OpenEXR.PIZ_COMPRESSION)):
                path = os.path.join(tmp, f"o-{name}.exr")
                t = time.perf_counter()
                write(rgba, path, comp)
                keep(f"OpenEXR write RGBA, {name}", 1e3 * (time.perf_counter() - t))
                os.remove(path)
                t = time.perf_counter()
                write(rgba, path, comp)
                flush(path)
                keep(f"OpenEXR write RGBA, {name}, then fsync", 1e3 * (time.perf_counter() - t))
            for comp in ("none", "zip", "piz"):
                r, w = ours(a.binary, a.color, a.depth, os.path.join(tmp, "ours.exr"), comp)
                keep("defocus io/read colour + depth", r)
                keep(f"defocus io/write RGBA, {comp} (with fsync)", w)
                _, w = ours(a.binary, a.color, a.depth, os.path.join(tmp, "ours.exr"), comp,
                            fsync=False)
                keep(f"defocus io/write RGBA, {comp}, --no-fsync", w)
    for name, ms in best.items():
        print(f"{name:45s} {ms:8.1f} ms")


if __name__ == "__main__":
    main()
