"""World <-> scene coordinates on the client: ``SceneInfo.to_scene`` inverts ``positions`` on
1-D and 2-D scenes along every axis; the describe reply's optional ``extent`` and ``film``
(additive in v1: older replies stay valid and keep their fields); ``contains`` and the
once-per-description warning for a point off the scene."""

from __future__ import annotations

import dataclasses
import logging
import pickle
import warnings
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from membrane_client import SceneInfo
from membrane_client.coordinates import Extent
from membrane_client.errors import ProtocolError, UserError
from membrane_client.protocol import encode

AXES = ("x", "y", "z")


def _info(
    dims: int = 2,
    axis: str = "z",
    *,
    origin: tuple[float, float, float] = (0.5, -1.0, 1.0),
    size: float = 2.0,
    scale: float = 100.0,
    n: int = 5,
    **fields: Any,
) -> SceneInfo:
    """A scene on [0, 1]^dims (a dimensionless scene's lattice)."""
    axis_points = np.linspace(0.0, 1.0, n)
    if dims == 1:
        points = axis_points[:, np.newaxis]
    else:
        u, v = np.meshgrid(axis_points, axis_points, indexing="ij")
        points = np.column_stack([u.ravel(), v.ravel()])
    return SceneInfo(
        name="s",
        description="",
        points=points,
        shape=(n,) * dims,
        dt=0.001,
        duration=1.0,
        start_offset=0.0,
        steps=1001,
        origin=np.array(origin, dtype=np.float64),
        size=size,
        scale=scale,
        axis=axis,
        policy="hold",
        snapping="nearest",
        evaluator="exact",
        **fields,
    )


def _physical(**fields: Any) -> SceneInfo:
    """A 50 x 50 mm patch in m (points strictly inside its box, as FEM nodes off the edge)."""
    points = np.array([[0.01, 0.01], [0.04, 0.01], [0.01, 0.04], [0.04, 0.04]])
    extent = Extent.of_bounds(np.array([0.0, 0.0]), np.array([0.05, 0.05]))
    info = _info(origin=(0.0, 0.0, 0.0), size=1.0, scale=1.0, film=False)
    return SceneInfo(
        **{
            **_fields(info),
            "points": points,
            "shape": (4,),
            "declared_extent": extent,
            **fields,
        }
    )


def _fields(info: SceneInfo) -> dict[str, Any]:
    return {
        name: getattr(info, name)
        for name in info.__dataclass_fields__
        if info.__dataclass_fields__[name].init
    }


def _reply(info: SceneInfo) -> dict[str, Any]:
    """The describe reply as it crosses the wire (msgpack-encodable, then read back)."""
    fields = info.to_reply_fields()
    encode(fields)  # every field travels
    return fields


# -- the inverse of the placement -----------------------------------------------------------


@settings(max_examples=300, deadline=None)
@given(
    dims=st.sampled_from([1, 2]),
    axis=st.sampled_from(AXES),
    origin=st.tuples(*[st.floats(-10.0, 10.0)] * 3),
    size=st.floats(0.01, 10.0) | st.floats(-10.0, -0.01),
    scale=st.floats(0.01, 1000.0) | st.floats(-1000.0, -0.01),
    seed=st.integers(0, 2**32 - 1),
)
def test_to_scene_inverts_positions(
    dims: int,
    axis: str,
    origin: tuple[float, float, float],
    size: float,
    scale: float,
    seed: int,
) -> None:
    info = _info(dims, axis, origin=origin, size=size, scale=scale)
    z = np.random.default_rng(seed).uniform(-1.0, 1.0, info.n_points)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # lattice points are inside: no warning
        scene, heights = info.to_scene(info.positions(z))
    assert scene.shape == (info.n_points, dims) and heights.shape == (info.n_points,)
    np.testing.assert_allclose(scene, info.points, rtol=0, atol=1e-12)
    np.testing.assert_allclose(heights, z, rtol=0, atol=1e-12)


