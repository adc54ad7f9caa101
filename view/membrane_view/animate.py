"""`membrane animate`: a film scene, or a scripted poke on a live scene, as a GIF or an MP4.

The frames come from the server (``Client.query`` for films, a ``Session`` for live scenes) and
are drawn with matplotlib: a heat map for a 2-D lattice, a curve for a rope. Pillow writes GIFs;
MP4 needs ffmpeg on the PATH (a one-line message when it is not there).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from membrane_client.client import Client
from membrane_client.frame import SceneInfo
from membrane_client.session import Probe
from membrane_errors import UserError

__all__ = ["HOLD_S", "RAMP_S", "RING_S", "Clip", "film_clip", "poke_clip", "write_clip"]

RAMP_S, HOLD_S, RING_S = 0.2, 0.2, 0.4  # the scripted poke: press, hold, ring after release


@dataclass
class Clip:
    info: SceneInfo
    times: np.ndarray  # (m,) simulation times
    frames: np.ndarray  # (m, *shape) displacements
    force: np.ndarray | None = None  # (m,) the probe's force on a live scene


def check_output(path: Path) -> str:
    """The writer for ``path`` ('pillow' or 'ffmpeg'); UserError (one line) when unusable."""
    from matplotlib import animation

    suffix = path.suffix.lower()
    if suffix not in (".gif", ".mp4"):
        raise UserError(f"--out must end in .gif or .mp4, got {path.name!r}")
    if not path.parent.is_dir():
        raise UserError(f"--out: no such directory {str(path.parent)!r}")
    if suffix == ".mp4" and not animation.FFMpegWriter.isAvailable():
        raise UserError("an .mp4 needs ffmpeg on the PATH (not found): install it, or write a .gif")
    return "pillow" if suffix == ".gif" else "ffmpeg"


def film_clip(client: Client, scene: str | None, fps: float, speed: float) -> Clip:
    """The film's frames at ``fps`` frames per second of animation, ``speed`` x real time."""
    info = client.describe(scene)
    count = max(2, int(info.duration / speed * fps) + 1)
    times = info.start_offset + np.minimum(np.arange(count) * speed / fps, info.duration)
    frames = np.stack([client.query(float(t), scene).z for t in times])
    return Clip(info, times, frames)


def poke_clip(client: Client, scene: str | None, fps: float, speed: float, depth: float) -> Clip:
    """A probe at the centre ramps to ``depth``, holds, lifts off; the tissue rings."""
    with client.session(scene) as session:
        info = session.info
        assert info is not None
        points = np.asarray(info.points, dtype=np.float64)
        centre = tuple(float(v) for v in (points.min(axis=0) + points.max(axis=0)) / 2)
        extent = float(np.max(points.max(axis=0) - points.min(axis=0)))
        radius = max(0.05 * extent, float(info.live.get("min_radius", 0.0)))
        total = RAMP_S + HOLD_S + RING_S
        steps = round(total / info.dt)
        every = max(1, round(speed / fps / info.dt))  # steps between two frames
        times, frames, force = [], [], []
        for k in range(steps):
            t = (k + 1) * info.dt
            d = depth * min(1.0, t / RAMP_S) if t <= RAMP_S + HOLD_S else None
            probes = [] if d is None else [Probe(centre, d, radius)]
            want = (k + 1) % every == 0
            frame = session.step(probes=probes, frame=want)
            if want:
                assert frame.z is not None
                times.append(frame.t)
                frames.append(frame.z)
                force.append(frame.probes[0].force if frame.probes else 0.0)
    return Clip(info, np.asarray(times), np.stack(frames), np.asarray(force))


def write_clip(clip: Clip, out: Path, writer: str, fps: float) -> int:
    """Draw ``clip`` and write it; returns the number of frames written."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib import animation
    from matplotlib.artist import Artist

    info, frames = clip.info, clip.frames
    peak = float(np.max(np.abs(frames))) or 1e-12
    fig, ax = plt.subplots(figsize=(5, 4.2), dpi=80)
    if len(info.shape) == 2:
        points = np.asarray(info.points)
        extent = (points[:, 0].min(), points[:, 0].max(), points[:, 1].min(), points[:, 1].max())
        image = ax.imshow(
            frames[0].T,
            origin="lower",
            extent=extent,
            cmap="RdBu_r",
            vmin=-peak,
            vmax=peak,
            interpolation="bilinear",
        )
        fig.colorbar(image, ax=ax, label="displacement")

        def update(m: int) -> list[Artist]:
            image.set_data(frames[m].T)
            ax.set_title(_title(clip, m))
            return [image]
    else:
        x = np.asarray(info.points)[:, 0]
        (line,) = ax.plot(x, frames[0], color="tab:orange", lw=2)
        ax.set_ylim(-1.1 * peak, 1.1 * peak)
        ax.set_xlabel("x")
        ax.set_ylabel("displacement")

        def update(m: int) -> list[Artist]:
            line.set_ydata(frames[m])
            ax.set_title(_title(clip, m))
            return [line]

    movie = animation.FuncAnimation(fig, update, frames=len(frames), blit=False)
    writers = {"pillow": animation.PillowWriter, "ffmpeg": animation.FFMpegWriter}
    movie.save(str(out), writer=writers[writer](fps=fps))
    plt.close(fig)
    return len(frames)


def _title(clip: Clip, m: int) -> str:
    text = f"{clip.info.name}  t = {clip.times[m]:.3f} s"
    if clip.force is not None:
        text += f"  force = {clip.force[m]:.3g}"
    return text
