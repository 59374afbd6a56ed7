"""Times OpenCV's filter2D on the image `benches/lowrank.rs` filters: a 1280x720 RGBA float32
image convolved with a disc kernel of 17, 33 and 65 pixels and a 65-pixel hexagon, and its three
colour channels with the hexagon (an opaque image, which our filters take in three channels; filter2D
switches to a DFT for large kernels), with clamp-to-edge borders like ours.

Not part of the test suite; run by hand for the README's comparison:
    pip install opencv-python-headless numpy && python3 benches/external/opencv_filter.py
Prints the median wall-clock milliseconds of 9 runs, with OpenCV's own thread count (all cores).
"""

import cv2
import numpy as np

from kernels import disc_kernel, median_ms


def hexagon_kernel(n: int, ss: int = 8) -> np.ndarray:
    """A regular hexagon (vertices up and down) of circumradius n/2, summing to 1."""
    r = n / 2.0
    offs = (np.arange(ss) + 0.5) / ss
    xs = (np.arange(n)[:, None] + offs[None, :]).ravel() - r
    x, y = np.abs(xs[None, :]), np.abs(xs[:, None])
    inside = (x <= r * np.sqrt(3) / 2) & (x / np.sqrt(3) + y <= r)
    k = inside.reshape(n, ss, n, ss).mean(axis=(1, 3)).astype(np.float32)
    return k / k.sum()


def main() -> None:
    rng = np.random.default_rng(0)
    img = rng.random((720, 1280, 4), dtype=np.float32)
    for name, k in [
        ("disc k17", disc_kernel(17)),
        ("disc k33", disc_kernel(33)),
        ("disc k65", disc_kernel(65)),
        ("hexagon k65", hexagon_kernel(65)),
    ]:
        ms = median_ms(lambda: cv2.filter2D(img, -1, k, borderType=cv2.BORDER_REPLICATE), runs=9)
        print(f"{name} 1280x720 RGBA f32: cv2.filter2D {ms:.1f} ms ({cv2.getNumThreads()} threads)")
    # Three channels, as our filters take an opaque image (its alpha is the kernel's sum).
    rgb = np.ascontiguousarray(img[:, :, :3])
    k = hexagon_kernel(65)
    ms = median_ms(lambda: cv2.filter2D(rgb, -1, k, borderType=cv2.BORDER_REPLICATE), runs=9)
    print(f"hexagon k65 1280x720 RGB f32: cv2.filter2D {ms:.1f} ms ({cv2.getNumThreads()} threads)")


if __name__ == "__main__":
    main()
