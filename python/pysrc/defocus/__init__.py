"""defocus: physically based, depth-aware lens blur (depth of field) on the CPU.

The Python face of the `defocus` Rust library and command line: the same thin-lens model, the
same methods and the same option names and units, with NumPy arrays in and out.

Units: distances in metres, focal length and sensor width in millimetres (full frame is 36 mm
wide), blur radii in pixels. Colour is either float32 linear light (alpha, if any,
premultiplied, as in OpenEXR) or uint8 sRGB (decoded to linear light before the blur and
encoded back after it, as the command line does with PNG). Depth is view-axis distance in
metres unless ``depth_kind`` says otherwise.

Example::

    import defocus
    color, depth = defocus.render("railing", method="pinhole", width=640, height=360,
                                  return_depth=True)
    out = defocus.blur(color, depth, method="lowrank", focus=2.5, fstop=1.4)
    truth = defocus.render("railing", width=640, height=360, focus=2.5, fstop=1.4)
    print(defocus.compare(out, truth))

Each function's docstring (``help(defocus.blur)``) gives its parameters with their units,
ranges and defaults.

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
    """A colour array as the native module reads it: C-contiguous float32 or uint8.

    Its shape is checked (the image size limit, the memory budget) before any copy: a
    broadcast array can have a shape far larger than its memory.
    """
    a = np.asarray(array)
    if a.dtype != np.uint8 and a.dtype.kind != "f":
        raise ValueError(
            f"{name}: dtype {a.dtype}: expected float32 (linear light) or uint8 (sRGB)"
        )
    _defocus.check_array(name, list(a.shape), True)
    if a.dtype == np.uint8:
        return np.ascontiguousarray(a)
    return np.ascontiguousarray(a, dtype=np.float32)


def _as_depth(array: Any) -> np.ndarray:
    """A depth array as the native module reads it: C-contiguous float32, its shape checked
    before any copy, as ``_as_color`` does."""
    a = np.asarray(array)
    if a.dtype.kind not in "fiu":
        raise ValueError(f"depth: dtype {a.dtype}: expected numbers (metres)")
    _defocus.check_array("depth", list(a.shape), False)
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
    device: str = "auto",
    **method_options: Any,
) -> Any:
    """Blurs a colour image (or a batch) with its depth through a thin lens: depth of field.

    The image is what a pinhole camera sees; the result is what a lens focused at ``focus``
    with the f-number ``fstop`` sees, each pixel spread by its circle of confusion in the
    aperture's shape. The same job as the command line's ``defocus blur``, on arrays.

    Parameters
    ----------
    color : numpy.ndarray
        HxWx3 or HxWx4 pixels, or NxHxWx3 / NxHxWx4 for a batch of N images. float32 (any
        float dtype is converted to it) is linear light, alpha premultiplied; uint8 is sRGB
        with straight alpha, decoded to linear light before the blur and encoded back after
        it. Without alpha, the image is opaque. Float colour must be finite
        (``numpy.nan_to_num`` replaces NaN and infinities).
    depth : numpy.ndarray
        HxW values (NxHxW for a batch), of the kind ``depth_kind``, in any float or integer
        dtype (read as float32). With the default kind: view-axis distance in metres, every
        value finite and above 0, or +inf where there is no surface (0 too, with
        ``zero_depth_is_far``).
    method : str, default "lowrank"
        A method that blurs a frame: ``"lowrank"`` (bokeh in the aperture's shape),
        ``"hammon"``, ``"gaussian"``, ``"poisson"``, ``"splat"`` or ``"multilayer"`` (the
        layered ones on the frame's fragment lists; with ``occlusion="fill"``, the frame
        decomposed into a near and a filled back layer). ``methods()`` lists every
        method with its options; those with ``needs_scene`` run in ``render`` only.
    focus : float or str or None, default "auto"
        Focus distance in metres along the view axis, or ``"auto"`` (``None`` is the same):
        the median depth of a small window at the image centre, widened until it holds a
        surface, for each image of a batch. Must be finite and above 0. With
        ``depth_kind="coc"`` it must stay ``"auto"`` (or ``None``).
    focus_pixel : tuple of (int, int) or None, default None
        Focus on the depth at this pixel, (column, row) from the top left: the median of a
        small window around it, instead of ``focus`` (which must then stay ``"auto"`` or
        ``None``; a distance and ``focus_pixel`` together raise ``ValueError``).
    fstop : float, default 2.8
        f-number N, at least 0.1; the lens radius is ``focal_length / (2 N)``.
    focal_length : float, default 50.0
        Focal length in millimetres, 0.1 to 10000.
    sensor_width : float, default 36.0
        Sensor width in millimetres (full frame is 36), 0.1 to 1000; it spans the image's
        width, so with the focal length it sets the field of view.
    aperture : str, default "disc"
        The aperture's shape, as the command line's ``--aperture``: ``"disc"``,
        ``"poly:B[,rot=DEG][,curve=R]"`` (B blades), ``"star[:N[,INNER]]"``, ``"heart"``,
        ``"ring[:INNER]"`` or ``"image:PATH"`` (a greyscale image of the bokeh). The methods
        that blur in the aperture's shape read it (``lowrank``, ``poisson``).
    depth_kind : str, default "depth"
        What ``depth`` holds: ``"depth"`` (or ``"view"``), view-axis distance in metres;
        ``"radial"``, distance from the eye along each pixel's ray, in metres; ``"inverse"``
        or ``"disparity"``, depth = ``depth_scale / value`` (0 is infinitely far);
        ``"coc"``, the signed circle-of-confusion radius in pixels (negative in front of the
        focus) times ``depth_scale``, every value finite: the map gives every pixel's blur,
        so ``focus`` stays ``"auto"`` and ``focus_pixel`` unset (else ``ValueError``).
    depth_scale : float, default 1.0
        Metres per depth unit, finite and above 0: the depth is ``value * depth_scale``
        (``depth_scale / value`` for inverse depth and disparity; for ``"coc"``, the radius
        in pixels is ``value * depth_scale``).
    zero_depth_is_far : bool, default False
        Read a depth of exactly 0 as "no surface" (infinitely far) instead of refusing it.
    seed : int, default 0
        Seed of the methods that draw random taps (``lowrank``'s fallback, ``poisson``),
        0 to 2**64 - 1.
    highlights : str or sequence of float or None, default None
        ``(threshold, gain)`` or ``(threshold, gain, knee)``, or the same as a string
        ``"0.9,20"``: lift the clipped highlights of low-dynamic-range input before the blur,
        so that the bokeh of a light clipped at 1.0 comes out bright. In linear light, a pixel
        whose brightest channel is above ``threshold`` (0 up to, not including, 1) is scaled
        by up to ``gain`` (1 to 1e6), reached at ``threshold + knee`` (``knee`` above 0, at
        most 1; by default ``1 - threshold``, so a pixel clipped at 1.0 gets the whole gain).
        ``None``: no lift.
    timings : bool, default False
        Also return where the time went, in milliseconds (see Returns).
    device : str, default "auto"
        Where the method runs, as the command line's ``--device``: ``"cpu"``; ``"gpu"``, any
        GPU adapter, a software one (lavapipe) included, and an error naming what was found
        when there is none or the method has no GPU passes; ``"auto"``, a hardware GPU when
        there is one and the method runs there (``hammon``, ``lowrank``, ``gaussian``,
        ``poisson``; in ``render`` also ``pinhole``, ``reference``, and ``multilayer`` with
        the paper's options ``no_coverage=True, ml_bokeh="box", highlight_rays="off"``), else
        the CPU. The GPU's images equal the CPU's within 45 dB PSNR. A
        GPU is opened once and shared by the calls that follow, and by a batch's images.
    **method_options
        The method's options, named as the command line's flags with underscores and
        without the dashes: ``rank=3`` for ``--rank 3``, ``max_coc=32``, a switch as
        ``no_mask=True``; a list or tuple is joined with commas, and ``None`` or ``False``
        leaves the option out. Units, ranges and defaults are the command line's
        (``methods()`` lists them); an option of another method is range-checked too.

    Returns
    -------
    numpy.ndarray or tuple of (numpy.ndarray, dict)
        The blurred image in the layout of ``color``: the same shape and channels, float32
        for float input, uint8 (sRGB) for uint8 input. With ``timings=True``, a tuple
        ``(image, timings)`` where ``timings`` is ``{"passes": [(name, ms), ...],
        "method_ms": ms}``: the method's passes as ``defocus blur --timings`` prints them,
        and the wall-clock time of the whole library call (the passes and the work between
        them), summed over the images of a batch.

    Raises
    ------
    ValueError
        A dtype or shape that is not one of the above, an image larger than the size limit
        (2**26 pixels) or a call that would need more memory than the budget
        (``DEFOCUS_MEMORY_BUDGET_GIB``, 16 GiB by default), both checked before anything is
        copied, ``color`` and ``depth`` of different sizes, a NaN or infinite colour value
        (the message names the channel and pixel), an unknown method or one that needs a
        scene, a depth value out of range, a lens value or method option out of range, no
        surface to focus on, or both a ``focus`` distance and ``focus_pixel``; in a batch, the
        message names the image. The messages are the command line's.
    OSError
        A file named by an option (``aperture="image:PATH"``) that cannot be read.
    OverflowError
        A negative ``seed`` or ``focus_pixel`` coordinate.
    """
    c = _as_color(color, "color")
    d = _as_depth(depth)
    if isinstance(focus, (int, float)) and not isinstance(focus, bool):
        focus = float(focus)
    if focus_pixel is not None and isinstance(focus, str) and focus.strip() == "auto":
        # The pixel replaces the default automatic focus, as `--focus-pixel` does.
        focus = None
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
        device,
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
    device: str = "auto",
    **method_options: Any,
) -> Union[np.ndarray, Tuple[np.ndarray, np.ndarray]]:
    """Renders a built-in scene or a scene file (.gltf, .glb, .obj) with any method.

    The same job as the command line's ``defocus render``. Unset camera values (``None``) are
    the scene's: a built-in scene's camera, or a scene file's first camera (a view framing
    the whole scene when it has none).

    Parameters
    ----------
    scene : str or os.PathLike, default "railing"
        A built-in scene name (``scenes()``) or the path of a .gltf, .glb or .obj file.
    method : str, default "reference"
        Any id of ``methods()``. ``"reference"`` averages lens views (the ground truth),
        ``"pinhole"`` renders without blur; the methods that blur a frame blur an
        anti-aliased pinhole frame of the scene, and the layered ones (``multilayer``,
        ``multiview``, ``splat`` with ``layers`` above 1) read the scene's hidden surfaces.
    width : int or None, default None
        Image width in pixels; ``None``: the scene's (1280 for the built-in scenes).
    height : int or None, default None
        Image height in pixels; ``None``: the scene's (720 for the built-in scenes).
    samples : int or None, default None
        1 to 2**20: the lens views of ``reference`` (``None``: 256), the samples per pixel of
        ``pinhole`` (``None``: 1) and of the pinhole frame that the frame-blurring methods
        blur (``None``: 16), the lens rays per pixel of ``multiview`` (``None``: 32). Other
        methods do not read it.
    seed : int, default 0
        Seed of the lens and pixel samplers and of the methods' random taps, 0 to 2**64 - 1.
    sampler : str, default "halton"
        The lens and pixel sampler of ``reference``, ``pinhole`` and ``multiview``:
        ``"halton"``, ``"sobol"``, ``"stratified"`` or ``"random"``.
    focus : float or str or None, default None
        Focus distance in metres along the view axis (finite, above 0), or ``"auto"``: the
        distance of the surface at the image centre. ``None``: the scene's.
    focus_pixel : tuple of (int, int) or None, default None
        Focus on the surface seen at this pixel, (column, row) from the top left; not
        together with ``focus``.
    fstop : float or None, default None
        f-number N, at least 0.1; ``None``: the scene's.
    focal_length : float or None, default None
        Focal length in millimetres, 0.1 to 10000; ``None``: the scene's.
    sensor_width : float or None, default None
        Sensor width in millimetres, 0.1 to 1000 (full frame is 36); ``None``: the scene's
        (36 for the built-in scenes).
    aperture : str or None, default None
        The aperture's shape, as in ``blur``; ``None``: the scene's.
    camera : str or None, default None
        A scene file's camera, by index (``"0"``) or name; ``None``: its first. A built-in
        scene has one camera and refuses this.
    allow_external_files : bool, default False
        Let a scene file read files outside its own folder (absolute glTF URIs or OBJ
        material paths, ``../``, links out). Off, so that a scene file from elsewhere
        cannot read other files of yours into the image or into error messages.
    return_depth : bool, default False
        Also return the pinhole view-axis depth at pixel centres.
    device : str, default "auto"
        Where the method runs, as in ``blur``: ``"cpu"``, ``"gpu"`` or ``"auto"``. On the GPU
        the frame-blurring methods blur there; the pinhole frame they blur is rendered on the
        CPU.
    **method_options
        The method's options, as in ``blur`` (``rank=3``, ``layers=4``).

    Returns
    -------
    numpy.ndarray or tuple of (numpy.ndarray, numpy.ndarray)
        The colour, HxWx4 float32, linear light with premultiplied alpha. With
        ``return_depth=True``, a tuple ``(colour, depth)``, depth HxW float32 in metres
        along the view axis, +inf where no surface was hit.

    Raises
    ------
    ValueError
        An unknown scene, method or sampler, a value or method option out of range, both
        ``focus`` and ``focus_pixel``, no surface to focus on, or a scene file that cannot be
        parsed (the command line's messages).
    OSError
        A scene file that cannot be read.
    OverflowError
        A negative ``width``, ``height``, ``samples``, ``seed`` or ``focus_pixel`` coordinate.
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
        device,
    )
    if return_depth:
        return color, depth
    return color


def compare(a: Any, b: Any) -> Dict[str, float]:
    """Measures how close image ``a`` is to image ``b``: MSE, PSNR and SSIM.

    The same numbers as the command line's ``defocus compare A B``. The measure is
    symmetric; alpha is not compared.

    Parameters
    ----------
    a : numpy.ndarray
        HxWx3 or HxWx4, float32 linear light (any float dtype is converted to it) or uint8
        sRGB. One image, not a batch.
    b : numpy.ndarray
        The image to compare with, the same width and height, in either dtype.

    Returns
    -------
    dict of str to float
        ``"mse"``: the mean squared error over R, G and B in linear light, unclamped;
        ``"psnr"``: the PSNR in dB over sRGB-encoded R, G and B clamped to [0, 1], peak 1
        (``inf`` for images identical once encoded); ``"ssim"``: the mean SSIM of the
        sRGB-encoded luma, -1 to 1, 1 for identical images.

    Raises
    ------
    ValueError
        A dtype or shape other than the above, an image larger than the size limit, a batch,
        images of different sizes, or a NaN or infinite colour value.
    """
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
    """Writes the comparison report of ``defocus compare``: every method against the truth.

    Renders ``reference`` (the truth) and every method of ``methods`` on ``scene``, or blurs a
    rendered frame (``color``, ``depth``) with every method that reads one and compares it
    with ``truth``; writes ``out/index.html`` (the images, error maps, a table and a
    time-quality plot), ``out/results.json`` and every image as PNG and EXR. Give ``scene``,
    or ``color``, ``depth`` and ``truth``.

    Parameters
    ----------
    out : str or os.PathLike
        The report's folder, created if absent; images an earlier report wrote and recorded
        in its ``results.json``, unchanged since, that this one does not replace are removed.
        An input that lies in it under a name the report writes is refused (``ValueError``).
    scene : str or os.PathLike or None, default None
        A built-in scene name or a scene file (.gltf, .glb, .obj); ``reference`` is rendered
        from it with ``reference_samples`` lens samples, unless ``truth`` is given.
    color : str or os.PathLike or None, default None
        Instead of ``scene``: a rendered frame's colour image (EXR, PNG or PFM).
    depth : str or os.PathLike or None, default None
        The frame's depth pass, view-axis metres (EXR, PFM or PNG); with ``color``.
    truth : str or os.PathLike or None, default None
        The ground truth to compare with (for example from another renderer), instead of
        ``reference``; needed with ``color``; with ``scene``, of the scene camera's size.
    methods : str or sequence of str, default "all"
        ``"all"``, method ids separated by commas, or a sequence of ids.
    reference_samples : int, default 256
        Lens samples of the ``reference`` render that is the truth.
    sweep : str or sequence of str or dict or None, default None
        Run each method that has a setting once per value: ``{"samples": [8, 16, 32]}``, or
        strings ``"samples=8,16,32"``; a key ``"splat.layers"`` sweeps that method alone.
        ``None``: each method once.
    frontier : bool, default False
        Also run ``reference`` at 4, 8, 16, 32, 64 and 128 lens samples and mark each method
        as on the time-quality frontier or behind it (some ``reference`` run is both faster
        and at least as good). Needs ``scene``.
    focus : float or str or None, default None
        Focus distance in metres, or ``"auto"``; ``None``: the scene's, or ``"auto"`` for a
        frame.
    **options
        The other flags of ``defocus compare``, with underscores: ``width`` and ``height``
        (pixels), ``fstop``, ``focal_length`` and ``sensor_width`` (millimetres),
        ``aperture``, ``samples``, ``seed``, ``allow_external_files``, the camera flags
        (``camera``, ``look_from``, ...) and every method option (``rank=3``, ``layers=4``).
        Unset, the lens is the scene's, or for a frame f/2.8, 50 mm on a 36 mm sensor, disc.

    Returns
    -------
    dict
        What ``results.json`` holds (each run's ``status``, ``psnr_db``, ``ssim``,
        ``total_ms``, passes, files, ``frontier``), with ``"index_html"``, the page's path,
        and ``"failed"``, the list of the labels of the runs that failed (their errors are in
        the page). A method that fails is reported there, not raised.

    Raises
    ------
    ValueError
        Bad arguments (neither ``scene`` nor ``color``, an unknown method, a value out of
        range), with the command line's message.
    OSError
        An input file that cannot be read, or an output that cannot be written.
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
    """Blurs a sequence of frame files, as ``defocus blur`` does with a frame pattern.

    Frames run side by side within the memory budget, each written atomically (a file that
    exists is whole); frames whose output exists are kept, so a rerun resumes, unless
    ``overwrite``. A frame that fails is reported, and the others are still written.

    Parameters
    ----------
    color : str or os.PathLike
        The colour frames, a pattern: ``shot.####.exr`` (one digit per ``#`` or ``@``) or
        ``shot.%04d.exr``; EXR, PNG (sRGB) or PFM.
    out : str or os.PathLike
        The output frames, a pattern: ``.exr`` (linear float RGBA), ``.png`` (8-bit sRGB) or
        ``.pfm``.
    depth : str or os.PathLike or None, default None
        The depth frames (metres, times ``depth_scale``), a pattern, or one file for every
        frame (a locked-off camera). For depth in the colour EXR, give the colour pattern
        again (and ``depth_channel=...`` if the channel is not found by its name). ``None``
        only with ``tilt_shift``.
    frames : str or None, default None
        The frames, such as ``"1001-1100"``, ``"1-100x2"`` or ``"1,5,10-20"``; ``None``:
        every frame of ``color``'s pattern on disk.
    overwrite : bool, default False
        Blur frames whose output exists again, replacing it.
    method : str, default "lowrank"
        A method that blurs a frame (``methods()``, those without ``needs_scene``).
    focus : float or str or dict of int to float, default "auto"
        Focus distance in metres, ``"auto"`` (the median depth of a small window at each
        frame's centre), or keys ``{frame: metres}`` for a rack focus, interpolated linearly
        in 1/distance and held outside the keys.
    fstop : float or dict of int to float, default 2.8
        The f-number N, at least 0.1, or keys ``{frame: N}``, interpolated in stops (linearly
        in log N).
    **options
        The other flags of ``defocus blur``, with underscores: ``focal_length`` and
        ``sensor_width`` (millimetres; 50 and 36 when unset), ``aperture``, ``depth_kind``,
        ``depth_scale``, ``depth_channel``, ``zero_depth_is_far``, ``seed``,
        ``tilt_shift``, ``highlights``, ``coc_out`` (a pattern), ``exr_compression`` and
        every method option (``rank=3``); the same units, ranges and defaults as there.

    Returns
    -------
    dict
        ``{"written": [frame, ...], "kept": [frame, ...], "failed": {frame: message},
        "failed_count": int, "frames_per_second": float}``: the frame numbers written and
        kept, the errors of the first 100 failed frames (a missing or bad input file), how many
        frames failed in all, and the rate of the frames written.

    Raises
    ------
    ValueError
        Bad arguments: ``color`` or ``out`` not a pattern, no ``depth``, no file matching
        ``color`` (without ``frames``), an unknown method, a value out of range (the command
        line's message).
    OSError
        The folder of the ``color`` frames cannot be read.
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
    written, kept, failed, failed_count, fps = _defocus.blur_sequence(flags)
    return {
        "written": list(written),
        "kept": list(kept),
        "failed": {int(n): message for n, message in failed},
        "failed_count": int(failed_count),
        "frames_per_second": fps,
    }


def methods() -> List[Dict[str, Any]]:
    """Lists every method of the registry, with its options.

    The methods and options are the command line's, from the same definitions.

    Returns
    -------
    list of dict
        One dict per method, in the registry's order: ``"id"`` (str, the name ``blur`` and
        ``render`` take), ``"description"`` (str), ``"paper"`` (str), ``"input"`` (str, what
        it reads), ``"needs_scene"`` (bool, true for the methods that run in ``render``
        only), ``"effects"`` (list of str, the lens effects it renders, such as
        ``"anamorphic"`` and ``"cats-eye"``; it refuses the others) and ``"options"`` (list
        of dict, each with ``"name"``, the keyword argument; ``"flag"``, the command line's;
        ``"help"``, with units; ``"default"``, a str or ``None``; and ``"switch"``, true for
        an on/off option).
    """
    return _defocus.methods()


def scenes() -> List[str]:
    """Lists the names of the built-in scenes, which ``render`` and ``report`` take.

    Returns
    -------
    list of str
        The names, such as ``"railing"``.
    """
    return list(_defocus.scenes())


def _method_ids() -> Sequence[str]:
    return [m["id"] for m in methods()]
