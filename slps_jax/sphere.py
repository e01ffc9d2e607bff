r"""Pictures on the sphere: a state of Euler–Zeitlin on su(N)* drawn as its vorticity field
(`plot`), orthographic or on a latitude–longitude map, and an animation of a run (`animate`),
to MP4 where ffmpeg is installed and to GIF (Pillow, which matplotlib brings) otherwise.

The field is `zeitlin.field` of the state's coefficients `zeitlin.mat2shr(W)` on a grid
(`zeitlin.grid`), in the state's units: the vorticity in 1/s (the library's time is in
seconds). matplotlib is imported when a picture is drawn.
"""

from __future__ import annotations

import os
import warnings

import numpy as np

from . import zeitlin

__all__ = ["animate", "plot"]

_PROJECTIONS = ("orthographic", "latlon")
_LABEL = r"vorticity $\omega$ (1/s)"


def _check(projection, center):
    if projection not in _PROJECTIONS:
        raise ValueError(f"projection must be one of {_PROJECTIONS}, got {projection!r}.")
    lat, lon = (float(c) for c in center)
    if not -90.0 <= lat <= 90.0:
        raise ValueError(f"center's latitude must be in [-90, 90] degrees, got {lat}.")
    return lat, lon


def _states(W):
    """`W` as a NumPy array of `(..., N, N)` states, checked."""
    W = np.asarray(W)
    if W.ndim < 2 or W.shape[-1] != W.shape[-2] or W.shape[-1] < 2:
        raise ValueError(f"a state of su(N)* is an (N, N) matrix, got shape {W.shape}.")
    if not np.all(np.isfinite(W)):
        raise ValueError("the state is not finite (a failed sample?): nothing to draw.")
    return W


def _fields(W, resolution):
    """The vorticity of the states `W` on `zeitlin.grid(resolution)`: `(theta, phi, f)`."""
    N = W.shape[-1]
    n_lat = max(2 * N, 64) if resolution is None else int(resolution)
    if n_lat < 4:
        raise ValueError(f"resolution must be at least 4 colatitudes, got {resolution!r}.")
    theta, phi = zeitlin.grid(n_lat)
    return theta, phi, np.asarray(zeitlin.field(zeitlin.mat2shr(W), theta, phi))


def _edges(n):
    """The `n + 1` edges of `n` equal cells on [0, 1) whose first centre is at 0 (the
    longitudes of `zeitlin.grid`) or at half a cell (its colatitudes): as fractions."""
    return (np.arange(n + 1) - 0.5) / n


def _mesh(theta, phi, projection, center):
    """Cell corners `(x, y)` of the grid and the cells drawn (`visible`), for pcolormesh."""
    n_lat, n_lon = theta.size, phi.size
    t_edges = np.clip(np.pi * (np.arange(n_lat + 1) / n_lat), 0.0, np.pi)
    p_edges = 2 * np.pi * _edges(n_lon)
    if projection == "latlon":
        lon = np.degrees(p_edges)
        lat = 90.0 - np.degrees(t_edges)
        x, y = np.meshgrid(lon, lat)
        return x, y, np.ones((n_lat, n_lon), bool)
    lat0, lon0 = np.radians(center[0]), np.radians(center[1])

    def view(t, p):  # the point of the sphere in the viewer's frame: depth, right, up
        x, y, z = np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)
        # rotate about z by -lon0, then about y so that the centre is the depth axis
        x, y = x * np.cos(lon0) + y * np.sin(lon0), -x * np.sin(lon0) + y * np.cos(lon0)
        depth = x * np.cos(lat0) + z * np.sin(lat0)
        up = -x * np.sin(lat0) + z * np.cos(lat0)
        return depth, y, up

    tc, pc = np.meshgrid(t_edges, p_edges, indexing="ij")
    _, right, up = view(tc, pc)
    depth, _, _ = view(*np.meshgrid(theta, phi, indexing="ij"))
    return right, up, depth > 0


def plot(
    W,
    ax=None,
    *,
    projection="orthographic",
    center=(30.0, 0.0),
    resolution=None,
    vmax=None,
    cmap="RdBu_r",
    colorbar=True,
    title=None,
):
    r"""Draw a state's vorticity on the sphere, in one call.

    **Arguments:**

    - `W`: one state, an `(N, N)` skew-Hermitian matrix (an `EulerZeitlin` state).
    - `ax`: the matplotlib axes to draw in (default: a new figure's).
    - `projection`: `"orthographic"` (default: the hemisphere facing `center`, as seen
      from far away, the limb drawn) or `"latlon"` (a map: longitude 0 … 360 degrees,
      latitude −90 … 90).
    - `center`: `(latitude, longitude)` in degrees of the point facing the viewer
      (orthographic; default `(30, 0)`).
    - `resolution`: the grid's colatitudes (default `max(2N, 64)`; twice as many
      longitudes).
    - `vmax`: the colour scale, symmetric, $\pm$`vmax` (default: the field's largest
      $|\omega|$).
    - `cmap`, `colorbar` (a colour bar labelled in the field's units, 1/s), `title`.

    **Returns:** the `QuadMesh` drawn (its `.axes` the axes, `.colorbar` the colour bar or
    `None`).
    """
    W = _states(W)
    if W.ndim != 2:
        raise ValueError(f"plot draws one state (N, N); got shape {W.shape} (animate draws runs).")
    center = _check(projection, center)
    theta, phi, f = _fields(W, resolution)
    return _draw(ax, f, theta, phi, projection, center, vmax, cmap, colorbar, title)


