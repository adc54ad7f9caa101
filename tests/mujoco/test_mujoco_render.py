"""`membrane mujoco` end to end: the press example rendered offscreen (MuJoCo's EGL through
Mesa) to a GIF in which the tissue dents under the tool, and bad input refused in one line."""

from __future__ import annotations

import math
import os
import subprocess
import sys
from collections.abc import Callable, Iterator
from pathlib import Path

import mujoco
import numpy as np
import pytest
from serve_process import ServeProcess

pytestmark = pytest.mark.slow

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "mujoco" / "press.xml"
ENV = {**os.environ, "MUJOCO_GL": "egl"}


def _egl_missing() -> str | None:
    probe = (
        "import mujoco; m = mujoco.MjModel.from_xml_string('<mujoco/>'); "
        "mujoco.Renderer(m, 16, 16).close()"
    )
    done = subprocess.run([sys.executable, "-c", probe], env=ENV, capture_output=True, text=True)
    return None if done.returncode == 0 else done.stderr.strip().splitlines()[-1]


@pytest.fixture(scope="module")
def server() -> Iterator[ServeProcess]:
    process = ServeProcess("skin-patch")
    yield process
    process.close()


def _membrane(*args: str) -> subprocess.CompletedProcess[str]:
    command = [sys.executable, "-m", "membrane_cli", "mujoco", *args]
    return subprocess.run(command, env=ENV, capture_output=True, text=True, timeout=240)


def test_the_press_example_dents_the_tissue_under_the_tool(
    server: ServeProcess, tmp_path: Path
) -> None:
    missing = _egl_missing()
    if missing is not None:
        pytest.skip(f"no offscreen OpenGL (EGL) here: {missing}")
    out = tmp_path / "press.gif"
    done = _membrane(
        str(EXAMPLE), "--scene", "skin-patch", "--tool", "tip", "--connect", server.address,
        "--out", str(out),
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert f"wrote {out} (25 frames)" in done.stdout
    from PIL import Image

    gif = Image.open(out)
    frames = []
    for index in range(getattr(gif, "n_frames", 1)):  # an animated image's
        gif.seek(index)
        frames.append(np.asarray(gif.convert("RGB"), dtype=np.float64).mean(axis=2))
    pixel = _camera(EXAMPLE, frames[0].shape)
    changes = []
    for index, frame in enumerate(frames):
        t = index * 0.04 + 0.001  # a frame every 40 steps of 1 ms, after its step
        x = 0.02 + 0.01 * float(np.clip((t - 0.3) / 0.4, 0.0, 1.0))  # the schedule's slide
        u, v = pixel(np.array([x, 0.025, 0.0]))
        window = (slice(v - 10, v + 11), slice(u - 10, u + 11))
        changes.append(abs(frame[window].mean() - frames[0][window].mean()))
    # the deepest press (0.3 to 0.7 s): the colour under the translucent tool darkens
    assert max(changes[8:18]) >= 0.1 * 255, changes


def _camera(model_file: Path, shape: tuple[int, ...]) -> Callable[[np.ndarray], tuple[int, int]]:
    """The pixel (u, v) of a world point in the model's first camera's image."""
    model = mujoco.MjModel.from_xml_path(str(model_file))
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    position, axes = data.cam_xpos[0].copy(), data.cam_xmat[0].reshape(3, 3).copy()
    height, width = shape
    focal = (height / 2) / math.tan(math.radians(float(model.cam_fovy[0])) / 2)

    def pixel(point: np.ndarray) -> tuple[int, int]:
        local = axes.T @ (point - position)  # the camera looks along its -z
        return (
            round(width / 2 + focal * local[0] / -local[2]),
            round(height / 2 - focal * local[1] / -local[2]),
        )

    return pixel


def test_bad_input_is_refused_in_one_line(server: ServeProcess, tmp_path: Path) -> None:
    broken = tmp_path / "broken.xml"
    broken.write_text("<mujoco><worldbody><geom type='sphere'></worldbody></mujoco>")
    example = str(EXAMPLE)
    for model, tool, extra, message in [
        (str(broken), "tip", [], "broken.xml:"),
        (example, "nothing", [], "no geom named 'nothing' in the model"),
        (example, "floor", [], "geom 'floor' is a plane"),
        (example, "tip", ["--out", str(tmp_path / "x.bmp")], "write a .png"),
    ]:
        done = _membrane(
            model, "--scene", "skin-patch", "--tool", tool, "--connect", server.address, *extra
        )
        assert done.returncode == 2, (model, tool, done.stderr)
        lines = done.stderr.strip().splitlines()
        assert len(lines) == 1 and message in lines[0], done.stderr