@pytest.mark.parametrize("axis", AXES)
@pytest.mark.parametrize("dims", [1, 2])
def test_random_world_points_round_trip(dims: int, axis: str) -> None:
    """World -> scene -> world: the lateral coordinates and the height come back (on a line,
    only the coordinate along it: the one across is dropped)."""
    info = _info(dims, axis)
    world = np.random.default_rng(7).uniform(-3.0, 3.0, (200, 3))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # most of these are off the scene
        scene, heights = info.to_scene(world)
    lateral = [i for i in range(3) if i != info.axis_index][:dims]
    again = np.tile(info.origin, (len(world), 1))
    again[:, lateral] += info.size * scene
    again[:, info.axis_index] += info.scale * heights
    kept = [*lateral, info.axis_index]
    np.testing.assert_allclose(again[:, kept], world[:, kept], rtol=0, atol=1e-12)


def test_axis_placement_is_the_protocols() -> None:
    """docs/PROTOCOL.md: axis z puts u on x and v on y; y puts u on x, v on z; x puts u on y, v
    on z. A probe tip 1e-3 below the rest plane (scale 100: 0.1 world units) has height -1e-3."""
    for axis, tip, at in [
        ("z", (0.7, -0.6, 0.9), (0.1, 0.2)),
        ("y", (1.1, 0.9, 2.4), (0.3, 0.7)),
        ("x", (0.4, -0.2, 1.2), (0.4, 0.1)),
    ]:
        info = _info(axis=axis)  # origin (0.5, -1, 1), size 2, scale 100
        world = np.array(tip)
        world[info.axis_index] = info.origin[info.axis_index] - 0.1
        scene, heights = info.to_scene(world)
        assert scene.shape == (1, 2) and heights.shape == (1,)
        np.testing.assert_allclose(scene[0], at, atol=1e-15)
        assert heights[0] == pytest.approx(-1e-3)
    scene, heights = _info().to_scene([1.5, 0.0, 0.9])  # the coppelia probe's example
    np.testing.assert_allclose(scene[0], [0.5, 0.5])
    assert heights[0] == pytest.approx(-1e-3)


def test_to_scene_refuses_bad_shapes_and_degenerate_placements() -> None:
    with pytest.raises(UserError, match=r"\(3,\) or \(n, 3\)"):
        _info().to_scene([1.0, 2.0])
    with pytest.raises(UserError, match=r"\(3,\) or \(n, 3\)"):
        _info().to_scene(np.zeros((2, 2, 3)))
    with pytest.raises(UserError, match="non-zero"):
        _info(scale=0.0).to_scene([0.0, 0.0, 0.0])


# -- extent, contains and the warning --------------------------------------------------------


@pytest.mark.parametrize("dims", [1, 2])
def test_extent_defaults_to_the_lattice(dims: int) -> None:
    info = _info(dims)
    assert info.declared_extent is None
    np.testing.assert_array_equal(info.extent.lower, np.zeros(dims))
    np.testing.assert_array_equal(info.extent.upper, np.ones(dims))
    assert info.contains([0.0] * dims) and info.contains([1.0] * dims)
    assert info.contains([0.5] * dims)
    assert not info.contains([1.001] * dims) and not info.contains([-0.001] * dims)


def test_declared_extent_is_the_box() -> None:
    info = _physical()
    np.testing.assert_array_equal(info.extent.lower, [0.0, 0.0])
    np.testing.assert_array_equal(info.extent.upper, [0.05, 0.05])
    assert info.contains((0.0, 0.0)) and info.contains((0.05, 0.025))  # beyond the nodes
    assert not info.contains((0.05 + 1e-6, 0.025))
    # A boundary point comes back from the world a few ulps off: still inside.
    shifted = _physical(origin=np.array([0.1, 0.3, 0.7]))
    corner = shifted.origin + np.array([0.05, 0.05, 0.0])
    scene, _ = shifted.to_scene(corner)
    assert shifted.contains(scene[0])
    with pytest.raises(UserError, match="2 coordinates"):
        info.contains([0.01])


def test_outside_warns_once_per_scene_info(caplog: pytest.LogCaptureFixture) -> None:
    info = _physical()
    inside = [0.025, 0.025, -0.001]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        info.to_scene(inside)
    caplog.set_level(logging.WARNING, logger="membrane_client.coordinates")
    with pytest.warns(UserWarning, match=r"outside the scene's extent \[0.0, 0.0\] .. \[0.05"):
        info.to_scene([[0.025, 0.025, 0.0], [0.06, 0.01, 0.0]])
    assert [r.levelno for r in caplog.records] == [logging.WARNING]
    assert "[0.06, 0.01]" in caplog.records[0].getMessage()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        scene, _ = info.to_scene([0.07, -0.01, 0.0])  # said once already
    np.testing.assert_allclose(scene[0], [0.07, -0.01])
    assert len(caplog.records) == 1
    # Another description of the same scene warns again, and so does a copy (a pickled one).
    for again in (SceneInfo.from_reply(_reply(info)), pickle.loads(pickle.dumps(info))):
        with pytest.warns(UserWarning, match="outside"):
            again.to_scene([0.07, -0.01, 0.0])


