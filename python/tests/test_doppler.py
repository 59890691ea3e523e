"""Doppler scenes from files, numpy and yt against the CLI and analytic truths."""

import json
import math
import os
import stat
from pathlib import Path

import numpy as np
import pytest

import blueshift
from blueshift import doppler
from conftest import ROOT, read_csv, read_png, write_nrrd

C = 299_792_458.0
ENZO = ROOT / "scenes" / "enzo-moving7.json"
ENZO_DATA = ROOT.parent / "shared" / "data" / "enzo-moving7"


def _shell(n=24, omega=2.0e5):
    """A rotating hydrogen shell (rigid rotation about z, omega in m/s per world unit)."""
    ax = (np.arange(n) - (n - 1) / 2) / (n / 2)
    x, y, z = np.meshgrid(ax, ax, ax, indexing="ij")
    r = np.sqrt(x**2 + y**2 + z**2)
    dens = np.exp(-(((r - 0.6) / 0.12) ** 2))
    vel = np.stack([-omega * y, omega * x, 0 * z], axis=-1)
    temp = np.full_like(dens, 8000.0)
    return dens, vel, temp


needs_enzo = pytest.mark.skipif(not ENZO_DATA.exists(), reason="no ../shared/data/enzo-moving7")


@needs_enzo
def test_enzo_scene_file_render_and_pick_equal_the_cli(cli, tmp_path):
    s = doppler.Scene.read(ENZO)
    r = s.render(width=48, height=40)
    cli("doppler", "--scene", ENZO, "--width", 48, "--height", 40, "--pick", "20,17", "--out", tmp_path / "e.exr")
    np.testing.assert_array_equal(r.xyz.astype(np.float32), blueshift.read_hdr(tmp_path / "e.exr"))
    np.testing.assert_array_equal(r.rgb, read_png(tmp_path / "e.png"))
    w, v = s.spectrum(20, 17, width=48, height=40)
    csv = sorted(Path(tmp_path).glob("*.csv"))
    assert csv, list(Path(tmp_path).iterdir())
    ref = read_csv(csv[0])
    # The CLI's CSV is the same exact polyline (with extra grid points): both agree
    # everywhere between break points.
    xs = np.unique(np.concatenate([ref[:, 0], w]))
    mid = 0.5 * (xs[1:] + xs[:-1])
    np.testing.assert_allclose(np.interp(mid, w, v), np.interp(mid, ref[:, 0], ref[:, 1]), rtol=1e-12, atol=1e-300)
    assert v.max() > 0


def test_numpy_scene_equals_the_cli_on_the_same_files(cli, tmp_path):
    dens, vel, temp = _shell()
    scene = doppler.Scene(velocity=vel, temperature=temp, blackbody={"density": dens, "scale": 0.02},
                          species={"H": {"density": dens, "scale": 5.0}})
    path = scene.save(tmp_path / "scene")
    r = scene.render(width=32, height=32, exposure=1.0)
    cli("doppler", "--scene", path, "--width", 32, "--height", 32, "--exposure", 1.0, "--out", tmp_path / "n.exr")
    np.testing.assert_array_equal(r.xyz.astype(np.float32), blueshift.read_hdr(tmp_path / "n.exr"))
    np.testing.assert_array_equal(r.rgb, read_png(tmp_path / "n.png"))
    # A file the scene wrote is never replaced.
    with pytest.raises(FileExistsError):
        scene.save(tmp_path / "scene")