def _draw(ax, f, theta, phi, projection, center, vmax, cmap, colorbar, title):
    if ax is None:
        from matplotlib.figure import Figure

        ax = Figure(figsize=(5.0, 4.2) if projection == "orthographic" else (8.0, 4.0)).subplots()
    x, y, visible = _mesh(theta, phi, projection, center)
    lim = float(np.max(np.abs(f))) if vmax is None else float(vmax)
    lim = lim if lim > 0 else 1.0
    mesh = ax.pcolormesh(
        x, y, np.ma.masked_where(~visible, f), cmap=cmap, vmin=-lim, vmax=lim, shading="flat"
    )
    if projection == "orthographic":
        s = np.linspace(0.0, 2 * np.pi, 361)
        ax.plot(np.cos(s), np.sin(s), color="0.3", lw=0.8)
        ax.set_aspect("equal")
        ax.set_axis_off()
    else:
        ax.set_xlim(x.min(), x.max())
        ax.set_ylim(-90.0, 90.0)
        ax.set_xlabel("longitude (deg)")
        ax.set_ylabel("latitude (deg)")
    if title is not None:
        ax.set_title(title)
    mesh.colorbar = ax.figure.colorbar(mesh, ax=ax, label=_LABEL) if colorbar else None
    return mesh


def animate(
    states,
    path,
    *,
    times=None,
    sample=0,
    fps=10,
    projection="orthographic",
    center=(30.0, 0.0),
    resolution=None,
    vmax=None,
    cmap="RdBu_r",
):
    r"""Write an animation of a run's vorticity on the sphere, one frame per state.

    **Arguments:**

    - `states`: `(n_frames, N, N)` states; or a stored run (`open_run(path)`, or what
      `simulate_to_store` returns), whose saved states of sample `sample` are the frames
      and its `.times` their times.
    - `path`: the file written: `.mp4` (needs ffmpeg; where none is installed, a
      `RuntimeWarning` says so and the animation is written as GIF beside it, the suffix
      changed) or `.gif` (Pillow).
    - `times`: the frames' times in seconds, for their titles (default: the stored run's,
      or none).
    - `sample`: which sample of a stored run (default 0).
    - `fps`: frames per second.
    - `projection`, `center`, `resolution`, `cmap`: as for `plot`; `vmax`: the colour
      scale, shared by every frame (default: the largest $|\omega|$ of the run).

    **Returns:** the path written.
    """
    from matplotlib import animation
    from matplotlib.figure import Figure

    if hasattr(states, "read") and hasattr(states, "fields"):
        if "state" not in states.fields:
            raise ValueError(
                "animate: this stored run kept no states (Store(..., save_states=False))."
            )
        times = states.times if times is None else times
        states = states.read("state")[:, sample]
    W = _states(states)
    if W.ndim != 3:
        raise ValueError(f"animate: states must be (n_frames, N, N), got shape {W.shape}.")
    if times is not None and len(times) != W.shape[0]:
        raise ValueError(f"animate: {len(times)} times for {W.shape[0]} frames.")
    if not (isinstance(fps, int | float) and fps > 0):
        raise ValueError(f"animate: fps must be a positive number, got {fps!r}.")
    path = os.fspath(path)
    suffix = os.path.splitext(path)[1].lower()
    if suffix not in (".mp4", ".gif"):
        raise ValueError(f"animate: path must end in .mp4 or .gif, got {path!r}.")
    if suffix == ".mp4" and not animation.writers.is_available("ffmpeg"):
        gif = os.path.splitext(path)[0] + ".gif"
        warnings.warn(
            f"animate: no MP4 writer (ffmpeg is not installed); writing {gif} instead.",
            RuntimeWarning,
            stacklevel=2,
        )
        path, suffix = gif, ".gif"
    center = _check(projection, center)
    theta, phi, f = _fields(W, resolution)
    lim = float(np.max(np.abs(f))) if vmax is None else float(vmax)
    fig = Figure(figsize=(5.0, 4.2) if projection == "orthographic" else (8.0, 4.0))
    ax = fig.subplots()

    def title(k):
        return None if times is None else f"t = {float(times[k]):.3g} s"

    mesh = _draw(ax, f[0], theta, phi, projection, center, lim, cmap, True, title(0))
    visible = _mesh(theta, phi, projection, center)[2]

    def frame(k):
        mesh.set_array(np.ma.masked_where(~visible, f[k]))
        if times is not None:
            ax.set_title(f"t = {float(times[k]):.3g} s")
        return (mesh,)

    movie = animation.FuncAnimation(fig, frame, frames=W.shape[0], blit=False)
    writer = (
        animation.FFMpegWriter(fps=fps) if suffix == ".mp4" else animation.PillowWriter(fps=fps)
    )
    movie.save(path, writer=writer)
    return path
