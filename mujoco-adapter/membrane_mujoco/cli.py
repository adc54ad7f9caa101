"""`membrane mujoco MODEL.xml --scene S --tool NAME`: a MuJoCo model coupled to a live session.

This module imports with the core dependencies only; ``mujoco`` (the ``mujoco`` extra) is
imported when the command runs.

The model's tool geoms press the tissue (its grasp sites hold it) each session step and feel
its force back
(``coupler``); its controls follow the schedule written in the model (``schedule``), for
``--seconds`` or the schedule's length. With ``--out FILE`` the run is rendered offscreen to a
PNG (the frame of the largest contact force), GIF or MP4; without it, a passive viewer opens
where a display exists, and the run is headless otherwise. Progress (time, force and depth per
tool, force and height per grasp) every simulated second; at the end the time per coupled step
beside the session's and MuJoCo's shares.

Exit codes: 0 the run ended; 1 the server did not answer or refused a step; 2 bad input (the
model file, a tool geom that cannot press, a timestep that does not divide the scene's dt).
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path
from typing import Any

from membrane_cli.arguments import bounded_float, bounded_int
from membrane_cli.connection import add_connection_arguments, connect
from membrane_client.errors import UserError

__all__ = ["add_mujoco"]

POSITIVE = bounded_float(0.0, exclusive=True)


def add_mujoco(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Register `membrane mujoco`."""
    parser = subparsers.add_parser(
        "mujoco",
        help="couple a MuJoCo model's tools to a live scene (needs the 'mujoco' extra)",
        description=(
            "Load a MuJoCo model (MJCF), add the live scene's lattice to it as visual spheres, "
            "and step both: each session step presses the named tool geoms (spheres or "
            "cylinders) into the tissue and applies the contact forces back to their bodies, "
            "MuJoCo stepping in substeps of the scene's dt. Controls follow the model's "
            "<custom><numeric name='membrane_schedule'> rows. Needs the 'mujoco' extra."
        ),
    )
    parser.add_argument("model", type=Path, help="the MJCF file")
    add_connection_arguments(parser, timeout=2.0, curve=False)
    parser.add_argument("--scene", required=True, help="the live scene (skin-patch, ...)")
    parser.add_argument(
        "--tool", action="append", default=[], metavar="GEOM", help="a tool geom (repeatable)"
    )
    parser.add_argument(
        "--grasp", action="append", default=[], metavar="SITE", help="a grasp site (repeatable)"
    )
    parser.add_argument(
        "--seconds", type=POSITIVE, default=None, help="simulated time (default: the schedule's)"
    )
    parser.add_argument("--out", type=Path, default=None, help="render to FILE.png/.gif/.mp4")
    parser.add_argument("--fps", type=POSITIVE, default=25.0, help="frames per simulated second")
    parser.add_argument("--width", type=bounded_int(16, 4096), default=480)
    parser.add_argument("--height", type=bounded_int(16, 4096), default=360)
    parser.add_argument(
        "--camera", default=None, help="a camera of the model (default: its first, else free)"
    )
    parser.add_argument(
        "--force-scale", type=POSITIVE, default=None, help="N per force unit (dimensionless scenes)"
    )
    parser.set_defaults(handler=_run_mujoco)


def _run_mujoco(args: argparse.Namespace) -> int:
    if args.out is not None:  # before mujoco is imported: it picks its OpenGL backend then
        os.environ.setdefault("MUJOCO_GL", "egl")  # headless: Mesa's EGL, no display needed
    import mujoco
    import numpy as np

    from membrane_mujoco.coupler import Coupler
    from membrane_mujoco.schedule import Schedule

    try:
        spec = mujoco.MjSpec.from_file(str(args.model))
    except ValueError as error:  # MuJoCo's parse errors: the file and its line
        raise UserError(f"{args.model}: {error}") from None
    with connect(args, args.scene) as client, client.session(args.scene) as session:
        coupler = Coupler(spec, session, args.tool, grasps=args.grasp, force_scale=args.force_scale)
        schedule = Schedule.of(coupler.model)
        seconds = args.seconds or (schedule.duration if schedule is not None else 2.0)
        steps = max(1, round(seconds / coupler.info.dt))
        recorder = _recorder(args, coupler.model) if args.out is not None else None
        viewer = None if recorder is not None or not _has_display() else _viewer(coupler)
        totals = _Totals()
        every = max(1, round(1.0 / (args.fps * coupler.info.dt)))
        try:
            for n in range(steps):
                if schedule is not None:
                    coupler.data.ctrl[:] = schedule.at(coupler.time)
                step = coupler.step()
                totals.add(step)
                if recorder is not None and n % every == 0:
                    pressed = float(np.abs(step.forces[:, :3]).sum())
                    recorder.capture(coupler.data, pressed)
                if viewer is not None:
                    viewer.sync()
                if (n + 1) % round(1.0 / coupler.info.dt) == 0 or n + 1 == steps:
                    _progress(coupler.time, step)
        finally:
            if viewer is not None:
                viewer.close()
        if recorder is not None:
            print(f"wrote {recorder.write(args.fps)} ({len(recorder.frames)} frames)")
            recorder.close()
        print(totals.summary(coupler.substeps))
    return 0


class _Totals:
    def __init__(self) -> None:
        self.session: list[float] = []
        self.mujoco: list[float] = []

    def add(self, step: Any) -> None:
        self.session.append(step.session_s)
        self.mujoco.append(step.mujoco_s)

    def summary(self, substeps: int) -> str:
        import numpy as np

        session, sim = np.array(self.session) * 1e6, np.array(self.mujoco) * 1e6
        both = session + sim
        return (
            f"{both.size} coupled steps ({substeps} MuJoCo steps each): p50 {np.median(both):.0f} "
            f"us (session {np.median(session):.0f}, MuJoCo {np.median(sim):.0f}); p99 "
            f"{np.percentile(both, 99):.0f} us"
        )


def _progress(t: float, step: Any) -> None:
    parts = [
        f"{tool.kind} force {reading.force:.4g} depth {tool.depth:.4g}"
        for tool, reading in zip(step.tools, step.frame.tools, strict=True)
    ] + [
        f"grasp force {reading.force:.4g} height {grasp.height:.4g}"
        for grasp, reading in zip(step.grasps, step.frame.grasps, strict=True)
    ]
    print(f"t {t:.3f} s: {', '.join(parts)}", flush=True)


def _recorder(args: argparse.Namespace, model: Any) -> Any:
    from membrane_mujoco.recording import Recorder

    camera = args.camera if args.camera is not None or model.ncam == 0 else 0
    return Recorder(model, args.out, args.width, args.height, camera)


def _has_display() -> bool:
    return sys.platform == "darwin" or bool(
        os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")
    )


def _viewer(coupler: Any) -> Any:
    import mujoco.viewer

    return mujoco.viewer.launch_passive(coupler.model, coupler.data)
