"""defocus: physically based, depth-aware lens blur (depth of field) on the CPU.

The Python face of the `defocus` Rust library and command line: the same thin-lens model, the
same methods and the same option names and units, with NumPy arrays in and out.

Units: distances in metres, focal length and sensor width in millimetres (full frame is 36 mm
wide), blur radii in pixels. Colour is either float32 linear light (alpha, if any,
premultiplied, as in OpenEXR) or uint8 sRGB (decoded to linear light before the blur and
encoded back after it, as the command line does with PNG). Depth is view-axis distance in
metres unless ``depth_kind`` says otherwise.

Example::

    import numpy as np, defocus
    color, depth = defocus.render("railing", method="pinhole", width=640, height=360,
                                  return_depth=True)
    out = defocus.blur(color, depth, method="lowrank", focus=2.5, fstop=1.4)
    print(defocus.compare(out, defocus.render("railing", width=640, height=360)))

Batches: a leading axis N on colour (NxHxWxC) and depth (NxHxW) blurs N images in parallel,
with the GIL released. Bad arguments raise ``ValueError``, unreadable files ``OSError``, with
the command line's messages.
"""

from __future__ import annotations

import json
import os
from typing import Any, Dict, List, Optional, Sequence, Tuple, Union

import numpy as np

from . import _defocus
from ._augment import RandomDefocus

__all__ = [
    "blur",
    "render",
    "compare",
    "report",
    "blur_sequence",
    "methods",
    "scenes",
    "RandomDefocus",
    "__version__",
]

__version__: str = _defocus.__version__

Focus = Union[float, str, None]


def _flags(options: Dict[str, Any]) -> List[str]:
    """Method keyword arguments as the command line's flags (``rank=3`` -> ``--rank=3``)."""
    flags: List[str] = []
    for key, value in options.items():
        flag = "--" + key.replace("_", "-")
        if value is None or value is False:
            continue
        if value is True:
            flags.append(flag)
            continue
        if isinstance(value, (tuple, list)):
            value = ",".join(str(v) for v in value)
        flags.append(f"{flag}={value}")
    return flags


def _as_color(array: Any, name: str) -> np.ndarray:
    """A colour array as the native module reads it: C-contiguous float32 or uint8."""
    a = np.asarray(array)
    if a.dtype == np.uint8:
        return np.ascontiguousarray(a)
    if a.dtype.kind == "f":
        return np.ascontiguousarray(a, dtype=np.float32)
    raise ValueError(
        f"{name}: dtype {a.dtype}: expected float32 (linear light) or uint8 (sRGB)"
    )


def _as_depth(array: Any) -> np.ndarray:
    a = np.asarray(array)
    if a.dtype.kind not in "fiu":
        raise ValueError(f"depth: dtype {a.dtype}: expected numbers (metres)")
    return np.ascontiguousarray(a, dtype=np.float32)


