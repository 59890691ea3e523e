"""Spectra, tracking renders, tone mapping and relativity against the CLI and analytic
truths."""

import json
import math
import threading
import time

import numpy as np
import pytest

import blueshift
from blueshift import spectrum
from conftest import read_png, write_nrrd

C = 299_792_458.0


def test_blackbody_colour_equals_the_cli(cli):
    bb = spectrum.blackbody(5800.0)
    ref = cli("spectrum", "--blackbody", 5800, "--json", json_out=True)
    assert bb.xyz() == tuple(ref["xyz"])
    assert bb.xy() == pytest.approx(ref["xy"], abs=1e-15)
    assert bb.srgb() == tuple(ref["srgb_display"])
    assert bb.srgb(display=False) == tuple(ref["srgb_linear"])
    assert bb.integral() == ref["integral"]
    assert len(bb.pieces()) == ref["pieces"]


def test_planck_values_match_the_analytic_law():
    # Planck's law in W sr^-1 m^-2 nm^-1 (CODATA constants), independent of the library.
    h, k = 6.62607015e-34, 1.380649e-23
    t = 5800.0
    bb = spectrum.blackbody(t, max_error=1e-6)
    wl = np.linspace(400, 800, 41)
    lam = wl * 1e-9
    ref = 2 * h * C**2 / lam**5 / np.expm1(h * C / (lam * k * t)) * 1e-9
    np.testing.assert_allclose(bb.eval(wl), ref, rtol=2e-6)


def test_shifted_lines_equal_the_cli(cli):
    s = spectrum.build(lines="H,He", radial_velocity=3.0e6, doppler="relativistic", line_width=0.5)
    ref = cli("spectrum", "--lines", "H,He", "--radial-velocity", 3.0e6, "--doppler", "relativistic",
              "--line-width", 0.5, "--json", json_out=True)
    assert s.xyz() == tuple(ref["xyz"])
    assert s.shift == ref["shift"]
    beta = 3.0e6 / C
    assert s.shift == pytest.approx(math.sqrt((1 + beta) / (1 - beta)), rel=1e-14)


def test_doppler_shift_formulas():
    assert spectrum.doppler_shift(1.0e6) == pytest.approx(1 + 1.0e6 / C, rel=1e-15)
    b = 0.3
    assert spectrum.doppler_shift(b * C, "relativistic") == pytest.approx(math.sqrt((1 + b) / (1 - b)), rel=1e-12)
    h = dict(spectrum.catalogue("H"))
    assert any(abs(w - 656.28) < 0.05 for w in h)


def test_invariant_black_body_stays_a_black_body_at_t_over_s():
    s = spectrum.build(blackbody=6000.0, shift=1.2, radiometric="invariant")
    assert s.observed_temperature_k == pytest.approx(5000.0, rel=1e-12)
    ref = spectrum.blackbody(5000.0)
    assert s.xy() == pytest.approx(ref.xy(), abs=2e-4)


def _blob(n=24):
    x, y, z = np.meshgrid(*(np.linspace(-1, 1, n),) * 3, indexing="ij")
    # Asymmetric along x and y so a transposed layout would show.
    return np.exp(-((x - 0.3) ** 2 + (y + 0.2) ** 2 * 2 + z**2) * 4.0)


def test_render_from_numpy_equals_the_cli_on_the_same_file(cli, tmp_path):
    d = _blob()
    write_nrrd(tmp_path / "blob.nhdr", d)
    settings = dict(method="mdwt-1dda", spp=4, width=40, height=32, seed=3)
    img = blueshift.render(volume=d, tf="builtin:viridis", **settings)
    cli("render", "--volume", tmp_path / "blob.nhdr", "--tf", "builtin:viridis", "--method", "mdwt-1dda",
        "--spp", 4, "--width", 40, "--height", 32, "--seed", 3, "--out", tmp_path / "r.exr")
    ref = blueshift.read_hdr(tmp_path / "r.exr")
    assert img.shape == (32, 40, 4) and img.dtype == np.float32
    np.testing.assert_array_equal(np.asarray(img)[:, :, :3], np.asarray(ref))
    assert img.spp == 4 and img.noise is not None and img.noise > 0


