"""PFM files (the command line's float format) read and written with NumPy, for the tests."""

import numpy as np


def read_pfm(path):
    with open(path, "rb") as f:
        kind = f.readline().strip()
        w, h = map(int, f.readline().split())
        scale = float(f.readline())
        channels = 3 if kind == b"PF" else 1
        data = np.frombuffer(f.read(), dtype="<f4" if scale < 0 else ">f4")
    image = data.reshape(h, w, channels) if channels == 3 else data.reshape(h, w)
    return image[::-1]  # PFM rows run bottom to top


def write_pfm(path, image):
    image = np.ascontiguousarray(image[::-1], dtype="<f4")
    kind = b"PF" if image.ndim == 3 else b"Pf"
    with open(path, "wb") as f:
        f.write(kind + b"\n%d %d\n-1.0\n" % (image.shape[1], image.shape[0]))
        f.write(image.tobytes())
