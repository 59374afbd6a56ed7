"""``RandomDefocus``: a seeded, depth-aware lens-blur augmentation for training pipelines."""

from __future__ import annotations

from typing import Any, Dict, Optional, Sequence, Tuple, Union

import numpy as np


class RandomDefocus:
    """A lens-blur augmentation: blurs (image, depth) pairs with a random focus and f-number.

    Unlike a uniform disc or Gaussian blur, the blur follows the depth: what lies at the
    focus distance stays sharp, and the blur grows with the distance from it, in the
    aperture's shape. Each call draws the focus distance, the f-number and the aperture, then
    calls ``defocus.blur``. The draws come from ``numpy.random.default_rng(seed)``: the same
    seed gives the same sequence of blurs.

    Works on NumPy arrays and on torch tensors (through NumPy; a CxHxW tensor comes back
    CxHxW, on its device and in its dtype).

    Parameters
    ----------
    focus_range : tuple of (float, float) or None, default None
        ``(near, far)`` in metres, ``0 < near <= far``: the focus distance is drawn uniformly
        in 1/distance (dioptres) between them. ``None``: the depth of a random pixel of the
        image among those with a finite depth above 0, so that some surface of the image is
        in focus.
    fstop_range : tuple of (float, float), default (1.4, 8.0)
        ``(low, high)`` f-numbers, ``0 < low <= high``: the f-number is drawn uniformly in
        stops (in log N) between them. ``blur`` refuses f-numbers below 0.1.
    aperture : str or sequence of str, default "disc"
        An aperture as ``blur`` takes it (``"disc"``, ``"poly:6"``, ...), or a non-empty list
        of them, one drawn per call with equal chances.
    method : str, default "lowrank"
        The method of ``blur``.
    focal_length : float, default 50.0
        Focal length in millimetres.
    sensor_width : float, default 36.0
        Sensor width in millimetres (full frame is 36).
    depth_kind : str, default "depth"
        What the depth holds, as in ``blur``. With ``"inverse"`` or ``"disparity"`` the focus
        is drawn in metres (``depth_scale / value``); with ``"coc"`` the map gives every
        pixel's blur, and the drawn focus and f-number do not change the image.
    depth_scale : float, default 1.0
        Metres per depth unit, as in ``blur``.
    p : float, default 1.0
        The probability, 0 to 1, that a call blurs; otherwise the image comes back as it came
        in (the draws are still made, so the sequence does not depend on ``p``'s outcomes).
    seed : int or None, default None
        Seed of the draws; ``None``: fresh entropy from the operating system, a different
        sequence each time.
    **method_options
        The method's options, as ``blur`` takes them (``rank=3``), for every call.

    Attributes
    ----------
    last_params : dict
        The last call's draws, for labels such as a defocus map: ``"applied"`` (bool),
        ``"focus"`` (metres), ``"fstop"`` (float) and ``"aperture"`` (str). Empty before the
        first call.
    rng : numpy.random.Generator
        The generator the draws come from (``reseed`` replaces it).

    Raises
    ------
    ValueError
        ``focus_range`` not ``0 < near <= far``, ``fstop_range`` not ``0 < low <= high``,
        ``p`` outside 0 to 1, or an empty list of apertures.

    Examples
    --------
    A data set that makes defocus training pairs::

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
        """Starts a new stream of draws, from ``numpy.random.default_rng(seed)``.

        For example one per data-loader worker, whose copies of this object would otherwise
        draw the same sequence.

        Parameters
        ----------
        seed : int or None
            Seed of the draws; ``None``: fresh entropy from the operating system.
        """
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
        """Draws a focus, an f-number and an aperture, and blurs ``image`` with them.

        Parameters
        ----------
        image : numpy.ndarray or torch.Tensor
            HxWx3 or HxWx4, float32 linear light (alpha premultiplied) or uint8 sRGB, as
            ``blur`` takes it; a tensor may also be CxHxW.
        depth : numpy.ndarray or torch.Tensor
            HxW (a tensor may have axes of length 1, such as 1xHxW), of the kind
            ``depth_kind``; metres by default.

        Returns
        -------
        numpy.ndarray or torch.Tensor
            The blurred image as ``blur`` returns it (the same shape and channels; float32
            for float input, uint8 for uint8), or, for a tensor, a tensor in the input's
            layout, device and dtype. ``image`` itself when the draw skipped the blur
            (``p`` below 1). The draws are in ``last_params``.

        Raises
        ------
        ValueError
            What ``blur`` raises, or, without ``focus_range``, a depth with no finite value
            above 0 to focus on.
        """
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