def test_rotating_shell_centroid_is_minus_omega_x(tmp_path):
    omega = 2.0e5
    dens, vel, temp = _shell(omega=omega)
    scene = doppler.Scene(velocity=vel, temperature=temp, species={"H": dens})
    # Seen from +y the line of sight is -y: v_los = -v_y = -omega x for every point of a
    # column at x, so each pixel's centroid sits at lambda0 (1 - omega x / c).
    cube = scene.cube(line="H-alpha", velocity_bins=(-300, 300, 120), axis="y", width=24, height=24, cell_domain=True)
    m = cube.moments()
    n = 24
    xs = (np.arange(n) - (n - 1) / 2) / (n / 2)
    m0 = m["m0"]
    good = m0 > 0.05 * m0.max()
    # With cell_domain the 24 pixels span the 24 voxels' cells: pixel centres sit on voxel
    # centres. yt's y view: image right is world z, image up is world x; moments are [x_img, y_img]
    # with y_img = 0 at the bottom, so column j of the map sits at world x = xs[j].
    checked = 0
    for j in range(n):
        row = good[:, j]
        if row.any():
            np.testing.assert_allclose(m["m1"][row, j], -omega * xs[j] / 1e3, atol=0.01 * omega / 1e3)
            checked += 1
    assert checked > n // 2
    # The picked spectrum's line centroid too (H-alpha window): row r from the top is
    # world x = xs[n - 1 - r].
    lam0 = [w for w, _ in blueshift.spectrum.catalogue("H") if 650 < w < 660][0]
    r = 5
    w, v = scene.spectrum(12, r, width=24, height=24, axis="y", cell_domain=True)
    win = (w > lam0 - 2) & (w < lam0 + 2)
    cen = np.trapezoid(w[win] * v[win], w[win]) / np.trapezoid(v[win], w[win])
    expect = lam0 * (1 - omega * xs[n - 1 - r] / C)
    assert abs(cen - expect) < 0.02 * abs(lam0 - expect)


def test_units_cm_per_s_give_the_km_per_s_picture():
    unyt = pytest.importorskip("unyt")
    dens, vel, temp = _shell()
    a = doppler.Scene(velocity=unyt.unyt_array(vel * 100.0, "cm/s"), temperature=unyt.unyt_array(temp, "K"),
                      species={"H": dens})
    b = doppler.Scene(velocity=unyt.unyt_array(vel / 1000.0, "km/s"), temperature=temp, species={"H": dens})
    c = doppler.Scene(velocity=vel, temperature=temp, species={"H": dens})
    ra, rb, rc = (s.render(width=24, height=24) for s in (a, b, c))
    np.testing.assert_allclose(ra.xyz, rc.xyz, rtol=1e-5, atol=1e-12 * rc.xyz.max())
    np.testing.assert_allclose(rb.xyz, rc.xyz, rtol=1e-5, atol=1e-12 * rc.xyz.max())
    with pytest.raises(TypeError, match="velocity: cannot convert"):
        doppler.Scene(velocity=unyt.unyt_array(vel, "K"), species={"H": dens})


def test_mass_density_quantities_convert_as_scene_files_do(cli, tmp_path):
    unyt = pytest.importorskip("unyt")
    dens, vel, temp = _shell(16)
    rho = dens * 1e-24
    write_nrrd(tmp_path / "rho.nhdr", rho)
    doc = {"species": [{"name": "H", "lines": "H",
                        "density": {"file": "rho.nhdr", "unit": "g/cm3", "mass_fraction": 0.76, "scale": 1e-2}}]}
    (tmp_path / "s.json").write_text(json.dumps(doc))
    a = doppler.Scene.read(tmp_path / "s.json").render(width=16, height=16)
    b = doppler.Scene(species={"H": {"density": unyt.unyt_array(rho, "g/cm**3"), "mass_fraction": 0.76,
                                     "scale": 1e-2}}).render(width=16, height=16)
    np.testing.assert_array_equal(a.xyz, b.xyz)


def test_bad_scenes_raise_clearly():
    dens, vel, temp = _shell(8)
    with pytest.raises(ValueError, match="NaN"):
        doppler.Scene(species={"H": np.where(dens > 0.5, np.nan, dens)})
    with pytest.raises(ValueError, match="not a catalogue name"):
        doppler.Scene(species={"Fe": dens})
    with pytest.raises(ValueError, match=r"expected \[nx, ny, nz, 3\]"):
        doppler.Scene(velocity=vel[..., :2], species={"H": dens})
    s = doppler.Scene(species={"H": dens})
    with pytest.raises(blueshift.BlueshiftError, match="outside"):
        s.spectrum(99, 0, width=8, height=8)
    with pytest.raises(blueshift.BlueshiftError, match="unknown field"):
        s.render(width=8, height=8, bogus_option=1)
    with pytest.raises(blueshift.BlueshiftError, match="black body"):
        doppler.Scene(species={}).render()


