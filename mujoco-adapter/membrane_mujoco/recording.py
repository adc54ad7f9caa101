"""Offscreen frames of a coupled run, written as a PNG (the frame of the largest contact
force), a GIF or an MP4.

Rendering goes through MuJoCo's own ``Renderer`` (OpenGL offscreen: ``MUJOCO_GL=egl`` on a
headless Linux, through Mesa's software EGL where there is no GPU). GIF and PNG are written
with Pillow; MP4 needs ``imageio`` with its ffmpeg plugin, and is refused with that reason
without it.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path
from typing import Any

import numpy as np

from membrane_client.errors import UserError

__all__ = ["FORMATS", "Recorder"]

FORMATS = (".png", ".gif", ".mp4")


class Recorder:
    """Frames from ``model``'s ``camera`` (a name or an index, or None for the free camera
    looking at the model's centre), ``width`` x ``height`` pixels, kept for ``write``."""

    def __init__(
        self,
        model: Any,
        path: Path,
        width: int = 480,
        height: int = 360,
        camera: str | int | None = None,
    ) -> None:
        if path.suffix.lower() not in FORMATS:
            raise UserError(f"--out {path}: write a {', '.join(FORMATS)} file")
        if path.suffix.lower() == ".mp4" and importlib.util.find_spec("imageio") is None:
            raise UserError(
                "an MP4 needs imageio with its ffmpeg plugin: pip install imageio[ffmpeg]"
            )
        import mujoco

        self.path, self.camera = path, camera
        if (
            isinstance(camera, str)
            and mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, camera) < 0
        ):
            raise UserError(f"no camera named {camera!r} in the model")
        try:
            self._renderer = mujoco.Renderer(model, height, width)
        except Exception as error:  # no OpenGL context: the reason, in one line
            raise UserError(f"offscreen rendering is not available here ({error}); "
                            f"on a headless Linux set MUJOCO_GL=egl") from None  # fmt: skip
        self.frames: list[np.ndarray] = []
        self.forces: list[float] = []

    def capture(self, data: Any, force: float) -> None:
        """A frame of ``data`` now; ``force``: the contact forces' size then (the PNG's choice)."""
        if self.camera is None:
            self._renderer.update_scene(data)
        else:
            self._renderer.update_scene(data, camera=self.camera)
        self.frames.append(self._renderer.render().copy())
        self.forces.append(force)

    def write(self, fps: float) -> Path:
        """Write the file; its path."""
        if not self.frames:
            raise UserError("no frame was captured: nothing to write")
        suffix = self.path.suffix.lower()
        self.path.parent.mkdir(parents=True, exist_ok=True)
        if suffix == ".mp4":
            import imageio.v2 as imageio

            imageio.mimwrite(self.path, self.frames, fps=fps)
            return self.path
        from PIL import Image

        if suffix == ".png":
            Image.fromarray(self.frames[int(np.argmax(self.forces))]).save(self.path)
            return self.path
        images = [Image.fromarray(frame) for frame in self.frames]
        images[0].save(
            self.path, save_all=True, append_images=images[1:], duration=round(1000 / fps), loop=0
        )
        return self.path

    def close(self) -> None:
        self._renderer.close()
