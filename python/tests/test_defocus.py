"""Tests of the Python package: analytic cases, agreement with ``reference``, layouts, batches,
errors and the augmentation. Run with ``pytest python/tests`` after ``pip install ./python``."""

import threading

import numpy as np
import pytest

import defocus

W, H = 96, 64


def checkerboard(cell=4, channels=3):
    y, x = np.mgrid[0:H, 0:W]
    v = np.where((x // cell + y // cell) % 2 == 0, 0.9, 0.1).astype(np.float32)
    img = np.repeat(v[..., None], channels, axis=-1)
    if channels == 4:
        img[..., 3] = 1.0
    return img


def two_planes(near=1.0, far=4.0):
    depth = np.full((H, W), far, dtype=np.float32)
    depth[:, : W // 2] = near
    return depth


@pytest.mark.parametrize("method", ["lowrank", "hammon", "gaussian", "poisson"])
def test_constant_image_stays_constant(method):
    img = np.full((H, W, 3), 0.37, dtype=np.float32)
    out = defocus.blur(img, two_planes(), method, focus=1.5, fstop=1.4)
    assert out.shape == img.shape and out.dtype == np.float32
    assert np.abs(out - 0.37).max() < 1e-3


@pytest.mark.parametrize("method", ["lowrank", "hammon", "poisson"])
def test_in_focus_plane_stays_sharp(method):
    img = checkerboard()
    depth = np.full((H, W), 2.0, dtype=np.float32)
    out = defocus.blur(img, depth, method, focus=2.0, fstop=1.4)
    assert np.abs(out - img).max() < 1e-3


def test_out_of_focus_half_is_blurred_and_in_focus_half_is_not():
    img = checkerboard(cell=2)
    out = defocus.blur(img, two_planes(1.0, 4.0), "lowrank", focus=1.0, fstop=1.4)
    sharp, soft = out[8:-8, 8 : W // 2 - 12], out[8:-8, W // 2 + 12 : -8]
    # The in-focus half keeps the checkerboard's contrast; the far half loses it.
    assert sharp.std() > 0.35
    assert soft.std() < 0.1


def test_uint8_srgb_in_gives_uint8_out_and_rgba_keeps_alpha():
    img = (checkerboard() * 255).astype(np.uint8)
    out = defocus.blur(img, two_planes(), "hammon", focus=1.0)
    assert out.dtype == np.uint8 and out.shape == img.shape
    rgba = checkerboard(channels=4)
    out = defocus.blur(rgba, two_planes(), "lowrank", focus=1.0)
    assert out.shape == (H, W, 4)
    assert np.abs(out[..., 3] - 1.0).max() < 1e-3


def test_batch_equals_one_call_per_image_and_non_contiguous_input_is_read():
    imgs = np.stack([checkerboard(2), checkerboard(5)])
    depths = np.stack([two_planes(), two_planes(2.0, 8.0)])
    batch = defocus.blur(imgs, depths, "lowrank", focus=1.5, fstop=2.0)
    assert batch.shape == imgs.shape
    for i in range(2):
        one = defocus.blur(imgs[i], depths[i], "lowrank", focus=1.5, fstop=2.0)
        np.testing.assert_array_equal(batch[i], one)
    # A view with strides (every other column) is read as the image it shows.
    wide = np.repeat(checkerboard(2), 2, axis=1)
    view = wide[:, ::2]
    a = defocus.blur(view, two_planes(), "hammon", focus=1.5)
    b = defocus.blur(np.ascontiguousarray(view), two_planes(), "hammon", focus=1.5)
    np.testing.assert_array_equal(a, b)


def test_threads_can_blur_at_once():
    img, depth = checkerboard(), two_planes()
    want = defocus.blur(img, depth, "lowrank", focus=1.5)
    results = [None] * 4

    def run(i):
        results[i] = defocus.blur(img, depth, "lowrank", focus=1.5)

    threads = [threading.Thread(target=run, args=(i,)) for i in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    for r in results:
        np.testing.assert_array_equal(r, want)


def test_point_light_becomes_a_disc_of_diameter_two_coc():
    # A single bright pixel far behind the focus, on a black background.
    n = 81
    img = np.zeros((n, n, 3), dtype=np.float32)
    img[n // 2, n // 2] = 1000.0
    depth = np.full((n, n), 100.0, dtype=np.float32)
    # A 50 mm lens at f/2 (lens radius E = 12.5 mm) on a sensor 4.05 mm wide over 81 pixels:
    # f_px = 1000. Focused at 1 m, a point at 100 m has the thin-lens CoC radius
    # C = f_px E (1/1 - 1/100) = 12.375 px.
    out = defocus.blur(
        img, depth, "lowrank", focus=1.0, fstop=2.0, focal_length=50.0, sensor_width=4.05
    )
    coc = 1000.0 * 0.0125 * (1.0 - 1.0 / 100.0)
    lit = out[..., 0] > out[..., 0].max() * 0.5
    row = np.nonzero(lit[n // 2])[0]
    width = row.max() - row.min() + 1
    assert abs(width - 2 * coc) <= 2.0, (width, 2 * coc)
    # Energy is kept by the normalised kernel.
    assert abs(out[..., 0].sum() / 1000.0 - 1.0) < 0.02


def test_blur_of_a_rendered_frame_is_the_command_lines_and_near_the_reference():
    # The pinhole frame and depth of `glass` (16 samples a pixel), blurred from arrays by
    # lowrank, is exactly what `render --method lowrank` gives (the same frame, lens and
    # method), and against `reference` (256 lens views) through the same lens it measured
    # 28.7 dB at 160x90; the tolerance leaves 2 dB for sampling noise across machines.
    lens = dict(focus=3.0, fstop=1.4, focal_length=50.0, sensor_width=36.0)
    size = dict(width=160, height=90)
    color, depth = defocus.render(
        "glass", method="pinhole", samples=16, return_depth=True, **size, **lens
    )
    ours = defocus.blur(color, depth, "lowrank", **lens)
    np.testing.assert_array_equal(ours, defocus.render("glass", method="lowrank", **size, **lens))
    truth = defocus.render("glass", samples=256, **size, **lens)
    m = defocus.compare(ours, truth)
    assert m["psnr"] > 26.7, m


def test_methods_list_the_registry_with_options_and_defaults():
    ms = {m["id"]: m for m in defocus.methods()}
    assert {"reference", "hammon", "lowrank", "splat", "multilayer", "multiview"} <= set(ms)
    assert ms["multiview"]["needs_scene"] and not ms["lowrank"]["needs_scene"]
    rank = {o["name"]: o for o in ms["lowrank"]["options"]}["rank"]
    assert rank["default"] == "3" and rank["flag"] == "--rank"
    assert "layers" in {o["name"] for o in ms["multiview"]["options"]}


def test_bad_arguments_raise_value_error_with_the_flag_named():
    img, depth = checkerboard(), two_planes()
    cases = [
        (dict(rank=0), "rank"),
        (dict(no_such_option=1), "--no-such-option"),
        (dict(fstop=-1.0), "f-number"),
        (dict(depth_kind="furlongs"), "depth_kind"),
        (dict(aperture="poly:2"), "--aperture"),
    ]
    for kwargs, named in cases:
        with pytest.raises(ValueError, match=named):
            defocus.blur(img, depth, "lowrank", focus=1.5, **kwargs)
    with pytest.raises(ValueError, match="size mismatch"):
        defocus.blur(img, depth[:, :-1], "lowrank", focus=1.5)
    with pytest.raises(ValueError, match="not positive depths"):
        defocus.blur(img, -depth, "lowrank", focus=1.5)
    with pytest.raises(ValueError, match="render"):
        defocus.blur(img, depth, "multiview")
    with pytest.raises(OSError, match="no-such-aperture.png"):
        defocus.blur(img, depth, "lowrank", focus=1.5, aperture="image:no-such-aperture.png")


def test_nan_and_infinite_colour_are_refused_with_the_pixel_named_as_the_command_line_does():
    depth = two_planes()
    for bad in (np.nan, np.inf, -np.inf):
        img = checkerboard()
        img[5, 7, 1] = bad
        with pytest.raises(ValueError, match=r"color: channel G at pixel \(7, 5\) is"):
            defocus.blur(img, depth, "hammon", focus=1.5)
        with pytest.raises(ValueError, match=r"image 1 of the batch: color: channel G"):
            defocus.blur(np.stack([checkerboard(), img]), np.stack([depth, depth]), "hammon",
                         focus=1.5)
        with pytest.raises(ValueError, match=r"b: channel G at pixel \(7, 5\)"):
            defocus.compare(checkerboard(), img)


def test_huge_and_zero_stride_arrays_are_refused_before_any_copy():
    from defocus import _defocus

    # A broadcast array of 70000x70000 RGBA floats takes 16 bytes of memory and names 78 GB.
    huge = np.broadcast_to(np.float32(0.5), (70000, 70000, 4))
    huge_depth = np.broadcast_to(np.float32(2.0), (70000, 70000))
    for call in (
        lambda: defocus.blur(huge, huge_depth, "hammon", focus=1.5),
        lambda: _defocus.blur(huge, huge_depth, "hammon", "depth", 1.0, False, 1.5, None, 2.8,
                              50.0, 36.0, "disc", 0, []),
        lambda: defocus.compare(huge, huge),
        lambda: _defocus.compare(huge, huge),
    ):
        with pytest.raises(ValueError, match="larger than the limit"):
            call()
    # Images within the size limit, but a batch far beyond the memory budget.
    many = np.broadcast_to(np.float32(0.5), (1 << 20, 1024, 1024, 4))
    many_depth = np.broadcast_to(np.float32(2.0), (1 << 20, 1024, 1024))
    for call in (
        lambda: defocus.blur(many, many_depth, "hammon", focus=1.5),
        lambda: _defocus.blur(many, many_depth, "hammon", "depth", 1.0, False, 1.5, None, 2.8,
                              50.0, 36.0, "disc", 0, []),
    ):
        with pytest.raises(ValueError, match="budget"):
            call()
    # An empty image is refused too, by its shape.
    with pytest.raises(ValueError, match="at least 1 pixel"):
        defocus.blur(np.zeros((0, 4, 3), np.float32), np.zeros((0, 4), np.float32), "hammon")
    # A zero-stride array within the limits is read as the values it shows.
    flat = np.broadcast_to(np.float32(0.37), (H, W, 3))
    out = defocus.blur(flat, two_planes(), "hammon", focus=1.5)
    assert np.abs(out - 0.37).max() < 1e-3


def test_names_read_from_a_scene_file_reach_python_errors_escaped(tmp_path):
    import json
    import struct

    positions = struct.pack("<9f", 0, 0, -1, 1, 0, -1, 0, 1, -1)
    (tmp_path / "t.bin").write_bytes(positions)
    evil = "cam\x1b]0;pwned\x07\nerror: forged"
    gltf = {
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": [0, 1]}],
        "nodes": [{"mesh": 0}, {"camera": 0, "name": evil}],
        "cameras": [{"type": "perspective", "perspective": {"yfov": 0.8, "znear": 0.1}}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3",
                       "min": [0, 0, -1], "max": [1, 1, -1]}],
        "bufferViews": [{"buffer": 0, "byteLength": 36}],
        "buffers": [{"byteLength": 36, "uri": "t.bin"}],
    }
    path = tmp_path / "t.gltf"
    path.write_text(json.dumps(gltf))
    with pytest.raises(ValueError) as e:
        defocus.render(str(path), method="pinhole", width=8, height=6, camera="no-such-camera")
    message = str(e.value)
    assert "cam\\x1b]0;pwned\\x07\\nerror: forged" in message, message
    assert not any(ord(c) < 32 or ord(c) == 127 for c in message), repr(message)


def test_render_returns_colour_and_depth_of_the_asked_size():
    color, depth = defocus.render("glass", method="pinhole", width=64, height=36, return_depth=True)
    assert color.shape == (36, 64, 4) and depth.shape == (36, 64)
    assert np.all(depth > 0)


def test_random_defocus_is_seeded_and_p_zero_leaves_the_image():
    img, depth = checkerboard(), two_planes()
    a = defocus.RandomDefocus(seed=3, fstop_range=(1.4, 4.0))
    b = defocus.RandomDefocus(seed=3, fstop_range=(1.4, 4.0))
    for _ in range(3):
        np.testing.assert_array_equal(a(img, depth), b(img, depth))
        assert a.last_params == b.last_params
        assert 1.4 <= a.last_params["fstop"] <= 4.0
        # Without a focus range, the focus is a depth of the image.
        assert a.last_params["focus"] in (1.0, 4.0)
    ranged = defocus.RandomDefocus(focus_range=(0.5, 5.0), seed=1)
    ranged(img, depth)
    assert 0.5 <= ranged.last_params["focus"] <= 5.0
    never = defocus.RandomDefocus(p=0.0, seed=0)
    assert never(img, depth) is img


def test_random_defocus_takes_torch_tensors_in_chw():
    torch = pytest.importorskip("torch")
    img = torch.from_numpy(np.moveaxis(checkerboard(), -1, 0).copy())
    depth = torch.from_numpy(two_planes())
    out = defocus.RandomDefocus(seed=0)(img, depth)
    assert isinstance(out, torch.Tensor) and out.shape == img.shape


def test_highlights_lift_clipped_lights_before_the_blur():
    img = np.full((H, W, 3), 0.2, dtype=np.float32)
    img[H // 2, W // 2] = 1.0  # a light clipped at 1.0
    depth = np.full((H, W), 50.0, dtype=np.float32)
    plain = defocus.blur(img, depth, "lowrank", focus=1.0, fstop=2.0)
    lifted = defocus.blur(img, depth, "lowrank", focus=1.0, fstop=2.0, highlights=(0.9, 11.0))
    # The light's extra energy (gain 11 on 0.8 above the background) spreads into its bokeh;
    # the background, below the threshold, is unchanged.
    extra = (lifted - plain)[..., 0].sum()
    assert abs(extra - 10.0) < 0.2, extra
    assert abs(lifted[2, 2, 0] - plain[2, 2, 0]) < 1e-6
    with pytest.raises(ValueError, match="--highlights"):
        defocus.blur(img, depth, "lowrank", focus=1.0, highlights="1.5,2")


def test_lens_presets_and_effects_reach_python_through_the_same_options():
    img = defocus.render("lights", width=32, height=18, samples=8, lens="anamorphic-2x")
    assert img.shape == (18, 32, 4)
    ids = {m["id"]: m for m in defocus.methods()}
    assert "anamorphic" in ids["reference"]["effects"] and not ids["hammon"]["effects"]
    with pytest.raises(ValueError, match="anamorphic"):
        defocus.blur(checkerboard(), two_planes(), "hammon", focus=1.5, anamorphic=0.5)


def test_report_writes_the_page_and_its_numbers_are_the_images(tmp_path):
    # The report renders `reference` and each method through the library's jobs; its PSNR for
    # a method must be what the same render through `defocus.render`, compared here, gives.
    lens = dict(focus=3.0, fstop=1.4, width=96, height=54)
    out = tmp_path / "report"
    r = defocus.report(
        out, "glass", methods=["pinhole", "lowrank"], reference_samples=32, samples=4, **lens
    )
    assert (out / "index.html").is_file() and (out / "results.json").is_file()
    assert r["index_html"].endswith("index.html") and r["failed"] == []
    runs = {run["label"]: run for run in r["runs"]}
    assert set(runs) == {"pinhole", "lowrank"}
    assert all(run["status"] == "ok" for run in runs.values())
    truth = defocus.render("glass", samples=32, **lens)
    ours = defocus.render("glass", method="lowrank", samples=4, **lens)
    assert runs["lowrank"]["psnr_db"] == pytest.approx(defocus.compare(ours, truth)["psnr"], abs=1e-6)
    assert (out / runs["lowrank"]["image_png"]).is_file()


def test_report_errors_are_value_and_os_errors(tmp_path):
    with pytest.raises(ValueError, match="--scene"):
        defocus.report(tmp_path / "r")
    with pytest.raises(ValueError, match="no-such-method"):
        defocus.report(tmp_path / "r", "glass", methods=["no-such-method"])
    missing = tmp_path / "missing.exr"
    with pytest.raises(OSError, match="missing.exr"):
        defocus.report(tmp_path / "r", color=missing, depth=missing, truth=missing)


def test_timings_are_the_methods_passes_and_leave_the_image_unchanged():
    image, depth = checkerboard(), two_planes()
    plain = defocus.blur(image, depth, "lowrank", focus=1.0, fstop=1.4)
    out, timings = defocus.blur(image, depth, "lowrank", focus=1.0, fstop=1.4, timings=True)
    np.testing.assert_array_equal(out, plain)
    names = [name for name, _ in timings["passes"]]
    assert "lowrank/separable" in names and "lowrank/fallback" in names
    assert all(ms >= 0.0 for _, ms in timings["passes"])
    # The whole call holds its passes.
    assert timings["method_ms"] >= sum(ms for _, ms in timings["passes"])
    # A batch sums each pass over its images: twice the images, the same passes.
    batch, batch_timings = defocus.blur(np.stack([image, image]), np.stack([depth, depth]),
                                        "lowrank", focus=1.0, fstop=1.4, timings=True)
    assert [name for name, _ in batch_timings["passes"]] == names
    np.testing.assert_array_equal(batch[1], plain)


def test_blur_sequence_writes_each_frame_as_blur_does_resumes_and_names_a_bad_frame(tmp_path):
    from pfm import read_pfm, write_pfm

    frames = {}
    for n in range(1, 5):
        color, depth = defocus.render("glass", method="pinhole", width=48, height=27, samples=2,
                                      seed=n, return_depth=True)
        color = np.ascontiguousarray(color[..., :3])
        write_pfm(tmp_path / f"c.{n:04d}.pfm", color)
        write_pfm(tmp_path / f"z.{n:04d}.pfm", depth)
        frames[n] = (color, depth)
    args = (tmp_path / "c.####.pfm", tmp_path / "o.%04d.pfm", tmp_path / "z.@@@@.pfm")
    r = defocus.blur_sequence(*args, method="hammon", focus=2.0, fstop=2.0)
    assert r["written"] == [1, 2, 3, 4] and r["kept"] == [] and r["failed"] == {}
    for n, (color, depth) in frames.items():
        want = defocus.blur(color, depth, "hammon", focus=2.0, fstop=2.0)
        np.testing.assert_array_equal(read_pfm(tmp_path / f"o.{n:04d}.pfm"), want)
    # A rerun keeps what exists; a lost output and a missing input are handled frame by frame.
    (tmp_path / "o.0002.pfm").unlink()
    (tmp_path / "o.0003.pfm").unlink()
    (tmp_path / "c.0003.pfm").unlink()
    r = defocus.blur_sequence(*args, frames="1-4", method="hammon", focus=2.0, fstop=2.0)
    assert r["kept"] == [1, 4] and r["written"] == [2]
    assert list(r["failed"]) == [3] and "c.0003.pfm" in r["failed"][3]
    # A rack focus: keys per frame, and each frame's own focus.
    r = defocus.blur_sequence(*args, frames="1,2,4", overwrite=True, method="hammon",
                              focus={1: 1.0, 4: 4.0}, fstop=2.0)
    assert r["written"] == [1, 2, 4]
    color, depth = frames[4]
    np.testing.assert_array_equal(read_pfm(tmp_path / "o.0004.pfm"),
                                  defocus.blur(color, depth, "hammon", focus=4.0, fstop=2.0))
    with pytest.raises(ValueError, match="frame pattern"):
        defocus.blur_sequence(tmp_path / "c.0001.pfm", tmp_path / "x.pfm", tmp_path / "z.0001.pfm",
                              method="hammon")
    with pytest.raises(ValueError, match="--depth"):
        defocus.blur_sequence(*args[:2], method="hammon")


def test_focus_pixel_alone_focuses_there_and_a_distance_with_it_is_refused():
    # Two planes at 1 m and 4 m: focusing on a pixel of the near half keeps that half sharp,
    # as focus=1.0 does, and blurs the far half.
    img = checkerboard()
    depth = two_planes(near=1.0, far=4.0)
    by_pixel = defocus.blur(img, depth, "lowrank", focus_pixel=(W // 4, H // 2), fstop=1.4)
    by_distance = defocus.blur(img, depth, "lowrank", focus=1.0, fstop=1.4)
    assert np.abs(by_pixel - by_distance).max() < 1e-5
    near = (slice(8, H - 8), slice(8, W // 2 - 8))
    assert np.abs(by_pixel[near] - img[near]).max() < 1e-3
    with pytest.raises(ValueError, match="focus"):
        defocus.blur(img, depth, "lowrank", focus=2.0, focus_pixel=(1, 1))


def test_occlusion_fill_reaches_python_and_keeps_a_constant_image():
    depth = two_planes(near=0.5, far=4.0)
    img = np.full((H, W, 3), 0.37, dtype=np.float32)
    out = defocus.blur(img, depth, "lowrank", focus=4.0, fstop=1.4, occlusion="fill")
    assert np.abs(out - 0.37).max() < 2e-3
    board = checkerboard()
    a = defocus.blur(board, depth, "lowrank", focus=4.0, fstop=1.4, occlusion="fill")
    b = defocus.blur(board, depth, "lowrank", focus=4.0, fstop=1.4)
    assert np.abs(a - b).max() > 0.01
    with pytest.raises(ValueError, match="occlusion"):
        defocus.blur(board, depth, "lowrank", focus=4.0, occlusion="fil")


def gpu_or_skip(call):
    """`call()`, or a skip where no GPU adapter can be had (a machine without Vulkan)."""
    try:
        return call()
    except ValueError as e:
        if "adapter" in str(e):
            pytest.skip(f"no GPU adapter: {e}")
        raise


@pytest.mark.parametrize("method", ["hammon", "lowrank", "gaussian", "poisson"])
def test_blur_and_render_on_the_gpu_match_the_cpu(method):
    image, depth = defocus.render(
        scene="railing", method="pinhole", width=96, height=54, return_depth=True
    )
    cpu = defocus.blur(image, depth, method=method, focus=2.0, fstop=1.4, device="cpu")
    gpu = gpu_or_skip(
        lambda: defocus.blur(image, depth, method=method, focus=2.0, fstop=1.4, device="gpu")
    )
    assert defocus.compare(cpu, gpu)["psnr"] >= 45
    # A batch shares the GPU; each image is the single call's.
    batch = defocus.blur(np.stack([image, image]), np.stack([depth, depth]), method=method,
                         focus=2.0, fstop=1.4, device="gpu")
    assert defocus.compare(batch[1], gpu)["psnr"] >= 45
    scene_cpu = defocus.render(scene="lights", method=method, width=64, height=36, device="cpu")
    scene_gpu = defocus.render(scene="lights", method=method, width=64, height=36, device="gpu")
    assert defocus.compare(scene_cpu, scene_gpu)["psnr"] >= 45


@pytest.mark.parametrize("method", ["pinhole", "reference"])
def test_scene_methods_render_on_the_gpu_as_on_the_cpu(method):
    cpu, cpu_depth = defocus.render(scene="glass", method=method, width=64, height=36,
                                    samples=8, return_depth=True, device="cpu")
    gpu, gpu_depth = gpu_or_skip(
        lambda: defocus.render(scene="glass", method=method, width=64, height=36,
                               samples=8, return_depth=True, device="gpu")
    )
    assert defocus.compare(cpu, gpu)["psnr"] >= 45
    assert np.allclose(cpu_depth, gpu_depth, rtol=1e-4)


def test_multilayer_renders_on_the_gpu_as_the_paper():
    paper = dict(no_coverage=True, ml_bokeh="box", highlight_rays="off")
    cpu = defocus.render(scene="railing", method="multilayer", width=64, height=36,
                         device="cpu", **paper)
    gpu = gpu_or_skip(
        lambda: defocus.render(scene="railing", method="multilayer", width=64, height=36,
                               device="gpu", **paper)
    )
    assert defocus.compare(cpu, gpu)["psnr"] >= 40
    # The CPU's defaults beyond the paper are refused on the GPU by name.
    with pytest.raises(ValueError, match="no-coverage"):
        defocus.render(scene="railing", method="multilayer", width=64, height=36, device="gpu")


def test_device_values_are_checked_before_any_work():
    image, depth = checkerboard(), two_planes()
    with pytest.raises(ValueError, match="invalid device 'tpu'"):
        defocus.blur(image, depth, device="tpu")
    # A method without GPU passes is refused on the GPU, naming those that have them.
    with pytest.raises(ValueError, match="splat.*lowrank"):
        defocus.blur(image, depth, method="splat", device="gpu")
    # `auto` runs such a method on the CPU.
    out = defocus.blur(image, depth, method="splat", device="auto")
    assert out.shape == image.shape
