"""Times a good library's 2D filters on the image `benches/lowrank.rs` filters: a 1280x720 RGBA
float32 image convolved with a disc kernel of 17, 33 and 65 pixels, by direct convolution
(scipy.ndimage.convolve, per channel) and by FFT (scipy.signal.oaconvolve, overlap-add).

Not part of the test suite; run by hand for the README's comparison:
    pip install scipy && python3 benches/external/scipy_filter.py
Prints the median wall-clock milliseconds of 5 runs for each filter and kernel size.
"""

import numpy as np
from scipy import ndimage, signal

from kernels import disc_kernel, median_ms


def main() -> None:
    rng = np.random.default_rng(0)
    img = rng.random((720, 1280, 4), dtype=np.float32)
    for n in (17, 33, 65):
        k = disc_kernel(n)
        direct = median_ms(
            lambda: [ndimage.convolve(img[..., c], k, mode="nearest") for c in range(4)],
            runs=3 if n == 65 else 5,
        )
        fft = median_ms(lambda: signal.oaconvolve(img, k[:, :, None], mode="same", axes=(0, 1)))
        print(f"k{n} 1280x720 RGBA f32: ndimage.convolve {direct:.1f} ms, oaconvolve (FFT) {fft:.1f} ms")


if __name__ == "__main__":
    main()