def _uniform_ds(n=16):
    yt = pytest.importorskip("yt")
    dens, vel, temp = _shell(n)
    data = {
        ("gas", "density"): (dens * 1e-24, "g/cm**3"),
        ("gas", "temperature"): (temp, "K"),
        ("gas", "velocity_x"): (vel[..., 0] * 100.0, "cm/s"),
        ("gas", "velocity_y"): (vel[..., 1] * 100.0, "cm/s"),
        ("gas", "velocity_z"): (vel[..., 2] * 100.0, "cm/s"),
    }
    bbox = np.array([[0.0, 1.0]] * 3)
    return yt.load_uniform_grid(data, dens.shape, length_unit="Mpc", bbox=bbox, nprocs=1), (dens, vel, temp)


def _amr_ds(n=8):
    yt = pytest.importorskip("yt")
    grids = []
    for level, (le, re, dims) in enumerate([((0, 0, 0), (1, 1, 1), (n, n, n)), ((0.25, 0.25, 0.25), (0.75, 0.75, 0.75), (n, n, n))]):
        le, re = np.array(le, float), np.array(re, float)
        ax = [np.linspace(le[i], re[i], dims[i], endpoint=False) + (re[i] - le[i]) / dims[i] / 2 for i in range(3)]
        x, y, z = np.meshgrid(*ax, indexing="ij")
        r = np.sqrt((x - 0.5) ** 2 + (y - 0.5) ** 2 + (z - 0.5) ** 2)
        dens = np.exp(-((r / 0.2) ** 2)) * 1e-24 + 1e-28
        g = {"left_edge": le, "right_edge": re, "level": level, "dimensions": np.array(dims)}
        g[("gas", "density")] = (dens, "g/cm**3")
        g[("gas", "temperature")] = (np.full(dims, 9000.0), "K")
        g[("gas", "velocity_x")] = (-(y - 0.5) * 3e7, "cm/s")
        g[("gas", "velocity_y")] = ((x - 0.5) * 3e7, "cm/s")
        g[("gas", "velocity_z")] = (np.zeros(dims), "cm/s")
        grids.append(g)
    return yt.load_amr_grids(grids, [n, n, n], length_unit="Mpc", bbox=np.array([[0.0, 1.0]] * 3))


FIELDS = {"velocity": ("gas", "velocity"), "temperature": ("gas", "temperature"), "density": ("gas", "density")}


def _export_by_hand(folder, ds, level, dims):
    """The covering grid written with this file's own NRRD writer (not blueshift's) and a
    scene file by hand: the CLI's side of the from_yt comparison."""
    folder.mkdir()
    cg = ds.covering_grid(level=level, left_edge=ds.domain_left_edge,
                          dims=dims if dims is not None else ds.domain_dimensions * ds.refine_by**level)
    dds = np.asarray(cg.dds.to("code_length"))
    origin = np.asarray(cg.left_edge.to("code_length")) + dds / 2
    rho = np.asarray(cg[("gas", "density")].to("g/cm**3"))
    temp = np.asarray(cg[("gas", "temperature")].to("K"))
    vel = np.stack([np.asarray(cg[("gas", f"velocity_{a}")].to("km/s")) for a in "xyz"], axis=-1)
    write_nrrd(folder / "rho.nhdr", rho, dds, origin)
    write_nrrd(folder / "t.nhdr", temp, dds, origin)
    write_nrrd(folder / "v.nhdr", vel, dds, origin)
    doc = {"temperature": {"file": "t.nhdr", "unit": "K"},
           "velocity": {"file": "v.nhdr", "unit": "km/s"},
           "species": [{"name": "H I", "lines": "H",
                        "density": {"file": "rho.nhdr", "unit": "g/cm3", "mass_fraction": 0.76, "scale": 1e30}}]}
    (folder / "scene.json").write_text(json.dumps(doc))
    return folder / "scene.json"


