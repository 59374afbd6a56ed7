"""``RandomDefocus``: a seeded, depth-aware lens-blur augmentation for training pipelines."""

from __future__ import annotations

from typing import Any, Dict, Optional, Sequence, Tuple, Union

import numpy as np


class RandomDefocus:
    """Blurs an (image, depth) pair through a thin lens with a random focus and f-number.

    Unlike a uniform disc or Gaussian blur, the blur follows the depth: what lies at the
    focus distance stays sharp, and the blur grows with the distance from it, in the
    aperture's shape. Each call draws:

    - the focus distance, uniformly in 1/distance (dioptres) within ``focus_range`` metres,
      or, without a range, the depth at a random pixel of the image (so some surface of the
      image is in focus);
    - the f-number, uniformly in stops (log N) within ``fstop_range``;
    - the aperture, one of ``aperture`` when it is a list.

    The draws come from ``numpy.random.default_rng(seed)``: the same seed gives the same
    sequence of blurs. ``last_params`` holds the last call's draws (focus in metres, f-number,
    aperture, applied), for labels such as a defocus map.

    Works on NumPy arrays (HxWxC colour, float32 linear or uint8 sRGB, and HxW depth in
    metres) and on torch tensors, through NumPy: a CxHxW tensor comes back CxHxW, on its
    device and in its dtype.

    Example, a data loader that makes defocus training pairs::

        aug = defocus.RandomDefocus(fstop_range=(1.4, 4.0), seed=0)

        class Pairs(torch.utils.data.Dataset):
            def __getitem__(self, i):
                image, depth = load(i)                   # HxWx3 float32, HxW metres
                blurred = aug(image, depth)
                return blurred, image, aug.last_params["focus"]
    """

    def __init__(
        self,
        focus_range: Optional[Tuple[float, float]] = None,
        fstop_range: Tuple[float, float] = (1.4, 8.0),
        aperture: Union[str, Sequence[str]] = "disc",
        method: str = "lowrank",
        focal_length: float = 50.0,
        sensor_width: float = 36.0,
        depth_kind: str = "depth",
        depth_scale: float = 1.0,
        p: float = 1.0,
        seed: Optional[int] = None,
        **method_options: Any,
    ) -> None:
        if focus_range is not None:
            near, far = focus_range
            if not (0 < near <= far):
                raise ValueError(
                    f"focus_range {focus_range}: expected 0 < near <= far, in metres"
                )
        lo, hi = fstop_range
        if not (0 < lo <= hi):
            raise ValueError(f"fstop_range {fstop_range}: expected 0 < low <= high")
        if not (0.0 <= p <= 1.0):
            raise ValueError(f"p {p}: expected a probability from 0 to 1")
        self.focus_range = focus_range
        self.fstop_range = fstop_range
        self.apertures = [aperture] if isinstance(aperture, str) else list(aperture)
        if not self.apertures:
            raise ValueError("aperture: expected a spec or a non-empty list of specs")
        self.method = method
        self.focal_length = focal_length
        self.sensor_width = sensor_width
        self.depth_kind = depth_kind
        self.depth_scale = depth_scale
        self.p = p
        self.method_options = method_options
        self.rng = np.random.default_rng(seed)
        self.last_params: Dict[str, Any] = {}

    def reseed(self, seed: Optional[int]) -> None:
        """Starts a new stream of draws (for example one per data-loader worker, whose copies
        of this object would otherwise draw the same sequence)."""
        self.rng = np.random.default_rng(seed)

    def _metres(self, d: np.ndarray) -> np.ndarray:
        """The depth in metres, to pick a focus from (NaN where a CoC map has none)."""
        with np.errstate(divide="ignore", invalid="ignore"):
            if self.depth_kind in ("depth", "view", "radial"):
                return d * self.depth_scale
            if self.depth_kind in ("inverse", "disparity"):
                return self.depth_scale / d
        return np.full_like(d, 1.0)

    def _draw(self, depth: np.ndarray) -> Dict[str, Any]:
        rng = self.rng
        applied = bool(rng.random() < self.p)
        if self.focus_range is not None:
            near, far = self.focus_range
            focus = 1.0 / rng.uniform(1.0 / far, 1.0 / near)
        else:
            finite = depth[np.isfinite(depth) & (depth > 0)]
            if finite.size == 0:
                raise ValueError("depth: no finite positive depth to focus on")
            focus = float(finite[rng.integers(finite.size)])
        lo, hi = self.fstop_range
        fstop = float(np.exp(rng.uniform(np.log(lo), np.log(hi))))
        aperture = self.apertures[int(rng.integers(len(self.apertures)))]
        return {"applied": applied, "focus": float(focus), "fstop": fstop, "aperture": aperture}

    def __call__(self, image: Any, depth: Any) -> Any:
        from . import blur

        tensor = hasattr(image, "detach") and hasattr(image, "cpu")
        if tensor:
            like = image
            array = image.detach().cpu().numpy()
            d = depth.detach().cpu().numpy() if hasattr(depth, "detach") else np.asarray(depth)
            chw = array.ndim == 3 and array.shape[0] in (3, 4) and array.shape[-1] not in (3, 4)
            if chw:
                array = np.moveaxis(array, 0, -1)
            d = np.squeeze(d)
        else:
            array, d = np.asarray(image), np.asarray(depth)
        d = np.asarray(d, dtype=np.float32)
        params = self._draw(self._metres(d))
        self.last_params = params
        if not params["applied"]:
            return image
        out = blur(
            array,
            d,
            self.method,
            focus="auto" if self.depth_kind == "coc" else params["focus"],
            fstop=params["fstop"],
            focal_length=self.focal_length,
            sensor_width=self.sensor_width,
            aperture=params["aperture"],
            depth_kind=self.depth_kind,
            depth_scale=self.depth_scale,
            **self.method_options,
        )
        if tensor:
            import torch  # only when given a tensor

            if chw:
                out = np.moveaxis(out, -1, 0)
            return torch.from_numpy(np.ascontiguousarray(out)).to(device=like.device, dtype=like.dtype)
        return out