def test_layouts_and_dtypes_give_the_same_image():
    d = _blob(16)
    kw = dict(method="marcher", width=24, height=24)
    a = blueshift.render(volume=d.astype(np.float64), tf="builtin:grey", **kw)
    b = blueshift.render(volume=np.asfortranarray(d, dtype=np.float32), tf="builtin:grey", **kw)
    c = blueshift.render(volume=d.astype(np.float32)[:, ::-1, :][:, ::-1, :], tf="builtin:grey", **kw)
    np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(a, c)
    # The Volume round trip keeps [x, y, z].
    v = blueshift.Volume.from_arrays({"d": d}, spacing=(1, 2, 3))
    np.testing.assert_array_equal(v.array("d"), d.astype(np.float32))
    assert v.dims == (16, 16, 16) and v.spacing == (1.0, 2.0, 3.0)


def test_progressive_passes_end_in_the_one_call_image():
    d = _blob(16)
    kw = dict(method="woodcock", spp=5, width=20, height=20, seed=9)
    passes = list(blueshift.render_progressive(volume=d, tf="builtin:viridis", **kw))
    assert [p for p, _, _ in passes] == [1, 2, 3, 4, 5]
    assert passes[0][2] is None and passes[-1][2] > 0
    final = blueshift.render(volume=d, tf="builtin:viridis", **kw)
    np.testing.assert_array_equal(passes[-1][1], final)
    # Stopping early cancels the render without waiting for the remaining passes.
    it = blueshift.render_progressive(volume=d, tf="builtin:viridis", method="woodcock", spp=1_000_000, width=64, height=64)
    next(it)
    t0 = time.perf_counter()
    it.close()
    # A million passes would take hours; closing waits for one pass at most.
    assert time.perf_counter() - t0 < 30
    # A bad scene is refused at the call, not at the first pass.
    with pytest.raises(blueshift.BlueshiftError, match="method"):
        blueshift.render_progressive(volume=d, method="bogus")


def test_transfer_functions_and_a_scene_dict(cli, tmp_path):
    tf = blueshift.TransferFunction.from_knots((0.0, 1.0), [(0, 1, 0, 0), (1, 0, 0, 1)], [(0, 0.0), (1, 1.0)])
    rgba = tf.eval([0.0, 0.5, 1.0])
    np.testing.assert_allclose(rgba[1], [0.5, 0.0, 0.5, 0.5], atol=1e-6)
    tf.save(tmp_path / "tf.json")
    with pytest.raises(FileExistsError):
        tf.save(tmp_path / "tf.json")
    d = _blob(16)
    write_nrrd(tmp_path / "b.nhdr", d)
    scene = {"channels": [{"volume": str(tmp_path / "b.nhdr"), "tf": str(tmp_path / "tf.json")}],
             "method": "mdwt-ndda", "spp": 3, "width": 16, "height": 16, "density_scale": 4.0}
    (tmp_path / "scene.json").write_text(json.dumps(scene))
    a = blueshift.render(scene)
    b = blueshift.render(channels=[{"volume": d, "tf": tf}], method="mdwt-ndda", spp=3, width=16, height=16, density_scale=4.0)
    np.testing.assert_array_equal(a, b)
    cli("render", tmp_path / "scene.json", "--out", tmp_path / "s.exr")
    np.testing.assert_array_equal(np.asarray(a)[:, :, :3], blueshift.read_hdr(tmp_path / "s.exr"))


def test_volume_write_nrrd_detached_or_attached_never_replacing(tmp_path):
    a = np.random.default_rng(4).random((5, 4, 3), dtype=np.float32)
    v = blueshift.Volume.from_arrays({"rho": a}, spacing=(0.5, 1.0, 2.0))
    # .nhdr: a text header naming the raw voxels beside it, x fastest.
    v.write_nrrd("rho", tmp_path / "v.nhdr")
    header = (tmp_path / "v.nhdr").read_text()
    assert "data file: v.raw" in header and "encoding: raw" in header
    raw = (tmp_path / "v.raw").read_bytes()
    assert raw == np.asfortranarray(a).tobytes(order="F")
    # .nrrd: attached.
    v.write_nrrd("rho", tmp_path / "v.nrrd")
    for p in ["v.nhdr", "v.nrrd"]:
        back = blueshift.Volume.read(tmp_path / p)
        np.testing.assert_array_equal(back.array(), a)
        assert back.spacing == (0.5, 1.0, 2.0)
    # Nothing is replaced: not the header, and not the data file of a new header.
    (tmp_path / "w.raw").write_bytes(b"keep")
    for p in ["v.nhdr", "v.nrrd", "w.nhdr"]:
        with pytest.raises(blueshift.BlueshiftError, match="exists"):
            v.write_nrrd("rho", tmp_path / p)
    assert (tmp_path / "w.raw").read_bytes() == b"keep" and not (tmp_path / "w.nhdr").exists()
    with pytest.raises(blueshift.BlueshiftError, match=".nrrd"):
        v.write_nrrd("rho", tmp_path / "v.raw")
    assert not list(tmp_path.glob(".blueshift-*"))


