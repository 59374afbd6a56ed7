"""Each method through Python gives the command line's pixels, to the bit: `defocus.render`
against `defocus render`, and `defocus.blur` against `defocus blur` on the same files (the
command line writes float PFM, read back here). Skipped, with the reason, where the `defocus`
binary has not been built (`cargo build`), or set DEFOCUS_CLI to its path."""

import os
import subprocess
from pathlib import Path

import numpy as np
import pytest

import defocus
from pfm import read_pfm, write_pfm

ROOT = Path(__file__).resolve().parents[2]


def find_cli():
    if os.environ.get("DEFOCUS_CLI"):
        return os.environ["DEFOCUS_CLI"]
    built = [ROOT / "target" / p / "defocus" for p in ("release", "debug")]
    built = [p for p in built if p.is_file()]
    # The newest build: the one made from the source under test.
    return str(max(built, key=lambda p: p.stat().st_mtime)) if built else None


CLI = find_cli()
pytestmark = pytest.mark.skipif(
    CLI is None, reason="the defocus binary is not built (cargo build), nor DEFOCUS_CLI set"
)

SIZE = dict(width=64, height=36)
LENS = dict(focus=2.0, fstop=1.4, focal_length=50.0)
SAMPLES = {"reference": 4, "pinhole": 4, "multiview": 4}


def cli(*args):
    done = subprocess.run([CLI, *map(str, args), "--quiet"], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr


def lens_flags():
    return ["--focus", LENS["focus"], "--fstop", LENS["fstop"],
            "--focal-length", LENS["focal_length"]]


@pytest.mark.parametrize("method", [m["id"] for m in defocus.methods()])
def test_render_through_python_is_the_command_lines(method, tmp_path):
    samples = SAMPLES.get(method)
    out = tmp_path / "out.pfm"
    flags = ["render", "--scene", "glass", "--method", method, "--width", SIZE["width"],
             "--height", SIZE["height"], *lens_flags(), "--out", out]
    if samples:
        flags += ["--samples", samples]
    cli(*flags)
    ours = defocus.render("glass", method=method, samples=samples, **SIZE, **LENS)
    np.testing.assert_array_equal(ours[..., :3], read_pfm(out))


@pytest.mark.parametrize(
    "method", [m["id"] for m in defocus.methods() if not m["needs_scene"]]
)
def test_blur_through_python_is_the_command_lines(method, tmp_path):
    color, depth = defocus.render("glass", method="pinhole", samples=4, return_depth=True,
                                  **SIZE, **LENS)
    color = np.ascontiguousarray(color[..., :3])
    write_pfm(tmp_path / "color.pfm", color)
    write_pfm(tmp_path / "depth.pfm", depth)
    out = tmp_path / "out.pfm"
    cli("blur", "--color", tmp_path / "color.pfm", "--depth", tmp_path / "depth.pfm",
        "--method", method, *lens_flags(), "--out", out)
    ours = defocus.blur(color, depth, method, **LENS)
    np.testing.assert_array_equal(ours, read_pfm(out))
