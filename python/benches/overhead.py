"""What the Python shell costs, measured.

1. A 1280x720 `lowrank` blur through `defocus.blur` (NumPy in, NumPy out): the call's wall
   time against the wall time of the Rust library call inside it (`timings=True`:
   `method_ms`). The difference is what Python adds: reading the arrays, checking the depth,
   making the lens, and the array out. The command line's compute passes on the same pixels
   (`defocus blur --timings json`, file reading and writing left out) are printed beside
   them.
2. A batch of 16 frames at 640x360 in one call (NxHxWxC, run in parallel in Rust with the GIL
   released) against the same 16 frames one call at a time, on all cores and on one
   (`RAYON_NUM_THREADS=1`, in a child process).

Least of `--runs` runs, interleaved. Run from the repository root after building the binary
and installing the package:

    cargo build --release && pip install ./python
    python python/benches/overhead.py [--runs 9] [--binary target/release/defocus]
"""

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time

import numpy as np

import defocus

LENS = dict(focus=2.5, fstop=1.4, focal_length=50.0)


def cli_compute_ms(binary, color_path, depth_path, out_path):
    args = [binary, "blur", "--color", color_path, "--depth", depth_path, "--method", "lowrank",
            "--focus", str(LENS["focus"]), "--fstop", str(LENS["fstop"]),
            "--focal-length", str(LENS["focal_length"]), "--out", out_path, "--timings", "json"]
    done = subprocess.run(args, check=True, capture_output=True, text=True)
    passes = json.loads(done.stdout)["passes"]
    return sum(p["ms"] for p in passes if not p["name"].startswith("io/"))


def batch_frames():
    color, depth = defocus.render("railing", method="pinhole", width=640, height=360,
                                  return_depth=True)
    rng = np.random.default_rng(0)
    images = np.stack([(color * rng.uniform(0.5, 1.5)).astype(np.float32) for _ in range(16)])
    return images, np.stack([depth] * 16)


def one_at_a_time_ms(images, depths):
    t = time.perf_counter()
    for i in range(len(images)):
        defocus.blur(images[i], depths[i], method="lowrank", **LENS)
    return 1e3 * (time.perf_counter() - t)


def batched_ms(images, depths):
    t = time.perf_counter()
    defocus.blur(images, depths, method="lowrank", **LENS)
    return 1e3 * (time.perf_counter() - t)


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=9)
    parser.add_argument("--binary", default=os.path.join("target", "release", "defocus"))
    parser.add_argument("--one-core", action="store_true", help=argparse.SUPPRESS)
    a = parser.parse_args()

    if a.one_core:  # the child process of part 2, with RAYON_NUM_THREADS=1
        images, depths = batch_frames()
        print(min(one_at_a_time_ms(images, depths) for _ in range(a.runs)))
        return

    color, depth = defocus.render("railing", method="pinhole", width=1280, height=720,
                                  return_depth=True)
    calls, passes, overheads, cli = [], [], [], []
    with tempfile.TemporaryDirectory() as tmp:
        paths = [os.path.join(tmp, n) for n in ("color.exr", "depth.exr", "out.exr")]
        # The same pixels both ways: the binary renders the pinhole frame rendered above.
        subprocess.run([a.binary, "render", "--scene", "railing", "--method", "pinhole",
                        "--width", "1280", "--height", "720", "--out", paths[0],
                        "--depth-out", paths[1], "--quiet"], check=True)
        for _ in range(a.runs):
            t = time.perf_counter()
            _, timings = defocus.blur(color, depth, method="lowrank", timings=True, **LENS)
            call = 1e3 * (time.perf_counter() - t)
            inside = timings["method_ms"]
            calls.append(call)
            passes.append(inside)
            overheads.append(call - inside)
            cli.append(cli_compute_ms(a.binary, *paths))
    added = statistics.median(overheads)
    print(f"1280x720 lowrank through Python: call {min(calls):.1f} ms (least), the Rust call in it "
          f"{min(passes):.1f} ms; Python adds {added:.1f} ms (median), "
          f"{100 * added / statistics.median(passes):.1f}% of the Rust call; "
          f"the command line's passes {min(cli):.1f} ms (least)")

    images, depths = batch_frames()
    sequential = min(one_at_a_time_ms(images, depths) for _ in range(a.runs))
    batch = min(batched_ms(images, depths) for _ in range(a.runs))
    child = subprocess.run([sys.executable, __file__, "--one-core", "--runs", str(a.runs)],
                           env=dict(os.environ, RAYON_NUM_THREADS="1"), check=True,
                           capture_output=True, text=True)
    one_core = float(child.stdout)
    print(f"16 x 640x360 lowrank on {os.cpu_count()} cores: one call at a time {sequential:.0f} ms "
          f"(one core: {one_core:.0f} ms), one batch {batch:.0f} ms: "
          f"x{sequential / batch:.2f} the throughput of one call at a time on all cores, "
          f"x{one_core / batch:.2f} on one core")


if __name__ == "__main__":
    main()
