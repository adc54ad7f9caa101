"""`membrane caches`: scenes and their material variants loaded as a server loads them, their
FEM tables found or built in the cache directory; on a real local Ray (2 workers, loopback only)
the same entries, bit for bit, as one after another here; bad options one line and exit code 2."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from membrane_cli.dispatcher import main
from membrane_models.fem.cache import CacheUse
from membrane_server.cache_build import SceneCaches, missing_entries, parse_vary, variants

# The shipped disk, made small: a 20 mm disk, coarse, 8 modes on a 5 x 5 lattice (a second).
_TINY = """\
name = "tiny-disk"
description = "a small disk for the caches' tests"
dt = 0.001

[tissue]
name = "tiny disk"
kind = "plate"
shape = "disk"
size = [0.02]
element_size = 0.004
youngs_modulus = 1.5e6
poisson = 0.45
thickness = 0.003
density = 1109.0
supports = "clamped"
modes = 8
radii = [0.0]

[lattice]
nx = 5
ny = 5

[live]
"""


@pytest.fixture
def tiny_scene(tmp_path: Path) -> Path:
    path = tmp_path / "tiny-disk.toml"
    path.write_text(_TINY)
    return path


def _entries(folder: Path) -> dict[str, dict[str, np.ndarray]]:
    found = {}
    for path in sorted(folder.glob("*.npz")):
        with np.load(path) as stored:
            found[path.name] = {name: stored[name] for name in stored.files}
    return found


def test_variants_are_the_product_of_the_varied_values_and_leave_the_file_alone(
    tiny_scene: Path,
) -> None:
    text = tiny_scene.read_text()
    built = variants(
        [str(tiny_scene)], ["tissue.youngs_modulus=1e6,2e6", "tissue.thickness=0.002,0.003"]
    )
    assert [(v.data["tissue"]["youngs_modulus"], v.data["tissue"]["thickness"]) for v in built] == [
        (1e6, 0.002), (1e6, 0.003), (2e6, 0.002), (2e6, 0.003),
    ]  # fmt: skip
    assert built[0].label == "tiny-disk tissue.youngs_modulus=1000000.0 tissue.thickness=0.002"
    assert all(v.data["name"] == "tiny-disk" for v in built)
    assert tiny_scene.read_text() == text


@pytest.mark.parametrize(
    ("vary", "says"),
    [
        ("tissue.youngs_modulus", "--vary takes KEY=V1,V2"),
        ("tissue.youngs_modulus=1e6,abc", "'abc' is not a TOML value"),
        ("tissue.stiffness=1e6", "stiffness"),
        ("tissue.youngs_modulus=-1e6", "youngs_modulus"),
        ("dt.x=1", "'dt' of scene tiny-disk is not a table"),
        ("placement.size=2.0", "scene tiny-disk has no [placement] table"),
        ("tissue.supports=clamped", 'a string takes quotes: "clamped"'),
        ("tissue.radii=[0.0,0.005],[0.0", "'[0.0' is not a TOML value"),
        ("tissue.thickness=0.002,,0.003", "an empty value between commas"),
    ],
)
def test_bad_variants_are_one_line_and_exit_2(
    tiny_scene: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str], vary: str, says: str
) -> None:
    cache = tmp_path / "cache"
    code = main(["caches", "--scene", str(tiny_scene), "--vary", vary, "--cache-dir", str(cache)])
    err = capsys.readouterr().err
    assert code == 2 and says in err and len(err.strip().splitlines()) == 1, err
    assert not cache.exists()  # refused before anything was built


def test_a_varied_value_may_be_a_list_or_a_string_with_commas() -> None:
    parts, values = parse_vary('tissue.radii=[0.0, 0.005],[0.0,0.003], "a, b"')
    assert parts == ("tissue", "radii")
    assert values == [[0.0, 0.005], [0.0, 0.003], "a, b"]


def test_a_key_varied_twice_is_refused(
    tiny_scene: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    vary = ["--vary", "tissue.youngs_modulus=1e6", "--vary", "tissue.youngs_modulus=2e6"]
    code = main(["caches", "--scene", str(tiny_scene), *vary, "--cache-dir", str(tmp_path)])
    err = capsys.readouterr().err
    assert code == 2 and "given twice" in err and len(err.strip().splitlines()) == 1


def test_entries_a_job_left_out_of_sight_are_named(tmp_path: Path) -> None:
    (tmp_path / "fem").mkdir()
    (tmp_path / "fem" / "seen.npz").write_bytes(b"")
    uses = (CacheUse("seen.npz", built=True), CacheUse("elsewhere.npz", built=True))
    assert missing_entries([SceneCaches("a", "t", uses, 1.0)], tmp_path) == ["elsewhere.npz"]


@pytest.mark.slow
def test_variants_built_on_a_local_ray_are_the_serial_builds_bit_for_bit(
    tiny_scene: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    argv = ["caches", "--scene", str(tiny_scene), "--vary", "tissue.youngs_modulus=1e6,2e6"]
    assert main([*argv, "--cache-dir", str(tmp_path / "serial")]) == 0
    out = capsys.readouterr().out
    assert out.count("1 built, 0 found") == 2, out
    ray = ["--cache-dir", str(tmp_path / "ray"), "--executor", "ray", "--workers", "2"]
    assert main([*argv, *ray]) == 0
    out = capsys.readouterr().out
    assert "ray: 2 jobs on a local Ray" in out
    assert out.count("built, 0 found") == 2 and "[2/2] tiny-disk" in out, out  # as each ends
    serial, on_ray = _entries(tmp_path / "serial" / "fem"), _entries(tmp_path / "ray" / "fem")
    assert len(serial) == 2 and serial.keys() == on_ray.keys()
    for name, arrays in serial.items():
        assert arrays.keys() == on_ray[name].keys()
        for key, values in arrays.items():
            assert np.array_equal(values, on_ray[name][key]), (name, key)
    assert main([*argv, "--cache-dir", str(tmp_path / "serial")]) == 0  # now read back
    assert capsys.readouterr().out.count("0 built, 1 found") == 2


def test_a_cache_dir_that_cannot_be_written_is_one_line_before_any_build(
    tiny_scene: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    blocked = tmp_path / "a-file"
    blocked.write_text("")
    code = main(["caches", "--scene", str(tiny_scene), "--cache-dir", str(blocked)])
    err = capsys.readouterr()
    assert code == 2 and "cannot write in" in err.err and len(err.err.strip().splitlines()) == 1
    assert "built" not in err.out


def test_recorders_nest() -> None:
    from membrane_models.fem.cache import _record, recorded_entries

    with recorded_entries() as outer:
        with recorded_entries() as inner:
            pass  # equal lists (both empty) when the inner one closes
        _record(Path("x.npz"), built=True)
    assert outer == [CacheUse("x.npz", True)] and inner == []
