"""The scene's dt against MuJoCo's timestep, and a model's own control schedule."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from membrane_client.errors import UserError
from membrane_mujoco.schedule import Schedule
from membrane_mujoco.timing import substeps


def test_a_timestep_that_divides_dt_gives_its_substeps() -> None:
    assert substeps(0.001, 0.001) == 1
    assert substeps(0.0005, 0.001) == 2
    assert substeps(0.002, 0.01) == 5  # 0.01 / 0.002 is 4.999... in floating point


@pytest.mark.parametrize(
    ("timestep", "reason"),
    [(0.002, "longer than the scene's dt"), (0.0003, "does not divide"), (0.0, "must be > 0")],
)
def test_a_timestep_that_cannot_match_is_refused_with_the_fix(timestep: float, reason: str) -> None:
    with pytest.raises(UserError, match=reason):
        substeps(timestep, 0.001)


MODEL = """<mujoco><worldbody><body><joint name="z" type="slide"/><geom size=".01"/></body>
</worldbody><actuator><position joint="z"/></actuator><custom>{custom}</custom></mujoco>"""


def test_the_schedule_is_linear_between_its_rows_and_held_beyond() -> None:
    custom = '<numeric name="membrane_schedule" data="0 0  1 -2  3 -2"/>'
    schedule = Schedule.of(mujoco.MjModel.from_xml_string(MODEL.format(custom=custom)))
    assert schedule is not None and schedule.duration == 3.0
    for t, expected in [(-1.0, 0.0), (0.25, -0.5), (2.0, -2.0), (9.0, -2.0)]:
        assert schedule.at(t) == pytest.approx(np.array([expected]))


def test_a_model_without_a_schedule_has_none_and_a_malformed_one_is_refused() -> None:
    assert Schedule.of(mujoco.MjModel.from_xml_string(MODEL.format(custom=""))) is None
    for data, reason in [("0 0 1", "rows of a time and 1 controls"), ("1 0 0 0", "increasing")]:
        custom = f'<numeric name="membrane_schedule" data="{data}"/>'
        with pytest.raises(UserError, match=reason):
            Schedule.of(mujoco.MjModel.from_xml_string(MODEL.format(custom=custom)))
