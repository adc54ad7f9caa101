"""`membrane fem static|modes|transient`: the acceptance figures, plots, one-line refusals.

In process through the dispatcher's ``main`` (capsys), and the acceptance commands once
through the installed console script (slow: a subprocess each).
"""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from membrane_cli.dispatcher import main

SQUARE = [
    "--shape",
    "square",
    "--size",
    "50mm",
    "--thickness",
    "3mm",
    "--E",
    "1.5MPa",
    "--nu",
    "0.45",
]
# 0.005612 P a^2 / D, a clamped square plate under a central point load (Timoshenko)
CENTRE_DEFLECTION_MM = 0.005612 * 1.0 * 0.05**2 / (1.5e6 * 0.003**3 / (12 * (1 - 0.45**2))) * 1e3
PNG = b"\x89PNG\r\n\x1a\n"


def _fem(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(["fem", *argv])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def _number(pattern: str, text: str) -> float:
    match = re.search(pattern, text)
    assert match is not None, f"{pattern!r} not in:\n{text}"
    return float(match.group(1))


def _modes(text: str) -> list[tuple[float, float | None]]:
    """(FEM Hz, closed-form Hz or None) per row of the mode table."""
    rows = re.findall(r"^\s+\d+\s+(\S+)\s+(\S+)\s+\S+", text, flags=re.MULTILINE)
    return [(float(f), None if ref == "-" else float(ref)) for f, ref in rows]


def test_static_centre_deflection_of_the_skin_square(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = _fem(capsys, "static", *SQUARE, "--load", "1N")
    assert code == 0, err
    assert abs(CENTRE_DEFLECTION_MM - 3.315) < 5e-4
    w = _number(r"deflection at the load: (\S+) mm", out)
    assert w == pytest.approx(CENTRE_DEFLECTION_MM, rel=0.01)
    assert _number(r"peak deflection: (\S+) mm", out) == pytest.approx(w, rel=1e-6)
    assert _number(r"stiffness: (\S+) N/mm", out) == pytest.approx(1 / w, rel=1e-3)
    assert _number(r"D = (\S+) N m", out) == pytest.approx(0.004232, rel=1e-3)
    assert "800 triangles" in out and "element size 2.5 mm" in out
    stress = _number(r"stress: (\S+) kPa von Mises", out)
    assert 100 < stress < 160  # M ~ P/(4 pi) (1 + nu) ln(a / r) at r = h: about 130 kPa
    assert "r = h = 3 mm" in out and "log(1/r)" in out
    warning = err.strip().splitlines()
    assert len(warning) == 1 and "warning" in warning[0] and "w << h" in warning[0]


@pytest.mark.slow
def test_static_nonlinear_beside_linear(capsys: pytest.CaptureFixture[str]) -> None:
    # the study's patch at 1 N on 6.25 mm elements (docs/NONLINEAR.md: 3.310 and 2.543 mm)
    code, out, err = _fem(
        capsys, "static", *SQUARE, "--load", "1N", "--element-size", "6.25mm", "--nonlinear"
    )
    assert code == 0, err
    row = re.search(r"deflection \(mm\)\s+(\S+)\s+(\S+)", out)
    assert row is not None, out
    linear, large = float(row.group(1)), float(row.group(2))
    assert linear == pytest.approx(3.310, rel=1e-3) and large == pytest.approx(2.543, rel=1e-3)
    stress = re.search(r"stress \(kPa von Mises\)\s+(\S+)\s+(\S+)", out)
    assert stress is not None and 0 < float(stress.group(2)) < float(stress.group(1))
    assert "nonlinear (edges held in their plane)" in out and "w << h" not in err


@pytest.mark.slow
def test_static_patch_and_pressure(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = _fem(
        capsys, "static", *SQUARE, "--load", "0.1N", "--at", "20,25", "--tool-radius", "5mm"
    )
    assert code == 0, err
    assert "spread uniformly over a 5 mm radius disk at (20, 25) mm" in out
    assert "under the patch's centre" in out
    assert err == ""  # 0.3 mm: within the thin-plate limit, no warning
    code, out, err = _fem(
        capsys, "static", *SQUARE, "--pressure", "100Pa", "--supports", "simply_supported"
    )
    assert code == 0, err
    # Navier: w = 0.00406 q a^4 / D at the centre of a simply supported square
    expected = 0.00406 * 100 * 0.05**4 / 0.0042323 * 1e3
    assert _number(r"deflection at \(25, 25\) mm: (\S+) mm", out) == pytest.approx(
        expected, rel=0.01
    )


def test_static_membrane_and_negative_coordinates(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = _fem(
        capsys,
        "static",
        "--model",
        "membrane",
        "--tension",
        "50N/m",
        "--shape",
        "disk",
        "--size",
        "40mm",
        "--at",
        "-5,0",
    )
    assert code == 0, err
    assert "membrane: T 50 N/m" in out and "at (-5, 0) mm" in out
    assert "log-singular" in err and len(err.strip().splitlines()) == 1


@pytest.mark.slow
def test_modes_of_the_clamped_disk_beside_bessel(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = _fem(
        capsys,
        "modes",
        "--shape",
        "disk",
        "--size",
        "40mm",
        "--thickness",
        "3mm",
        "--E",
        "1.5MPa",
        "--nu",
        "0.45",
    )
    assert code == 0, err
    assert "clamped disk plate" in out
    rows = _modes(out)
    assert len(rows) == 10
    scale = np.sqrt(0.0042323 / (1109 * 0.003)) / 0.02**2 / (2 * np.pi)
    assert rows[0][1] == pytest.approx(10.2158 * scale, rel=1e-4)
    for found, exact in rows:
        assert exact is not None and found == pytest.approx(exact, rel=3e-3)
    assert rows[1][1] == rows[2][1]  # the n = 1 pair


def test_modes_of_a_membrane_rectangle_and_none_for_a_mesh(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    code, out, err = _fem(
        capsys,
        "modes",
        "--model",
        "membrane",
        "--tension",
        "50N/m",
        "--shape",
        "rectangle",
        "--size",
        "40mmx30mm",
        "--count",
        "4",
    )
    assert code == 0, err
    for found, exact in _modes(out):
        assert exact is not None and found == pytest.approx(exact, rel=1e-3)
    meshio = pytest.importorskip("meshio")
    from membrane_models import fem

    domain = fem.rectangle(0.04, 0.03, 0.005)
    points = np.c_[domain.mesh.p.T, np.zeros(domain.mesh.p.shape[1])]
    meshio.write(tmp_path / "plate.vtk", meshio.Mesh(points, [("triangle", domain.mesh.t.T)]))
    code, out, err = _fem(
        capsys, "modes", "--shape", "mesh", "--mesh", str(tmp_path / "plate.vtk"), "--count", "2"
    )
    assert code == 0, err
    assert "closed form: none here" in out and all(ref is None for _, ref in _modes(out))


@pytest.mark.slow
def test_transient_steps_the_live_engine_and_caches_its_tables(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    argv = [
        "transient",
        *SQUARE,
        "--element-size",
        "10mm",
        "--count",
        "12",
        "--duration",
        "15ms",
        "--cache-dir",
        str(tmp_path),
    ]
    code, out, err = _fem(capsys, *argv)
    assert code == 0, err
    assert "built and stored in the cache" in out and list(tmp_path.glob("*.npz"))
    peak = _number(r"peak deflection under the load: (\S+) mm", out)
    static = _number(r"static deflection .*: (\S+) mm", out)
    assert _number(r"ratio peak / static: (\S+)", out) == pytest.approx(peak / static, rel=2e-3)
    assert 1.6 < peak / static <= 2.05  # a sudden load on an undamped plate: about twice
    code, again, err = _fem(capsys, *argv, "--damping", "0.5", "--ramp", "10ms")
    assert code == 0, err
    assert "read from the cache" in again and "ramped up over 10 ms" in again
    assert (
        1.0 < _number(r"ratio peak / static: (\S+)", again) < 1.1
    )  # ramped, damped: little overshoot


@pytest.mark.slow
def test_every_subcommand_draws_its_plot(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    pytest.importorskip("matplotlib")
    coarse = [*SQUARE, "--element-size", "10mm"]
    runs = {
        "static.png": ["static", *coarse],
        "modes.png": ["modes", *coarse, "--count", "4"],
        "transient.png": [
            "transient",
            *coarse,
            "--count",
            "8",
            "--duration",
            "2ms",
            "--cache-dir",
            str(tmp_path),
        ],
    }
    for name, argv in runs.items():
        code, out, err = _fem(capsys, *argv, "--plot", str(tmp_path / name))
        assert code == 0, err
        image = (tmp_path / name).read_bytes()
        assert image[:8] == PNG and len(image) > 5000 and f"plot: {tmp_path / name}" in out


BAD_INPUT = [
    (["static", "--shape", "hexagon"], "invalid choice: 'hexagon'"),
    (["static", "--shape", "polygon"], "needs --vertices"),
    (["static", "--shape", "polygon", "--vertices", "0,0;40,0"], "at least 3 points"),
    (["static", "--size", "50mm", "--thickness", "-3mm"], "--thickness -3mm: must be positive"),
    (["static", "--size", "50"], "--size 50: give a unit, e.g. 50mm"),
    (["static", "--size", "50mm", "--E", "1.5mpa"], "did you mean MPa?"),
    (["static", "--size", "50mm", "--load", "2kPa"], "kPa is a pressure, not a force"),
    (["static", "--size", "50mm", "--at", "80,10"], "(80, 10) mm is off the mesh"),
    (["static", "--size", "50mm", "--supports", "free"], "rigid-body motions"),
    (["static", "--size", "50mm", "--supports", "glued"], "--supports glued: one of"),
    (["static", "--size", "50mm", "--nu", "0.7"], "--nu 0.7"),
    (["static", "--size", "50mm", "--pressure", "1kPa", "--load", "1N"], "takes no --load"),
    (["static", "--size", "50mm", "--at", "5,25", "--tool-radius", "8mm"], "reaches off the mesh"),
    (["static", "--shape", "rectangle", "--size", "50mm"], "takes AxB"),
    (["static", "--shape", "mesh", "--mesh", "no-such-file.msh"], "no-such-file.msh"),
    (["modes", "--model", "membrane", "--size", "50mm"], "needs --tension"),
    (["modes", "--size", "50mm", "--count", "0"], "--count"),
    (["transient", "--size", "50mm", "--dt", "0ms"], "--dt 0ms: must be positive"),
    (["transient", "--size", "50mm", "--duration", "inf s"], "must be finite"),
]


@pytest.mark.parametrize(("argv", "message"), BAD_INPUT, ids=[" ".join(a) for a, _ in BAD_INPUT])
def test_bad_input_is_one_line_and_exit_code_2(
    capsys: pytest.CaptureFixture[str], argv: list[str], message: str
) -> None:
    try:
        code = main(["fem", *argv])
    except SystemExit as stop:  # argparse's own refusals
        code = int(stop.code or 0)
    captured = capsys.readouterr()
    assert code == 2
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("membrane fem"), captured.err
    assert message in lines[0] and "Traceback" not in captured.err


def test_help_has_examples(capsys: pytest.CaptureFixture[str]) -> None:
    for command in ("static", "modes", "transient"):
        with pytest.raises(SystemExit) as stop:
            main(["fem", command, "--help"])
        assert stop.value.code == 0
        out = capsys.readouterr().out
        assert "examples:" in out and f"membrane fem {command} " in out


def _console_script() -> str:
    script = Path(sys.executable).with_name("membrane")
    found = str(script) if script.exists() else shutil.which("membrane")
    if found is None:
        pytest.skip("the membrane console script is not installed")
    return found


@pytest.mark.slow
def test_the_acceptance_commands_through_the_console_script() -> None:
    membrane = _console_script()
    static = subprocess.run(
        [membrane, "fem", "static", *SQUARE, "--load", "1N"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert static.returncode == 0, static.stderr
    w = _number(r"deflection at the load: (\S+) mm", static.stdout)
    assert w == pytest.approx(3.315, rel=0.01)
    modes = subprocess.run(
        [membrane, "fem", "modes", "--shape", "disk", "--size", "40mm", *SQUARE[4:]],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert modes.returncode == 0, modes.stderr
    rows = _modes(modes.stdout)
    assert len(rows) == 10 and all(ref is not None for _, ref in rows)
    bad = subprocess.run(
        [membrane, "fem", "static", "--size", "50"], capture_output=True, text=True, timeout=120
    )
    assert (
        bad.returncode == 2
        and bad.stderr.strip() == "membrane fem: error: --size 50: give a unit, e.g. 50mm"
    )