def test_tonemap_checks_its_arguments_and_keeps_the_shape():
    rng = np.random.default_rng(1)
    hdr = (10 ** rng.uniform(-2, 3, size=(20, 30, 1)) * rng.uniform(0.2, 1, size=(20, 30, 3))).astype(np.float32)
    for op in ("drago", "reinhard", "linear", "durand"):
        disp = blueshift.tonemap(hdr, op=op)
        assert disp.kind == "display" and disp.shape == hdr.shape
        assert np.all(np.isfinite(disp)) and float(np.min(disp)) >= 0.0
    # Drago maps the brightest pixel to Ld_max / 100 = 1 (Drago et al. 2003, Eq. 4).
    lum = hdr @ np.array([0.2126, 0.7152, 0.0722], dtype=np.float32)
    d = blueshift.tonemap(hdr, op="drago")
    k = np.unravel_index(np.argmax(lum), lum.shape)
    assert float(np.asarray(d)[k] @ np.array([0.2126, 0.7152, 0.0722])) == pytest.approx(1.0, rel=2e-3)
    params = blueshift.tonemap_parameters("drago")
    assert "bias" in params
    with pytest.raises(TypeError, match="no parameter 'nope'"):
        blueshift.tonemap(hdr, op="drago", nope=1)
    with pytest.raises(ValueError, match="is not one of"):
        blueshift.tonemap(hdr, op="bogus")


def test_tonemap_of_a_file_equals_the_cli(cli, tmp_path):
    cli("relativity", "--synth", "checker", "--beta", 0.8, "--width", 48, "--height", 24, "--out", tmp_path / "in.exr")
    src = blueshift.read_hdr(tmp_path / "in.exr")
    for op in ("drago", "reinhard", "fattal", "linear"):
        cli("tonemap", tmp_path / "in.exr", "--op", op, "--out", tmp_path / f"{op}.png")
        ours = blueshift.tonemap(src, op=op).to_srgb8()
        np.testing.assert_array_equal(ours, read_png(tmp_path / f"{op}.png"), err_msg=op)


def test_relativity_equals_the_cli(cli, tmp_path):
    img = blueshift.relativity.render("checker", beta=0.6, direction=(1, 0, -1), width=64, height=32, fov=100)
    cli("relativity", "--synth", "checker", "--beta", 0.6, "--direction", "1,0,-1", "--width", 64, "--height", 32,
        "--fov", 100, "--out", tmp_path / "r.exr")
    np.testing.assert_array_equal(img, blueshift.read_hdr(tmp_path / "r.exr"))
    with pytest.raises(ValueError, match="below 1"):
        blueshift.relativity.render("checker", beta=1.0)


def test_an_envmap_array_reads_as_the_same_image_in_a_file_would(cli, tmp_path):
    # 2:1 equirectangular and a 6:1 strip of cube faces, as files (views of the checker)
    # and as the arrays those files hold.
    for w, h in [(32, 16), (48, 8)]:
        path = tmp_path / f"e{w}.exr"
        cli("relativity", "--synth", "checker", "--beta", 0.3, "--width", w, "--height", h, "--out", path)
        a = np.asarray(blueshift.read_hdr(path), dtype=np.float32)
        kw = dict(beta=0.5, width=24, height=12)
        got = blueshift.relativity.render(a, **kw)
        np.testing.assert_array_equal(got, blueshift.relativity.render(path, **kw))
    # Any other shape is refused, as a file of that shape is.
    with pytest.raises(blueshift.BlueshiftError, match="neither a 2:1"):
        blueshift.relativity.render(np.ones((10, 10, 3), dtype=np.float32), beta=0.5)