def blur(
    color: Any,
    depth: Any,
    method: str = "lowrank",
    *,
    focus: Focus = "auto",
    focus_pixel: Optional[Tuple[int, int]] = None,
    fstop: float = 2.8,
    focal_length: float = 50.0,
    sensor_width: float = 36.0,
    aperture: str = "disc",
    depth_kind: str = "depth",
    depth_scale: float = 1.0,
    zero_depth_is_far: bool = False,
    seed: int = 0,
    highlights: Optional[Union[str, Sequence[float]]] = None,
    timings: bool = False,
    **method_options: Any,
) -> Any:
    """Depth of field for a colour image and its depth, through a thin lens.

    Args:
        color: HxWx3 or HxWx4 (or NxHxWxC for a batch); float32 linear light (alpha
            premultiplied) or uint8 sRGB (alpha straight).
        depth: HxW (or NxHxW) depth values, of the kind ``depth_kind``.
        method: a method that reads a frame: ``lowrank`` (McGraw, bokeh in the aperture's
            shape), ``hammon`` (GPU Gems 3 ch. 28), ``gaussian``, ``poisson`` or ``splat``.
            ``methods()`` lists them and their options.
        focus: focus distance in metres along the view axis, or ``"auto"``: the median depth of
            a small window at the image centre.
        focus_pixel: focus on the depth at pixel (column, row) instead.
        fstop: f-number N; the lens radius is focal_length / (2 N).
        focal_length: focal length in millimetres.
        sensor_width: sensor width in millimetres, spanning the image's width.
        aperture: ``disc``, ``poly:B[,rot=DEG][,curve=R]``, ``star[:N[,INNER]]``, ``heart``,
            ``ring[:INNER]`` or ``image:PATH``.
        depth_kind: ``depth`` (view-axis distance in metres), ``radial`` (distance from the eye
            along each pixel's ray), ``inverse`` or ``disparity`` (depth = depth_scale /
            value; 0 is infinitely far) or ``coc`` (signed CoC radius in pixels, negative in
            front of the focus, times depth_scale; focus is then not used).
        depth_scale: metres per depth unit (for inverse depth and disparity: the factor in
            depth = depth_scale / value).
        zero_depth_is_far: read a depth of exactly 0 as "no surface" (infinitely far).
        seed: seed of the methods that draw random taps.
        highlights: ``(threshold, gain[, knee])`` or ``"0.9,20"``: lift clipped highlights of
            low-dynamic-range input before the blur, in linear light (pixels whose brightest
            channel is above ``threshold`` are scaled by up to ``gain``, reached at
            ``threshold + knee``, by default 1), so the bokeh of lights clipped at 1.0 comes
            out bright.
        timings: also return where the time went: ``{"passes": [(name, ms), ...],
            "method_ms": ms}``, the method's passes as ``blur --timings`` prints them and the
            wall-clock time of the whole library call (passes and the work between them),
            in milliseconds, summed over a batch's images.
        **method_options: the method's options, named as the command line's flags with
            underscores (``rank=3``, ``max_coc=32``, ``no_mask=True``).

    Returns:
        The blurred image in the input's layout: same shape, dtype and channels. With
        ``timings=True``, ``(image, timings)``.
    """
    c = _as_color(color, "color")
    d = _as_depth(depth)
    if isinstance(focus, (int, float)) and not isinstance(focus, bool):
        focus = float(focus)
    return _defocus.blur(
        c,
        d,
        method,
        depth_kind,
        float(depth_scale),
        bool(zero_depth_is_far),
        focus,
        None if focus_pixel is None else (int(focus_pixel[0]), int(focus_pixel[1])),
        float(fstop),
        float(focal_length),
        float(sensor_width),
        aperture,
        int(seed),
        _flags(method_options),
        None
        if highlights is None
        else highlights
        if isinstance(highlights, str)
        else ",".join(str(float(v)) for v in highlights),
        bool(timings),
    )


def render(
    scene: Union[str, "os.PathLike[str]"] = "railing",
    method: str = "reference",
    *,
    width: Optional[int] = None,
    height: Optional[int] = None,
    samples: Optional[int] = None,
    seed: int = 0,
    sampler: str = "halton",
    focus: Focus = None,
    focus_pixel: Optional[Tuple[int, int]] = None,
    fstop: Optional[float] = None,
    focal_length: Optional[float] = None,
    sensor_width: Optional[float] = None,
    aperture: Optional[str] = None,
    camera: Optional[str] = None,
    allow_external_files: bool = False,
    return_depth: bool = False,
    **method_options: Any,
) -> Union[np.ndarray, Tuple[np.ndarray, np.ndarray]]:
    """Renders a built-in scene (``scenes()``) or a scene file (.gltf, .glb, .obj).

    Args:
        scene: a built-in scene name or a path.
        method: any method of ``methods()``; ``reference`` is the ground truth (lens views
            averaged), ``pinhole`` no blur.
        width, height: image size in pixels [default: the scene's, 1280x720 for built-ins].
        samples: lens views of ``reference``, samples per pixel of ``pinhole`` and of the
            frame the post-process methods blur, lens rays per pixel of ``multiview``.
        seed, sampler: the lens and pixel sampler (``halton``, ``sobol``, ``stratified``, ``random``).
        focus: focus distance in metres, or ``"auto"`` (the surface at the image centre)
            [default: the scene's].
        focus_pixel: focus on the surface at pixel (column, row).
        fstop, focal_length, sensor_width: the lens (f-number, millimetres)
            [default: the scene's].
        aperture: as in ``blur`` [default: the scene's].
        camera: a scene file's camera, by index or name.
        allow_external_files: let a scene file read files outside its own folder.
        return_depth: also return the pinhole view-axis depth in metres (inf: no surface).
        **method_options: the method's options, as in ``blur``.

    Returns:
        Colour HxWx4 float32 (linear, premultiplied alpha), and with ``return_depth`` a tuple
        (colour, depth HxW float32).
    """
    color, depth = _defocus.render(
        os.fspath(scene),
        method,
        width,
        height,
        samples,
        int(seed),
        sampler,
        float(focus) if isinstance(focus, (int, float)) and not isinstance(focus, bool) else focus,
        None if focus_pixel is None else (int(focus_pixel[0]), int(focus_pixel[1])),
        fstop,
        focal_length,
        sensor_width,
        aperture,
        camera,
        bool(allow_external_files),
        bool(return_depth),
        _flags(method_options),
    )
    if return_depth:
        return color, depth
    return color


