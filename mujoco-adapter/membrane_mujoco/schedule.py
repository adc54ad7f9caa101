"""A control schedule written in the MJCF itself, so that a model file alone drives its tools.

```xml
<custom>
  <!-- rows of: time (s), then one control per actuator in the model's order -->
  <numeric name="membrane_schedule" data="0 0.030  0.2 0.026  0.6 0.026  0.8 0.030"/>
</custom>
```

Each actuator's control is linear between rows and held before the first and after the last.
A model without the element runs with its controls as they are (its own keyframes, say).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np

from membrane_client.errors import UserError

__all__ = ["NAME", "Schedule"]

NAME = "membrane_schedule"


@dataclass(frozen=True)
class Schedule:
    """Times ``(r,)`` and controls ``(r, nu)``."""

    times: np.ndarray
    controls: np.ndarray

    @classmethod
    def of(cls, model: Any) -> Schedule | None:
        """The model's schedule, or None without one; ``UserError`` on a malformed one."""
        index = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_NUMERIC, NAME)
        if index < 0:
            return None
        start, size = int(model.numeric_adr[index]), int(model.numeric_size[index])
        values = np.array(model.numeric_data[start : start + size], dtype=np.float64)
        width = 1 + model.nu
        if model.nu == 0 or size == 0 or size % width:
            raise UserError(
                f"{NAME} holds {size} numbers: rows of a time and {model.nu} controls "
                f"(one per actuator) were expected"
            )
        rows = values.reshape(-1, width)
        if not np.isfinite(rows).all() or (np.diff(rows[:, 0]) <= 0).any():
            raise UserError(f"{NAME}: its times must be finite and increasing")
        return cls(rows[:, 0], rows[:, 1:])

    @property
    def duration(self) -> float:
        return float(self.times[-1])

    def at(self, t: float) -> np.ndarray:
        """Every actuator's control at time ``t`` (s)."""
        return np.array([np.interp(t, self.times, column) for column in self.controls.T])