def test_bad_input_raises_with_the_library_message(tmp_path):
    d = _blob(8)
    with pytest.raises(blueshift.BlueshiftError, match="method"):
        blueshift.render(volume=d, method="bogus")
    with pytest.raises(blueshift.BlueshiftError):
        blueshift.render(volume=d, width=0)
    with pytest.raises(TypeError, match="array 'value': dtype complex128"):
        blueshift.render(volume=d.astype(complex))
    with pytest.raises(ValueError, match=r"shape \(8, 8\)"):
        blueshift.render(volume=d[:, :, 0])
    with pytest.raises(blueshift.BlueshiftError, match="nope.nhdr"):
        blueshift.Volume.read(tmp_path / "nope.nhdr")
    assert issubclass(blueshift.BlueshiftError, ValueError)


def test_the_gil_is_released_during_a_render():
    d = _blob(32)
    ticks = []
    stop = threading.Event()

    def count():
        while not stop.is_set():
            ticks.append(time.perf_counter())
            time.sleep(0.001)

    t = threading.Thread(target=count)
    t.start()
    time.sleep(0.02)
    start = time.perf_counter()
    blueshift.render(volume=d, method="woodcock", spp=64, width=96, height=96)
    end = time.perf_counter()
    stop.set()
    t.join()
    during = [x for x in ticks if start < x < end]
    # Holding the GIL would freeze the counter for the whole render.
    assert len(during) > 5, (len(during), end - start)


def test_ctrl_c_cancels_a_render():
    import _thread
    import signal

    d = _blob(32)
    # Python's own Ctrl-C handler even where SIGINT was inherited ignored (a process started
    # in the background by a non-interactive shell): interrupt_main does nothing without it.
    old = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        timer = threading.Timer(0.3, _thread.interrupt_main)
        timer.start()
        t0 = time.perf_counter()
        with pytest.raises(KeyboardInterrupt):
            blueshift.render(volume=d, method="woodcock", spp=100_000, width=128, height=128)
        assert time.perf_counter() - t0 < 60
        timer.cancel()
    finally:
        signal.signal(signal.SIGINT, old)


def test_images_show_in_jupyter():
    import io

    from PIL import Image as PILImage

    img = blueshift.relativity.render("checker", beta=0.5, width=32, height=16)
    png = img._repr_png_()
    shown = np.asarray(PILImage.open(io.BytesIO(png)).convert("RGB"))
    np.testing.assert_array_equal(shown, img.to_srgb8())
    assert shown.shape == (16, 32, 3) and shown.max() > 0
    r = blueshift.render(volume=_blob(8), method="marcher", width=16, height=12)
    assert np.asarray(PILImage.open(io.BytesIO(r._repr_png_()))).shape[:2] == (12, 16)
    # A slice shows itself, not the whole picture.
    part = img[:8]
    assert np.asarray(PILImage.open(io.BytesIO(part._repr_png_()))).shape[:2] == (8, 32)


def test_absurd_requests_are_refused_before_any_work():
    with pytest.raises(blueshift.BlueshiftError, match="pieces"):
        spectrum.blackbody(5000.0, max_error=1e-300)
    with pytest.raises(blueshift.BlueshiftError, match="temperature"):
        spectrum.blackbody(1e300)
    with pytest.raises(blueshift.BlueshiftError, match="4 GiB"):
        blueshift.relativity.render("checker", beta=0.5, width=32768, height=32768)
    with pytest.raises(ValueError, match="finite"):
        blueshift.render(volume=_blob(8), zoom=float("nan"))


def test_a_paraview_preset_loads_with_its_knots(tmp_path):
    preset = [{"Name": "two", "ColorSpace": "RGB",
               "RGBPoints": [0.0, 1.0, 0.0, 0.0, 10.0, 0.0, 0.0, 1.0],
               "Points": [0.0, 0.0, 0.5, 0.0, 10.0, 0.8, 0.5, 0.0]}]
    (tmp_path / "p.json").write_text(json.dumps(preset))
    tf = blueshift.TransferFunction.load(tmp_path / "p.json")
    assert tf.domain == (0.0, 10.0)
    rgba = tf.eval([0.0, 5.0, 10.0])
    np.testing.assert_allclose(rgba[:, 3], [0.0, 0.4, 0.8], atol=1e-6)
    np.testing.assert_allclose(rgba[2, :3], [0.0, 0.0, 1.0], atol=1e-6)
    lut = tf.lut(11)
    assert lut.shape == (11, 4)
    np.testing.assert_allclose(lut[:, 3], np.linspace(0, 0.8, 11), atol=1e-6)