def compare(a: Any, b: Any) -> Dict[str, float]:
    """MSE (linear light, unclamped), PSNR in dB and SSIM (sRGB-encoded, clamped to [0, 1]) of
    image ``a`` against image ``b`` (HxWx3 or HxWx4, float32 linear or uint8 sRGB)."""
    return _defocus.compare(_as_color(a, "a"), _as_color(b, "b"))


def report(
    out: Union[str, "os.PathLike[str]"],
    scene: Optional[Union[str, "os.PathLike[str]"]] = None,
    *,
    color: Optional[Union[str, "os.PathLike[str]"]] = None,
    depth: Optional[Union[str, "os.PathLike[str]"]] = None,
    truth: Optional[Union[str, "os.PathLike[str]"]] = None,
    methods: Union[str, Sequence[str]] = "all",
    reference_samples: int = 256,
    sweep: Union[None, str, Sequence[str], Dict[str, Sequence[Any]]] = None,
    frontier: bool = False,
    focus: Focus = None,
    **options: Any,
) -> Dict[str, Any]:
    """Writes the comparison report of ``defocus compare``: every method (or those of
    ``methods``) against the reference, as ``out/index.html`` (images, error maps, a table, a
    time/PSNR plot), ``out/results.json`` and every image as PNG and EXR.

    Args:
        out: the report's folder (created if absent; files of an earlier report that this one
            does not replace are removed).
        scene: a built-in scene name or a scene file: ``reference`` is rendered from it with
            ``reference_samples`` lens samples, then every method.
        color, depth, truth: instead of ``scene``, a rendered frame (colour and depth files)
            and its ground truth (a file, for example from another renderer).
        methods: ``"all"`` or method ids.
        reference_samples: lens samples of the reference.
        sweep: run each method that has the setting once per value:
            ``{"samples": [8, 16, 32]}``, or strings ``"samples=8,16,32"``; a key
            ``"splat.layers"`` sweeps that method alone.
        frontier: also run ``reference`` at 4 to 128 samples and mark each method as on the
            time-quality frontier or behind it (needs ``scene``).
        focus: metres or ``"auto"`` [default: the scene's; ``"auto"`` for frames].
        **options: the other flags of ``defocus compare`` with underscores: ``width``,
            ``height``, ``fstop``, ``focal_length``, ``sensor_width``, ``aperture``,
            ``samples``, ``seed``, camera flags (``camera``, ``look_from``, ...) and every
            method option (``rank=3``, ``layers=4``).

    Returns:
        What ``results.json`` holds (each run's ``status``, ``psnr_db``, ``ssim``,
        ``total_ms``, passes, files, ``frontier``), with ``index_html``, the page's path, and
        ``failed``, the labels of the runs that failed. A run that fails is reported, not
        raised; bad arguments raise ``ValueError``, unreadable files ``OSError``.
    """
    flags = [f"--out={os.fspath(out)}"]
    for name, value in (("scene", scene), ("color", color), ("depth", depth), ("truth", truth)):
        if value is not None:
            flags.append(f"--{name}={os.fspath(value)}")
    flags.append("--methods=" + (methods if isinstance(methods, str) else ",".join(methods)))
    flags.append(f"--reference-samples={int(reference_samples)}")
    if isinstance(sweep, str):
        sweep = [sweep]
    if isinstance(sweep, dict):
        sweep = [f"{k.replace('_', '-')}={','.join(str(v) for v in vs)}" for k, vs in sweep.items()]
    for s in sweep or []:
        flags.append(f"--sweep={s}")
    if frontier:
        flags.append("--frontier")
    if focus is not None:
        flags.append(f"--focus={focus}")
    flags.extend(_flags(options))
    index_html, results, failed = _defocus.report(flags)
    value: Dict[str, Any] = json.loads(results)
    value["index_html"] = index_html
    value["failed"] = list(failed)
    return value


