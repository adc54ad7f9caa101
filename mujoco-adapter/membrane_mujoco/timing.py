"""The scene's dt against MuJoCo's timestep: how many MuJoCo steps one session step spans."""

from __future__ import annotations

from membrane_client.errors import UserError

__all__ = ["substeps"]

_RELATIVE = 1e-9  # a timestep that divides dt up to rounding (0.002 into 0.01)


def substeps(timestep: float, dt: float) -> int:
    """n with n * timestep == dt; refused (``UserError``, with the fix) when there is none."""
    if not (timestep > 0.0 and dt > 0.0):
        raise UserError(f"MuJoCo's timestep ({timestep!r}) and the scene's dt ({dt!r}) must be > 0")
    if timestep > dt * (1.0 + _RELATIVE):
        raise UserError(
            f"MuJoCo's timestep {timestep:g} s is longer than the scene's dt {dt:g} s: the tissue "
            f'would be stepped less often than the model; set <option timestep="{dt:g}"/> '
            f"or a divisor of it"
        )
    count = round(dt / timestep)
    if abs(count * timestep - dt) > _RELATIVE * dt:
        below = dt / max(1, count)
        raise UserError(
            f"MuJoCo's timestep {timestep:g} s does not divide the scene's dt {dt:g} s: "
            f'set <option timestep="{below:g}"/> ({max(1, count)} substeps per session step)'
        )
    return count