def test_the_viewer_serves_a_tracking_scene_from_numpy():
    import urllib.request

    v = blueshift.view(volume=_blob(12), tf="builtin:viridis", width=32, height=32)
    try:
        assert v.running
        page = urllib.request.urlopen(v.url, timeout=10).read().decode()
        assert "<html" in page.lower()
        assert v._repr_html_().startswith("<iframe")
    finally:
        v.stop()
    assert not v.running
    v.stop()  # a second stop is harmless


def test_a_panic_is_an_exception_not_an_abort():
    with pytest.raises(RuntimeError, match="deliberate test panic"):
        blueshift._native._panic_in_work()
    # The interpreter and the module go on working.
    assert blueshift.spectrum.doppler_shift(0.0) == 1.0


def test_importing_blueshift_needs_no_yt():
    import subprocess
    import sys

    code = (
        "import sys; sys.modules['yt'] = None\n"
        "import blueshift, blueshift.yt\n"
        "print(blueshift.spectrum.blackbody(5800).xy() is not None)\n"
        "try:\n    blueshift.yt.BlueshiftSource\nexcept ImportError:\n    print('no yt')\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["True", "no", "yt"]


def test_relativity_effects_as_a_list():
    a = blueshift.relativity.render("checker", beta=0.5, effects=["aberration", "doppler"], width=16, height=8)
    b = blueshift.relativity.render("checker", beta=0.5, effects="aberration,doppler", width=16, height=8)
    np.testing.assert_array_equal(a, b)


def test_gpu_render_equals_the_clis_gpu_render(cli, tmp_path):
    import os

    d = _blob(16)
    write_nrrd(tmp_path / "b.nhdr", d)
    kw = dict(method="mdwt-1dda", spp=4, width=24, height=20, seed=5)
    try:
        img = blueshift.render(volume=d, tf="builtin:viridis", device="gpu", **kw)
    except blueshift.BlueshiftError as e:
        if os.environ.get("BLUESHIFT_REQUIRE_GPU_TESTS") == "1":
            raise
        pytest.skip(f"no wgpu adapter: {e}")
    assert img.backend == "gpu" and img.fallback is None
    cli("render", "--volume", tmp_path / "b.nhdr", "--tf", "builtin:viridis", "--method", "mdwt-1dda", "--spp", 4,
        "--width", 24, "--height", 20, "--seed", 5, "--device", "gpu", "--out", tmp_path / "g.exr")
    np.testing.assert_array_equal(np.asarray(img)[:, :, :3], blueshift.read_hdr(tmp_path / "g.exr"))
    # The GPU estimates the same image as the CPU reference (Monte Carlo: within the noise).
    cpu = blueshift.render(volume=d, tf="builtin:viridis", spp=256, method="mdwt-1dda", width=24, height=20)
    gpu = blueshift.render(volume=d, tf="builtin:viridis", spp=256, method="mdwt-1dda", width=24, height=20, device="gpu")
    sigma = math.hypot(cpu.noise, gpu.noise) / math.sqrt(24 * 20)
    assert abs(float(np.mean(cpu[..., :3])) - float(np.mean(gpu[..., :3]))) < 6 * sigma
    with pytest.raises(blueshift.BlueshiftError, match="device"):
        blueshift.render(volume=d, device="tpu")


def test_linear_maps_the_99th_percentile_to_white_as_the_cli_does():
    # One hot pixel in a flat grey field: the 99th percentile of the lit luminance is the
    # grey, which maps to 1 (the maximum, 1e4, would make the field 5e-5).
    hdr = np.full((32, 32, 3), 0.5, np.float32)
    hdr[3, 4] = 1e4
    d = np.asarray(blueshift.tonemap(hdr, op="linear"))
    assert d[0, 0] == pytest.approx([1.0, 1.0, 1.0], rel=1e-6)


def test_native_functions_refuse_fortran_ordered_arrays():
    u = (np.arange(5 * 7 * 3) % 251).astype(np.uint8).reshape(5, 7, 3)
    with pytest.raises(blueshift.BlueshiftError, match="C-ordered"):
        blueshift._native.png_bytes(np.asfortranarray(u))
    x = np.linspace(0, 1, 5 * 7 * 3, dtype=np.float32).reshape(5, 7, 3)
    with pytest.raises(blueshift.BlueshiftError, match="C-ordered"):
        blueshift._native.encode_srgb8(np.asfortranarray(x))
    # The Python layer passes C order: the same pixels either way.
    np.testing.assert_array_equal(blueshift.tonemap(np.asfortranarray(x), op="drago"),
                                  blueshift.tonemap(x, op="drago"))