def _keyed(value: Any) -> str:
    """A value, or keys ``{frame: value}``, as the command line's ``F:V,...``."""
    if isinstance(value, dict):
        return ",".join(f"{int(f)}:{float(v)}" for f, v in sorted(value.items()))
    return str(value)


def blur_sequence(
    color: Union[str, "os.PathLike[str]"],
    out: Union[str, "os.PathLike[str]"],
    depth: Optional[Union[str, "os.PathLike[str]"]] = None,
    *,
    frames: Optional[str] = None,
    overwrite: bool = False,
    method: str = "lowrank",
    focus: Union[float, str, Dict[int, float]] = "auto",
    fstop: Union[float, Dict[int, float]] = 2.8,
    **options: Any,
) -> Dict[str, Any]:
    """Blurs a sequence of frame files, as ``defocus blur`` does with frame patterns: frames
    run side by side within the memory budget, each written atomically; frames whose output
    exists are kept (a rerun resumes) unless ``overwrite``.

    Args:
        color: the colour frames, a pattern: ``shot.####.exr``, ``shot.%04d.exr`` or
            ``shot.@@@@.exr``.
        out: the output frames, a pattern (``.exr``, ``.png`` or ``.pfm``).
        depth: the depth frames, a pattern, or one file for every frame (a locked-off camera);
            ``None`` when the depth is a channel of the colour EXR (``depth_channel=...``).
        frames: ``"1001-1100"``, ``"1-100x2"``, ``"1,5,10-20"``; every frame of ``color``'s
            pattern on disk when ``None``.
        overwrite: write frames whose output exists again.
        method: a method that reads a frame (``defocus.methods()``, those without
            ``needs_scene``).
        focus: metres, ``"auto"`` (per frame), or keys ``{frame: metres}`` for a rack focus
            (interpolated linearly in 1/distance).
        fstop: the f-number, or keys ``{frame: N}`` (interpolated in stops).
        **options: the other flags of ``defocus blur`` with underscores: ``focal_length``,
            ``sensor_width`` (mm), ``aperture``, ``depth_kind``, ``depth_scale``,
            ``exr_compression``, ``coc_out`` and every method option (``rank=3``).

    Returns:
        ``{"written": [frames], "kept": [frames], "failed": {frame: message},
        "frames_per_second": float}``. A frame that fails (a missing or bad input file) is
        reported there, not raised, and the other frames are still written; bad arguments raise
        ``ValueError``.
    """
    flags = [f"--color={os.fspath(color)}", f"--out={os.fspath(out)}", f"--method={method}"]
    if depth is not None:
        flags.append(f"--depth={os.fspath(depth)}")
    if frames is not None:
        flags.append(f"--frames={frames}")
    if overwrite:
        flags.append("--overwrite")
    flags.append(f"--focus={_keyed(focus)}")
    flags.append(f"--fstop={_keyed(fstop)}")
    flags.extend(_flags(options))
    written, kept, failed, fps = _defocus.blur_sequence(flags)
    return {
        "written": list(written),
        "kept": list(kept),
        "failed": {int(n): message for n, message in failed},
        "frames_per_second": fps,
    }


def methods() -> List[Dict[str, Any]]:
    """Every method of the registry: ``id``, ``description``, ``paper``, ``input``,
    ``needs_scene`` (``render`` only), ``effects`` (the lens effects it renders, such as
    ``anamorphic`` and ``cats-eye``; the others it refuses) and ``options`` (each with ``name``, the keyword
    argument; ``flag``, the command line's; ``help`` with units; ``default``; ``switch`` for
    on/off options)."""
    return _defocus.methods()


def scenes() -> List[str]:
    """The names of the built-in scenes."""
    return list(_defocus.scenes())


def _method_ids() -> Sequence[str]:
    return [m["id"] for m in methods()]