# -- the describe reply ----------------------------------------------------------------------


def test_reply_without_extent_or_film_keeps_its_fields() -> None:
    """An older scene's reply (and so its revision, a hash of the fields) is unchanged."""
    info = _info()
    fields = _reply(info)
    assert "extent" not in fields and "film" not in fields
    back = SceneInfo.from_reply(fields)
    assert back.declared_extent is None and back.film is True
    np.testing.assert_array_equal(back.extent.upper, [1.0, 1.0])


def test_extent_and_film_round_trip() -> None:
    info = _physical()
    fields = _reply(info)
    assert fields["extent"] == {"lower": [0.0, 0.0], "upper": [0.05, 0.05]}
    assert fields["film"] is False
    back = SceneInfo.from_reply(fields)
    assert back.film is False and back.declared_extent is not None
    np.testing.assert_array_equal(back.extent.lower, [0.0, 0.0])
    np.testing.assert_array_equal(back.extent.upper, [0.05, 0.05])
    assert back.to_reply_fields().keys() == fields.keys()
    explicit = SceneInfo.from_reply({**_reply(_info()), "film": True})
    assert explicit.film is True and "film" not in explicit.to_reply_fields()


@pytest.mark.parametrize(
    ("extent", "message"),
    [
        ([0.0, 1.0], "map of 'lower' and 'upper'"),
        ({"lower": [0.0, 0.0]}, "map of 'lower' and 'upper'"),
        ({"lower": [0.0, 0.0], "upper": [1.0, 1.0], "x": 1}, "map of 'lower' and 'upper'"),
        ({"lower": [0.0], "upper": [1.0, 1.0]}, "lower must list 2 numbers"),
        ({"lower": [0.0, 0.0], "upper": [1.0, "1"]}, "upper must hold numbers"),
        ({"lower": [0.0, True], "upper": [1.0, 1.0]}, "lower must hold numbers"),
        ({"lower": [0.0, 0.0], "upper": [1.0, float("nan")]}, "upper must be finite"),
        ({"lower": [0.0, 2.0], "upper": [1.0, 1.0]}, "exceeds upper"),
    ],
)
def test_malformed_extent_is_a_protocol_error(extent: Any, message: str) -> None:
    with pytest.raises(ProtocolError, match=message):
        SceneInfo.from_reply({**_reply(_info()), "extent": extent})


@pytest.mark.parametrize("film", [1, "false", None])
def test_malformed_film_is_a_protocol_error(film: Any) -> None:
    with pytest.raises(ProtocolError, match="film must be a bool"):
        SceneInfo.from_reply({**_reply(_info()), "film": film})


def test_triangles_round_trip_and_are_left_out_when_none() -> None:
    info = _info()  # 25 points
    assert "triangles" not in _reply(info) and SceneInfo.from_reply(_reply(info)).triangles is None
    triangles = np.array([[0, 1, 5], [5, 1, 6]], dtype=np.int32)
    fields = _reply(dataclasses.replace(info, triangles=triangles))
    assert fields["triangles"] == [0, 1, 5, 5, 1, 6]
    back = SceneInfo.from_reply(fields)
    assert back.triangles is not None
    np.testing.assert_array_equal(back.triangles, triangles)


@pytest.mark.parametrize(
    ("triangles", "message"),
    [
        ([0, 1], "three per triangle"),
        ([0, 1, 2.0], "flat list of ints"),
        ([0, 1, True], "flat list of ints"),
        ("012", "flat list of ints"),
        ([0, 1, 25], "index the 25 points"),
        ([0, 1, -1], "index the 25 points"),
    ],
)
def test_malformed_triangles_are_a_protocol_error(triangles: Any, message: str) -> None:
    with pytest.raises(ProtocolError, match=message):
        SceneInfo.from_reply({**_reply(_info()), "triangles": triangles})