@pytest.mark.parametrize("which", ["uniform", "amr"])
def test_from_yt_cube_equals_the_cli_cube_on_exported_files(cli, tmp_path, which):
    if which == "uniform":
        ds, _ = _uniform_ds()
        level, dims = 0, None
    else:
        ds = _amr_ds()
        level, dims = 1, (16, 16, 16)
    scene = blueshift.from_yt(ds, FIELDS, level=level, dims=dims, species={"H I": {"mass_fraction": 0.76, "lines": "H", "scale": 1e30}})
    cube = scene.cube(line="H-alpha", velocity_bins=(-100, 100, 24), axis="z", width=16, height=16, cell_domain=True)
    flags = ["--line", "H-alpha", "--velocity-bins", "-100:100:24", "--axis", "z", "--width", 16, "--height", 16,
             "--cell-domain"]
    # Against files written independently from yt's arrays (km/s there, cm/s through
    # from_yt): the same cube to float32 rounding.
    hand = _export_by_hand(tmp_path / "hand", ds, level, dims)
    cli("doppler", "--scene", hand, "--cube", tmp_path / "hand.fits", *flags)
    raw = (tmp_path / "hand.fits").read_bytes()
    ours = cube.fits_bytes()
    assert len(raw) == len(ours)
    header = 2880 * ((raw.index(b"END     ") // 2880) + 1)
    a = np.frombuffer(raw[header:header + cube.data.size * 4], dtype=">f4")
    b = np.frombuffer(ours[header:header + cube.data.size * 4], dtype=">f4")
    np.testing.assert_allclose(b, a, rtol=1e-4, atol=1e-5 * a.max())
    assert a.max() > 0
    # Through Scene.save the CLI reads the very arrays: byte for byte.
    path = scene.save(tmp_path / "export")
    cli("doppler", "--scene", path, "--cube", tmp_path / "c.fits", *flags)
    assert cube.fits_bytes() == (tmp_path / "c.fits").read_bytes()
    assert cube.data.shape == (16, 16, 24)
    assert cube.wcs["CTYPE3"] == "VRAD"
    cube.to_fits(tmp_path / "mine.fits")
    assert (tmp_path / "mine.fits").read_bytes() == (tmp_path / "c.fits").read_bytes()
    with pytest.raises(blueshift.BlueshiftError, match="exists"):
        cube.to_fits(tmp_path / "mine.fits")
    # A new file's mode is 0666 less the umask, as the CLI's; a FIFO is written into, never
    # replaced by a regular file.
    umask = os.umask(0o022)
    os.umask(umask)
    assert stat.S_IMODE(os.stat(tmp_path / "mine.fits").st_mode) == 0o666 & ~umask
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    # Without a reader: refused at once (an open would block, Ctrl-C included).
    with pytest.raises(blueshift.BlueshiftError, match="no one reads"):
        cube.to_fits(fifo, overwrite=True)
    # With one (whose open does not wait): written into. The cube's FITS fits the pipe's
    # buffer, so the write completes before anything is read.
    fd = os.open(fifo, os.O_RDONLY | os.O_NONBLOCK)
    try:
        cube.to_fits(fifo, overwrite=True)
        os.set_blocking(fd, True)
        got = b"".join(iter(lambda: os.read(fd, 1 << 16), b""))
    finally:
        os.close(fd)
    assert got == cube.fits_bytes() and len(got) < 1 << 16
    assert stat.S_ISFIFO(os.stat(fifo).st_mode)
    with pytest.raises(blueshift.BlueshiftError, match="folder"):
        cube.to_fits(tmp_path / "missing" / "c.fits")
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


def test_scene_save_names_files_safely_and_leaves_nothing_half_written(tmp_path):
    dens, vel, temp = _shell(8)
    s = doppler.Scene(species={"H I": {"density": dens, "lines": "H"}, "H_I": {"density": dens, "lines": "H"},
                               "../../escape": {"density": dens, "lines": "H"}})
    path = s.save(tmp_path / "out")
    names = sorted(p.name for p in (tmp_path / "out").iterdir())
    assert len(names) == 4 and "scene.json" in names, names
    assert not list(tmp_path.glob("escape*")) and not list(tmp_path.parent.glob("escape*"))
    a = s.render(width=8, height=8)
    b = doppler.Scene.read(path).render(width=8, height=8)
    np.testing.assert_array_equal(a.xyz, b.xyz)
    # A folder holding one of the names: nothing is written at all.
    (tmp_path / "busy").mkdir()
    (tmp_path / "busy" / "scene.json").write_text("{}")
    with pytest.raises(FileExistsError):
        s.save(tmp_path / "busy")
    assert sorted(p.name for p in (tmp_path / "busy").iterdir()) == ["scene.json"]


def _blob_ds(n=24):
    yt = pytest.importorskip("yt")
    ax = (np.arange(n) + 0.5) / n
    x, y, z = np.meshgrid(ax, ax, ax, indexing="ij")
    # Off centre in x and y, so a flip or a transpose shows.
    blob = np.exp(-(((x - 0.8) ** 2 + (y - 0.65) ** 2 + (z - 0.5) ** 2) / 0.006))
    zero = np.zeros(blob.shape)
    data = {("gas", "density"): (blob * 1e-24 + 1e-30, "g/cm**3"), ("gas", "temperature"): (zero + 8000.0, "K"),
            ("gas", "velocity_x"): (zero, "cm/s"), ("gas", "velocity_y"): (zero, "cm/s"),
            ("gas", "velocity_z"): (zero, "cm/s")}
    return yt.load_uniform_grid(data, blob.shape, length_unit="Mpc", bbox=np.array([[0.0, 1.0]] * 3), nprocs=1)


def _centroid(img):
    lum = np.asarray(img)[..., :3].sum(-1)
    i, j = np.indices(lum.shape)
    return np.array([(i * lum).sum(), (j * lum).sum()]) / lum.sum()


def test_blueshift_source_refuses_non_square_pixels():
    yt = pytest.importorskip("yt")
    from yt.visualization.volume_rendering.api import Scene

    from blueshift.yt import BlueshiftSource

    ds = _blob_ds(8)
    scene = blueshift.from_yt(ds, FIELDS, species={"H I": {"mass_fraction": 0.76, "lines": "H", "scale": 1e30}})
    sc = Scene()
    cam = sc.add_camera(ds, lens_type="plane-parallel")
    cam.resolution = (32, 16)
    cam.set_width(ds.domain_width)
    sc.add_source(BlueshiftSource(scene))
    with pytest.raises(ValueError, match="square pixels"):
        sc.render()
    cam.set_width(ds.arr([1.0, 0.5, 1.0], "code_length"))
    assert np.asarray(sc.render()).shape[:2] == (32, 16)


def test_blueshift_source_lands_where_yts_own_volume_rendering_does():
    yt = pytest.importorskip("yt")
    from yt.visualization.volume_rendering.api import Scene

    from blueshift.yt import BlueshiftSource

    ds = _blob_ds()
    # yt's own renderer of the same density, as the independent reference.
    ref = yt.create_scene(ds, ("gas", "density"), lens_type="plane-parallel")
    cam = ref.camera
    cam.resolution = (32, 32)
    cam.set_width(ds.domain_width)
    cam.set_position(ds.arr([0.5, 0.5, 3.0], "code_length"), north_vector=[0, 1, 0])
    cam.set_focus(ds.arr([0.5, 0.5, 0.5], "code_length"))
    im_yt = np.asarray(ref.render())
    scene = blueshift.from_yt(ds, FIELDS, species={"H I": {"mass_fraction": 0.76, "lines": "H", "scale": 1e30}})
    sc = Scene()
    sc.camera = cam
    src = BlueshiftSource(scene)
    sc.add_source(src)
    im = np.asarray(sc.render())
    assert im.shape == im_yt.shape == (32, 32, 4)
    np.testing.assert_allclose(_centroid(im), _centroid(im_yt), atol=1.5)
    # What yt shows is blueshift's own picture of the camera, [x, row from the top].
    rgb = np.asarray(src.last.rgb, dtype=np.float64) / 255.0
    lin = np.where(rgb <= 0.04045, rgb / 12.92, ((rgb + 0.055) / 1.055) ** 2.4)
    np.testing.assert_allclose(im[..., :3], np.transpose(lin, (1, 0, 2)), atol=1e-12)
    # And blueshift's picture has the blob at x = 0.8 (right), y = 0.65 (up).
    row, col = np.unravel_index(np.argmax(rgb.sum(-1)), rgb.shape[:2])
    assert abs(col - 0.8 * 32) < 2 and abs(row - 0.35 * 32) < 2


def test_the_viewer_serves_a_python_scene_on_loopback():
    import urllib.error
    import urllib.request

    dens, vel, temp = _shell(8)
    s = doppler.Scene(velocity=vel, temperature=temp, species={"H": dens})
    with s.view(width=32, height=32) as v:
        assert v.url.startswith("http://127.0.0.1:")
        page = urllib.request.urlopen(v.url, timeout=10).read().decode()
        assert "<html" in page.lower()
        bad = v.url.rsplit("/", 2)[0] + "/" + "0" * 32 + "/"
        with pytest.raises(urllib.error.HTTPError) as e:
            urllib.request.urlopen(bad, timeout=10)
        assert e.value.code == 404
        assert f'src="{v.url}"' in v._repr_html_()
    assert not v.running


def test_a_trace_ends_in_the_picked_spectrum():
    dens, vel, temp = _shell(12)
    s = doppler.Scene(velocity=vel, temperature=temp, species={"H": dens})
    steps = s.trace(6, 6, width=12, height=12)
    assert len(steps) > 3
    ts = [st.t for st in steps]
    assert ts == sorted(ts) or ts == sorted(ts, reverse=True)
    w, v = s.spectrum(6, 6, width=12, height=12)
    grid = np.linspace(640, 670, 601)
    np.testing.assert_allclose(np.interp(grid, steps[-1].wavelengths, steps[-1].values), np.interp(grid, w, v),
                               rtol=1e-9, atol=1e-12 * v.max())


@needs_enzo
def test_yt_style_cm_per_s_gives_the_scene_files_km_per_s_picture():
    unyt = pytest.importorskip("unyt")
    vol = {n: blueshift.Volume.read(ENZO_DATA / f) for n, f in [
        ("rho", "density_gcm3_64x64x64_f32le.nhdr"), ("t", "temperature_K_64x64x64_f32le.nhdr"),
        ("v", "velocity_kms_64x64x64x3_f32le.nhdr")]}
    rho = unyt.unyt_array(vol["rho"].array(), "g/cm**3")
    # What yt hands over: velocities in cm/s, float64.
    v_cms = unyt.unyt_array(vol["v"].array().astype(np.float64) * 1e5, "cm/s")
    ours = doppler.Scene(
        velocity=v_cms, temperature=unyt.unyt_array(vol["t"].array(), "K"),
        blackbody={"density": rho, "mass_fraction": 0.76, "scale": 1e9},
        species={"H I": {"density": rho, "mass_fraction": 0.76, "lines": "H"},
                 "He I": {"density": rho, "mass_fraction": 0.24, "lines": "He"}},
        spacing=vol["rho"].spacing, origin=vol["rho"].origin, subtract_mean_velocity=True,
    ).render(width=48, height=48)
    ref = doppler.Scene.read(ENZO).render(width=48, height=48)
    np.testing.assert_allclose(ours.xyz, ref.xyz, rtol=2e-5, atol=1e-6 * ref.xyz.max())
    assert np.mean(ours.rgb == ref.rgb) > 0.99


@needs_enzo
def test_from_yt_on_the_original_enzo_snapshot_gives_the_scene_files_picture():
    yt = pytest.importorskip("yt")
    pytest.importorskip("h5py")
    ds = yt.load(str(ENZO_DATA / "original" / "moving7_0010"))
    scene = blueshift.from_yt(
        ds, {"velocity": ("gas", "velocity"), "temperature": ("gas", "temperature"),
             "density": ("gas", "density"), "blackbody": ("gas", "density")},
        level=2, dims=(64, 64, 64),
        species={"H I": {"mass_fraction": 0.76, "lines": "H"}, "He I": {"mass_fraction": 0.24, "lines": "He"}},
        blackbody={"mass_fraction": 0.76, "scale": 1e9}, subtract_mean_velocity=True)
    ours = scene.render(width=48, height=48)
    ref = doppler.Scene.read(ENZO).render(width=48, height=48)
    # The files are yt's float32 covering grids (velocity in km/s); yt hands float64 cm/s.
    np.testing.assert_allclose(ours.xyz, ref.xyz, rtol=2e-5, atol=1e-6 * ref.xyz.max())


def test_astropy_quantities_convert_like_unyt_ones():
    u = pytest.importorskip("astropy.units")
    unyt = pytest.importorskip("unyt")
    dens, vel, temp = _shell(12)
    rho = dens * 1e-24
    a = doppler.Scene(velocity=(vel / 1e3) * u.km / u.s, temperature=temp * u.K,
                      species={"H": {"density": rho * u.g / u.cm**3, "mass_fraction": 0.76}}).render(width=12, height=12)
    b = doppler.Scene(velocity=unyt.unyt_array(vel / 1e3, "km/s"), temperature=unyt.unyt_array(temp, "K"),
                      species={"H": {"density": unyt.unyt_array(rho, "g/cm**3"), "mass_fraction": 0.76}}).render(width=12, height=12)
    np.testing.assert_array_equal(a.xyz, b.xyz)
    # A number density in m^-3 is the cm^-3 one times 1e6.
    c = doppler.Scene(species={"H": dens * 1e6 / u.m**3}).render(width=12, height=12)
    d = doppler.Scene(species={"H": dens}).render(width=12, height=12)
    np.testing.assert_allclose(c.xyz, d.xyz, rtol=1e-6)
    assert blueshift.spectrum.doppler_shift(3000 * u.km / u.s) == pytest.approx(1 + 3e6 / C, rel=1e-15)
    with pytest.raises(TypeError, match="cannot convert"):
        doppler.Scene(velocity=vel * u.K, species={"H": dens})


def test_gpu_doppler_render_equals_the_clis(cli, tmp_path):
    import os

    dens, vel, temp = _shell(16)
    scene = doppler.Scene(velocity=vel, temperature=temp, blackbody={"density": dens, "scale": 0.02},
                          species={"H": {"density": dens, "scale": 5.0}})
    try:
        g = scene.render(width=24, height=24, device="gpu", gpu_precision="f32")
    except blueshift.BlueshiftError as e:
        if os.environ.get("BLUESHIFT_REQUIRE_GPU_TESTS") == "1":
            raise
        pytest.skip(f"no wgpu adapter: {e}")
    assert g.backend == "gpu"
    path = scene.save(tmp_path / "s")
    cli("doppler", "--scene", path, "--width", 24, "--height", 24, "--device", "gpu", "--gpu-precision", "f32",
        "--out", tmp_path / "g.exr")
    np.testing.assert_array_equal(g.xyz.astype(np.float32), blueshift.read_hdr(tmp_path / "g.exr"))
    c = scene.render(width=24, height=24)
    assert c.backend == "cpu"
    np.testing.assert_allclose(g.xyz, c.xyz, rtol=2e-3, atol=1e-4 * c.xyz.max())


def test_bricked_scene_reads_out_of_core_with_levels_equal_to_the_cli(cli, tmp_path):
    cli("synth", "hydrogen-shell", tmp_path / "s.bsv", "--res", 32, "--brick", 8)
    scene = {
        "velocity": {"files": [f"s_velocity_m_per_s_{a}.bsv" for a in "xyz"]},
        "species": [{"name": "hydrogen", "lines": "H", "density": {"file": "s.bsv"}}],
    }
    path = tmp_path / "scene.json"
    path.write_text(json.dumps(scene))
    s = doppler.Scene.read(path, cache_mb=1)
    assert s.levels == [(32, 32, 32), (16, 16, 16), (8, 8, 8)]
    r = s.render(width=24, height=24)
    cli("doppler", "--scene", path, "--width", 24, "--height", 24, "--cache-mb", 1, "--out", tmp_path / "b.exr")
    np.testing.assert_array_equal(r.xyz.astype(np.float32), blueshift.read_hdr(tmp_path / "b.exr"))
    coarse = s.at_level(2).render(width=24, height=24)
    cli("doppler", "--scene", path, "--width", 24, "--height", 24, "--lod", 2, "--out", tmp_path / "c.exr")
    np.testing.assert_array_equal(coarse.xyz.astype(np.float32), blueshift.read_hdr(tmp_path / "c.exr"))
    assert not np.array_equal(coarse.xyz, r.xyz)
    with pytest.raises(blueshift.BlueshiftError):
        s.at_level(3)
    with pytest.raises(blueshift.BlueshiftError):
        doppler.Scene.read(path, cache_mb=0)


def test_a_moving_observer_sees_the_doppler_factor_of_its_direction():
    # A still medium (no velocity): the observer flying head-on into the view at beta sees
    # H-alpha at lambda0 / sqrt((1 + b) / (1 - b)); beta 0 changes no byte of the image.
    dens, vel, temp = _shell(omega=0.0)
    scene = doppler.Scene(velocity=vel, temperature=temp, species={"H": dens})
    lam0 = [w for w, _ in blueshift.spectrum.catalogue("H") if 650 < w < 660][0]
    b = 0.2
    w, v = scene.spectrum(12, 12, width=24, height=24, doppler="relativistic", line_width=0.05, beta=b)
    d = math.sqrt((1 + b) / (1 - b))
    win = (w > lam0 / d - 3) & (w < lam0 / d + 3)
    cen = np.trapezoid(w[win] * v[win], w[win]) / np.trapezoid(v[win], w[win])
    assert abs(cen - lam0 / d) < 1e-3
    a = scene.render(width=16, height=16)
    z = scene.render(width=16, height=16, beta=0.0)
    np.testing.assert_array_equal(a.xyz, z.xyz)
    with pytest.raises(Exception, match="beta"):
        scene.render(width=16, height=16, beta=1.0)


def test_exposure_scale_takes_a_number_as_the_cli_does():
    s = doppler.Scene(species={"H": np.ones((8, 8, 8), np.float32)})
    a = s.render(16, 16, exposure_scale=1.5)
    b = s.render(16, 16, exposure_scale="1.5")
    np.testing.assert_array_equal(np.asarray(a.rgb), np.asarray(b.rgb))
    c = s.render(16, 16, exposure_scale=3)
    assert not np.array_equal(np.asarray(a.rgb), np.asarray(c.rgb))
    # A bool is no exposure (True once passed as 1.0).
    with pytest.raises(TypeError, match="not a bool"):
        s.render(16, 16, exposure_scale=True)


def test_results_beyond_the_memory_budget_are_refused_before_work(monkeypatch):
    s = doppler.Scene(species={"H": np.ones((4, 4, 4), np.float32)})
    monkeypatch.setenv("BLUESHIFT_MAX_MEMORY", "300M")
    with pytest.raises(blueshift.BlueshiftError, match="memory budget"):
        s.cube(velocity_bins=(-100, 100, 1000), width=512, height=512)
    monkeypatch.setenv("BLUESHIFT_MAX_MEMORY", "50M")
    with pytest.raises(blueshift.BlueshiftError, match="memory budget"):
        s.render(4096, 4096)
    assert s.render(8, 8).rgb.shape == (8, 8, 3)
