"""Pictures on the sphere (`sj.sphere`): what is drawn is the state's field, checked on a
single harmonic against its closed form; the orthographic view shows exactly the hemisphere
facing the viewer; an animation is written, as GIF where no MP4 writer is installed, with a
warning that says so."""

import warnings

import jax
import numpy as np
import pytest
from matplotlib import animation

import slps_jax as sj
from slps_jax import zeitlin as z

N = 6


def _t10(amplitude=1.0):
    """The state whose vorticity is amplitude * Y_10 = amplitude * sqrt(3) cos(theta)."""
    om = np.zeros(N * N)
    om[z.elm2ind(1, 0)] = amplitude
    return z.shr2mat(om, N)


def test_the_map_draws_the_field_in_its_units():
    mesh = sj.sphere.plot(_t10(2.0), projection="latlon", resolution=12, title="t = 0")
    theta, _ = z.grid(12)
    want = 2.0 * np.sqrt(3.0) * np.cos(theta)[:, None] * np.ones((1, 24))
    np.testing.assert_allclose(np.asarray(mesh.get_array()).reshape(12, 24), want, atol=1e-12)
    assert mesh.colorbar.ax.get_ylabel() == r"vorticity $\omega$ (1/s)"
    assert mesh.axes.get_title() == "t = 0"
    assert mesh.get_clim() == pytest.approx(
        (-2 * np.sqrt(3) * np.cos(theta[0]),) * 2 * np.r_[1, -1]
    )


def test_the_orthographic_view_shows_the_hemisphere_facing_the_viewer():
    theta, _ = z.grid(16)
    north = sj.sphere.plot(_t10(), center=(90.0, 0.0), resolution=16, colorbar=False)
    hidden = np.ma.getmaskarray(north.get_array()).reshape(16, 32)
    np.testing.assert_array_equal(hidden, np.broadcast_to((theta > np.pi / 2)[:, None], (16, 32)))
    assert north.colorbar is None
    # seen from the equator at longitude 95: the half of longitudes 5 ... 185
    east = sj.sphere.plot(_t10(), center=(0.0, 95.0), resolution=16)
    _, phi = z.grid(16)
    shown = ~np.ma.getmaskarray(east.get_array()).reshape(16, 32)
    facing = np.cos(phi - np.radians(95.0)) > 0
    np.testing.assert_array_equal(shown, np.broadcast_to(facing, (16, 32)))


@pytest.mark.parametrize(
    "bad, match",
    [
        (dict(W=np.zeros((2, N, N))), "one state"),
        (dict(W=np.zeros(5)), r"\(N, N\) matrix"),
        (dict(W=np.full((N, N), np.nan)), "not finite"),
        (dict(projection="mercator"), "projection"),
        (dict(center=(100.0, 0.0)), "latitude"),
    ],
)
def test_plot_refuses_bad_input(bad, match):
    kwargs = dict(W=_t10())
    kwargs.update(bad)
    with pytest.raises(ValueError, match=match):
        sj.sphere.plot(kwargs.pop("W"), **kwargs)


def test_animation_of_states_and_of_a_stored_run(tmp_path, monkeypatch):
    from PIL import Image

    w0 = z.shr2mat(np.r_[0.0, np.random.default_rng(0).normal(size=N * N - 1)], N)
    system = sj.EulerZeitlin(N, c=0.3)
    run = sj.simulate_to_store(
        system,
        w0,
        sj.Store(str(tmp_path / "run.zarr"), progress=False),
        t1=0.2,
        dt=0.02,
        n_samples=2,
        key=jax.random.key(0),
        save_every=2,
    )
    path = sj.sphere.animate(run, tmp_path / "run.gif", sample=1, fps=5, resolution=8)
    with Image.open(path) as gif:
        assert gif.format == "GIF" and gif.n_frames == 6
    # no ffmpeg: said, and written as GIF beside the path asked for
    monkeypatch.setattr(animation.writers, "is_available", lambda name: False)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        path = sj.sphere.animate(
            run.read("state")[:3, 0], tmp_path / "movie.mp4", projection="latlon", resolution=8
        )
    assert path == str(tmp_path / "movie.gif")
    assert any("no MP4 writer (ffmpeg is not installed)" in str(w.message) for w in caught)
    with Image.open(path) as gif:
        assert gif.n_frames == 3
    with pytest.raises(ValueError, match=r"\.mp4 or \.gif"):
        sj.sphere.animate(run, tmp_path / "movie.avi")
    with pytest.raises(ValueError, match="2 times for 3 frames"):
        sj.sphere.animate(run.read("state")[:3, 0], tmp_path / "x.gif", times=[0.0, 1.0])
