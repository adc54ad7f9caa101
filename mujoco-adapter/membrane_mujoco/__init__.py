"""MuJoCo drives the tissue: a MuJoCo model coupled to a live session (docs/MUJOCO.md).

- ``Coupler`` (``coupler``): the session's lattice drawn in the model (``lattice``), the
  model's tool geoms pressed into the tissue as rigid tools (``tools``) each session step, the
  contact forces applied back to the tool bodies, MuJoCo stepped in substeps of the scene's dt
  (``timing``);
- ``schedule``: a control schedule written in the MJCF itself (``<custom>``), so that a model
  file alone drives its tools; ``recording``: offscreen frames to PNG, GIF or MP4;
- ``cli``: ``membrane mujoco MODEL.xml --scene S --tool NAME``.

Imports only the client and the CLI helpers of ours (its import contract); ``mujoco`` and
Pillow come with the ``mujoco`` extra.
"""

from typing import Any

__all__ = ["CoupledStep", "Coupler"]


def __getattr__(name: str) -> Any:
    # lazily: `membrane mujoco` registers itself through this package without importing mujoco,
    # which picks its OpenGL backend (MUJOCO_GL) when first imported
    if name in __all__:
        from membrane_mujoco import coupler

        return getattr(coupler, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
