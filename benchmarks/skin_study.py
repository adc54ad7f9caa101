"""The study's skin patch under its 1 N load: the modelling choices that move its answers.

The patch: a 50 mm x 50 mm Kirchhoff plate, h = 3 mm, E = 1.5 MPa, nu = 0.45,
rho = 1109 kg/m^3 (D = E h^3 / (12 (1 - nu^2)) = 4.232e-3 N m), Argyris triangles. Tables
(markdown, printed in this order; docs/SKIN.md quotes them):

1. static, point load and uniform 5 mm patch (``fem.patch_load``) at the centre, clamped and
   simply supported, on meshes of 8 to 64 squares a side: the centre deflection (against
   0.005612 / 0.011601 P a^2 / D) and the surface von Mises stress at the load point, at the
   quadrature point nearest it, at r = h from it, and at the patch's centre;
2. a shear-deformable (Mindlin) estimate: the Kirchhoff deflection plus the shear deflection
   w_s, the deflection of a membrane of tension kappa G h (kappa = 5/6) under the same load
   (exact for a simply supported polygonal plate, Marcus' moment; an estimate when clamped);
   a point load's w_s grows without bound as the mesh is refined;
3. transient through the live core (``ModalStepper`` over ``fem_basis(live_tables(...))``,
   100 modes with the static correction, Gaussian footprint r = 2.5 mm, 2.5 mm triangles,
   dt = 0.05 ms): the load suddenly applied (zeta 0, 0.05, 0.12) and ramped linearly over
   100 ms (zeta 0.05), peak deflection at the centre against the same footprint's static one;
4. transient by exact modal superposition (the same 100 modes, the static correction of the
   rest) for the point and the 5 mm patch load: peak deflection and peak von Mises stress,
   cross-checked against the live core on the Gaussian footprint;
5. disks: the study's COMSOL geometry as written (R = 1 m, h = 0.01 m) and the area-equivalent
   disk (R = 28.2 mm, h = 3 mm), clamped and simply supported, point load: FEM against
   P R^2 / (16 pi D) and (3 + nu) / (1 + nu) times it, w / h, the first frequency against the
   axisymmetric frequency equations;
6. the COMSOL geometry's centre deflection at t = 0.1 .. 1 s under the suddenly applied 1 N
   (undamped, modal superposition of 100, 200 and 400 modes with the static correction)
   against the infinite plate's P t / (8 sqrt(D rho h)) and the static value, and the largest
   deflection within the first period; 6b: Mindlin's shear deflection of a disk in closed form;
7. the factors between modelling choices; 8: the loads at which w / h = 0.2 and 0.5.

One BLAS thread (threadpoolctl). About a minute on a 2-core machine; ``--plot`` also writes
the transient figure (matplotlib, the ``plot`` extra):

    python benchmarks/skin_study.py
    python benchmarks/skin_study.py --plot docs/skin-transient.png
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import numpy as np
from scipy.optimize import brentq
from scipy.special import iv, jv
from threadpoolctl import threadpool_limits

from membrane_models import fem
from membrane_models.fem.live_basis import fem_basis
from membrane_models.fem.sampling import derivatives
from membrane_models.fem.tables import footprint_loads, live_tables
from membrane_models.live import Load
from membrane_models.live.stepper import ModalStepper

E, NU, H, RHO = 1.5e6, 0.45, 0.003, 1109.0
SKIN = fem.Plate(youngs_modulus=E, poisson=NU, thickness=H, density=RHO)
D = SKIN.rigidity
SIDE, P = 0.05, 1.0
CENTRE = (SIDE / 2, SIDE / 2)
TOOL, FOOTPRINT = 0.005, 0.0025  # the patch load's radius; the live footprint's
MESHES = (8, 16, 32, 64)  # squares a side
LIVE_MESH = 20  # 2.5 mm triangles, the live skin patch's
ACCURATE = {"clamped": 0.005612, "simply_supported": 0.011601}  # w / (P a^2 / D), Timoshenko
SUPPORTS = ("clamped", "simply_supported")
SHORT = {"clamped": "clamped", "simply_supported": "simply supported"}
KAPPA_GH = 5 / 6 * E / (2 * (1 + NU)) * H  # Mindlin's shear stiffness kappa G h, N/m
MODES, DT, WINDOW, RAMP = 100, 5e-5, 0.04, 0.1
DISK_MODES = (100, 200, 400)  # the COMSOL disk's transient: modes stepped, the rest static
SS_COMSOL = "COMSOL as written simply_supported"
CURVES: dict[str, np.ndarray] = {}  # histories for --plot
ZETAS = (0.0, 0.05, 0.12)
LATTICE = (21, 21)
MIDDLE = (LATTICE[0] // 2) * LATTICE[1] + LATTICE[1] // 2


def von_mises(plate: fem.Plate, moments: np.ndarray) -> np.ndarray:
    """Surface von Mises (Pa) of moments (..., 3) = (M_x, M_y, M_xy) (N m/m)."""
    s = 6 * moments / plate.thickness**2
    sx, sy, txy = s[..., 0], s[..., 1], s[..., 2]
    return np.sqrt(sx * sx - sx * sy + sy * sy + 3 * txy * txy)


def moments_of(system: fem.System, u: np.ndarray, at: tuple[float, float]) -> np.ndarray:
    """(M_x, M_y, M_xy) (N m/m) of each column of u (N, k) at a point: (k, 3)."""
    plate = system.model
    assert isinstance(plate, fem.Plate)
    d, nu = plate.rigidity, plate.poisson
    columns = u.reshape(u.shape[0], -1)
    out = np.empty((columns.shape[1], 3))
    for k in range(columns.shape[1]):
        _, _, hess = derivatives(system, columns[:, k], np.array([at]))
        wxx, wxy, wyy = hess[0, 0, 0], hess[0, 0, 1], hess[0, 1, 1]
        out[k] = (-d * (wxx + nu * wyy), -d * (wyy + nu * wxx), -d * (1 - nu) * wxy)
    return out


def disk_frequency(plate: fem.Plate, radius: float, supports: str) -> float:
    """The axisymmetric first frequency (Hz): lambda^2 / R^2 sqrt(D / rho h) / (2 pi); clamped
    J0 I1 + I0 J1 = 0 (lambda^2 = 10.2158), simply supported
    J1 / J0 + I1 / I0 = 2 lambda / (1 - nu)."""
    if supports == "clamped":
        root = brentq(lambda x: jv(0, x) * iv(1, x) + iv(0, x) * jv(1, x), 2.5, 3.5)
    else:
        nu = plate.poisson
        root = brentq(
            lambda x: jv(1, x) / jv(0, x) + iv(1, x) / iv(0, x) - 2 * x / (1 - nu), 1.5, 2.3
        )
    return root**2 / radius**2 * math.sqrt(plate.rigidity / plate.areal_density) / (2 * math.pi)


def nearest_quadrature_point(system: fem.System, at: tuple[float, float]) -> tuple[float, float]:
    x = np.asarray(system.basis.global_coordinates()).reshape(2, -1)
    k = int(np.argmin((x[0] - at[0]) ** 2 + (x[1] - at[1]) ** 2))
    return float(x[0, k]), float(x[1, k])


def table(header: list[str], rows: list[list[str]]) -> None:
    print("| " + " | ".join(header) + " |")
    print("|" + " --- |" * len(header))
    for row in rows:
        print("| " + " | ".join(row) + " |")
    print()


def static_square() -> dict[str, dict[str, float]]:
    """Tables 1 and 2; returns the finest mesh's figures per support."""
    rows, mindlin_rows, finest = [], [], {}
    shear_model = fem.Membrane(tension=KAPPA_GH, areal_density=1.0)
    for supports in SUPPORTS:
        for n in MESHES:
            system = fem.assemble(fem.rectangle(SIDE, SIDE, SIDE / n), SKIN, supports)
            both = np.stack(
                [fem.point_load(system, P, CENTRE), fem.patch_load(system, P, CENTRE, TOOL)], 1
            )
            u_point, u_patch = fem.solve(system, both).T
            w_point = float(fem.sample(system, u_point, CENTRE))
            w_patch = float(fem.sample(system, u_patch, CENTRE))
            quad = nearest_quadrature_point(system, CENTRE)
            at_h = (CENTRE[0] + H, CENTRE[1])
            sigma = {
                "load": fem.surface_stress(system, u_point, CENTRE).von_mises,
                "quad": fem.surface_stress(system, u_point, quad).von_mises,
                "h": fem.surface_stress(system, u_point, at_h).von_mises,
                "patch": fem.surface_stress(system, u_patch, CENTRE).von_mises,
            }
            reference = ACCURATE[supports] * P * SIDE**2 / D
            rows.append(
                [
                    SHORT[supports],
                    f"{SIDE / n * 1e3:.3f}",
                    str(system.free),
                    f"{w_point * 1e3:.4f}",
                    f"{w_point / reference - 1:+.1e}",
                    f"{sigma['load'] / 1e3:.1f}",
                    f"{math.hypot(quad[0] - CENTRE[0], quad[1] - CENTRE[1]) * 1e3:.3f}",
                    f"{sigma['quad'] / 1e3:.1f}",
                    f"{sigma['h'] / 1e3:.2f}",
                    f"{w_patch * 1e3:.4f}",
                    f"{sigma['patch'] / 1e3:.2f}",
                ]
            )
            shear = fem.assemble(fem.rectangle(SIDE, SIDE, SIDE / n), shear_model, "clamped")
            shear_loads = np.stack(
                [fem.point_load(shear, P, CENTRE), fem.patch_load(shear, P, CENTRE, TOOL)], 1
            )
            ws_point, ws_patch = fem.sample(shear, fem.solve(shear, shear_loads), CENTRE)
            mindlin_rows.append(
                [
                    SHORT[supports],
                    f"{SIDE / n * 1e3:.3f}",
                    f"{w_point * 1e3:.4f}",
                    f"{ws_point * 1e3:.4f}",
                    f"{(w_point + ws_point) / w_point:.4f}",
                    f"{w_patch * 1e3:.4f}",
                    f"{ws_patch * 1e3:.4f}",
                    f"{(w_patch + ws_patch) / w_patch:.4f}",
                ]
            )
            finest[supports] = {
                "w_point": w_point,
                "w_patch": w_patch,
                "ws_patch": ws_patch,
                **sigma,
            }
    print("Table 1. Static, 1 N at the centre of the 50 mm square: point load and a 5 mm")
    print("uniform patch (fem.patch_load); element = the squares' side (two triangles each).\n")
    table(
        [
            "supports",
            "element (mm)",
            "free DOFs",
            "point: w (mm)",
            "w against Timoshenko",
            "point: von Mises at the load (kPa)",
            "nearest quadrature point: r (mm)",
            "von Mises there (kPa)",
            "von Mises at r = h (kPa)",
            "patch: w (mm)",
            "patch: von Mises at its centre (kPa)",
        ],
        rows,
    )
    growth = (1 + NU) * P / (4 * math.pi) * math.log(2) * 6 / H**2
    print(
        f"Kirchhoff's point-load moment grows as (1 + nu) P / (4 pi) ln(1/r): each halving of "
        f"the element adds (1 + nu) P ln 2 / (4 pi) x 6 / h^2 = {growth / 1e3:.2f} kPa at the "
        "load.\n"
    )
    print(
        f"Table 2. Mindlin estimate: w_s, the deflection of a membrane of tension kappa G h = "
        f"{KAPPA_GH:.1f} N/m (kappa = 5/6, G = E / (2 (1 + nu))) under the same load, P2 "
        "triangles on the same mesh; exact for the simply supported square (w_M = w_K + "
        "M / (kappa G h)), an estimate for the clamped one.\n"
    )
    table(
        [
            "supports",
            "element (mm)",
            "point: w_K (mm)",
            "point: w_s (mm)",
            "point: w_M / w_K",
            "patch: w_K (mm)",
            "patch: w_s (mm)",
            "patch: w_M / w_K",
        ],
        mindlin_rows,
    )
    per_halving = P / (2 * math.pi * KAPPA_GH) * math.log(2)
    print(
        f"Under a point load w_s grows by P ln 2 / (2 pi kappa G h) = {per_halving * 1e3:.4f} mm "
        "per halving of the element: a Mindlin plate's point deflection has no limit.\n"
    )
    return finest


def step_response(omega: np.ndarray, zeta: float, t: np.ndarray) -> np.ndarray:
    """q_k(t) of q'' + 2 zeta w q' + w^2 q = 1 (t >= 0) from rest: (times, modes)."""
    wt = omega[None, :] * t[:, None]
    wd = math.sqrt(1 - zeta * zeta)
    decay = np.exp(-zeta * wt)
    shape = np.cos(wd * wt) + zeta / wd * np.sin(wd * wt)
    return (1 - decay * shape) / omega[None, :] ** 2


def first_maximum(w: np.ndarray, floor: float) -> int:
    """The index of the first local maximum of w above ``floor``."""
    rising = np.flatnonzero((w[1:-1] > floor) & (w[1:-1] >= w[:-2]) & (w[1:-1] > w[2:]))
    return int(rising[0]) + 1 if rising.size else int(np.argmax(w))


def live_history(tables: object, zeta: float, steps: int, ramp: float | None = None) -> np.ndarray:
    basis = fem_basis(tables)  # type: ignore[arg-type]
    engine = ModalStepper(basis, DT, damping=zeta, hold="foh" if ramp else "zoh")
    state, out = engine.start().state, np.empty(steps)
    for index in range(1, steps + 1):
        force = P if ramp is None else P * min(index * DT / ramp, 1.0)
        result = engine.step(state, [Load(CENTRE, force, FOOTPRINT)])
        state = result.state
        assert result.frame is not None
        out[index - 1] = result.frame[MIDDLE]
    return out


def transient_square() -> dict[str, dict[str, float]]:
    """Tables 3 and 4; returns peak / static figures per support."""
    live_rows, modal_rows, figures, shares = [], [], {}, []
    t = np.arange(1, round(WINDOW / DT) + 1) * DT
    for supports in SUPPORTS:
        system = fem.assemble(fem.rectangle(SIDE, SIDE, SIDE / LIVE_MESH), SKIN, supports)
        modes = fem.modes(system, MODES)
        tables = live_tables(system, modes, LATTICE, [FOOTPRINT])
        gauss = footprint_loads(system, FOOTPRINT, np.array([CENTRE]))[:, 0]
        w_gauss = float(fem.sample(system, fem.solve(system, gauss), CENTRE))
        f1 = modes.frequency[0]
        figures[supports] = {"f1": f1}
        for zeta in ZETAS:
            history = live_history(tables, zeta, t.size)
            CURVES[f"{supports} {zeta:g}"] = history
            k = int(np.argmax(history))
            first = first_maximum(history, w_gauss)
            live_rows.append(
                [
                    SHORT[supports],
                    "suddenly applied",
                    f"{zeta:g}",
                    f"{w_gauss * 1e3:.4f}",
                    f"{history[first] * 1e3:.4f} at {t[first] * 1e3:.2f}",
                    f"{history[k] * 1e3:.4f} at {t[k] * 1e3:.2f}",
                    f"{history[k] / w_gauss:.4f}",
                    f"{1 + math.exp(-math.pi * zeta / math.sqrt(1 - zeta * zeta)):.4f}",
                ]
            )
            figures[supports][f"live {zeta:g}"] = history[k] / w_gauss
        ramp_steps = round((RAMP + WINDOW) / DT)
        slow = live_history(tables, 0.05, ramp_steps, RAMP)
        k = int(np.argmax(slow))
        live_rows.append(
            [
                SHORT[supports],
                f"ramped over {RAMP * 1e3:.0f} ms, held {WINDOW * 1e3:.0f} ms",
                "0.05",
                f"{w_gauss * 1e3:.4f}",
                "",
                f"{slow[k] * 1e3:.4f} at {(k + 1) * DT * 1e3:.2f}",
                f"{slow[k] / w_gauss:.4f} (final {slow[-1] / w_gauss:.4f})",
                "",
            ]
        )
        figures[supports]["ramp"] = slow[k] / w_gauss
        CURVES[f"{supports} static"] = np.array([w_gauss])
        CURVES["t"] = t
        # Exact modal superposition, the same modes and static correction, three loads.
        probe_h = (CENTRE[0] + H, CENTRE[1])
        loads = {
            "Gaussian r = 2.5 mm": gauss,
            "point": fem.point_load(system, P, CENTRE),
            "5 mm patch": fem.patch_load(system, P, CENTRE, TOOL),
        }
        at_centre = fem.sample(system, modes.shapes, CENTRE)
        moment_centre = moments_of(system, modes.shapes, CENTRE)
        moment_h = moments_of(system, modes.shapes, probe_h)
        for name, load in loads.items():
            u_static = fem.solve(system, load)
            s = modes.shapes.T @ load
            residual = u_static - modes.shapes @ (s / modes.omega**2)
            w_res = float(fem.sample(system, residual, CENTRE))
            m_res_c = moments_of(system, residual, CENTRE)[0]
            m_res_h = moments_of(system, residual, probe_h)[0]
            w_static = float(fem.sample(system, u_static, CENTRE))
            sig_static = float(von_mises(SKIN, moments_of(system, u_static, CENTRE)[0]))
            sig_static_h = float(von_mises(SKIN, moments_of(system, u_static, probe_h)[0]))
            if name == "point":
                shares.append(
                    f"{SHORT[supports]}: w {w_res / w_static:.4f}, M_x at the load "
                    f"{m_res_c[0] / moments_of(system, u_static, CENTRE)[0, 0]:.3f}, M_x at r = h "
                    f"{m_res_h[0] / moments_of(system, u_static, probe_h)[0, 0]:+.3f}"
                )
            for zeta in ZETAS:
                g = step_response(modes.omega, zeta, t) * s[None, :]
                w = g @ at_centre + w_res
                sig = von_mises(SKIN, g @ moment_centre + m_res_c)
                sig_h = von_mises(SKIN, g @ moment_h + m_res_h)
                k = int(np.argmax(w))
                first = first_maximum(w, w_static)
                row = [
                    SHORT[supports],
                    name,
                    f"{zeta:g}",
                    f"{w_static * 1e3:.4f}",
                    f"{w[first] * 1e3:.4f} ({w[first] / w_static:.4f}) at {t[first] * 1e3:.2f}",
                    f"{w[k] * 1e3:.4f} ({w[k] / w_static:.4f}) at {t[k] * 1e3:.2f}",
                    f"{sig_static / 1e3:.2f}",
                    f"{sig.max() / 1e3:.2f} ({sig.max() / sig_static:.4f})",
                ]
                if name == "point":
                    row.append(
                        f"{sig_static_h / 1e3:.2f} / {sig_h.max() / 1e3:.2f}"
                        f" ({sig_h.max() / sig_static_h:.4f})"
                    )
                else:
                    row.append("")
                modal_rows.append(row)
                figures[supports][f"{name} {zeta:g}"] = w[k] / w_static
                figures[supports][f"{name} {zeta:g} first"] = w[first] / w_static
                if name == "point" and zeta == 0:
                    figures[supports]["point peak w"] = w[k]
                    figures[supports]["point static w"] = w_static
                    figures[supports]["point peak sigma h"] = float(sig_h.max())
                    figures[supports]["point static sigma h"] = sig_static_h
                if name == "5 mm patch" and zeta == 0:
                    figures[supports]["patch peak sigma"] = float(sig.max())
        figures[supports]["modal gauss 0"] = figures[supports]["Gaussian r = 2.5 mm 0"]
    print(
        f"Table 3. Transient through the live core: ModalStepper over fem_basis(live_tables(...)),"
        f" {MODES} modes and the static correction, 2.5 mm triangles, 1 N Gaussian footprint "
        f"r = 2.5 mm at the centre, dt = {DT * 1e3:g} ms, {WINDOW * 1e3:.0f} ms window; w at "
        "the centre (the frame's middle lattice point). Static: the same footprint, fem.solve. "
        "Single oscillator: 1 + exp(-pi zeta / sqrt(1 - zeta^2)).\n"
    )
    table(
        [
            "supports",
            "load history",
            "zeta",
            "static w (mm)",
            "first maximum w (mm) at (ms)",
            "largest w in the window (mm) at (ms)",
            "largest / static",
            "one oscillator",
        ],
        live_rows,
    )
    for supports in SUPPORTS:
        f1 = figures[supports]["f1"]
        print(f"{SHORT[supports]}: first frequency {f1:.2f} Hz, period {1e3 / f1:.2f} ms.")
    print()
    print(
        f"Table 4. The suddenly applied load by exact modal superposition (the same {MODES} "
        "modes, the static correction of the rest, 0.05 ms samples over 40 ms): w and von "
        "Mises at the centre; the point load's stress also at r = h (static / peak).\n"
    )
    table(
        [
            "supports",
            "load",
            "zeta",
            "static w (mm)",
            "first maximum w (mm) (/ static) at (ms)",
            "largest w (mm) (/ static) at (ms)",
            "static von Mises (kPa)",
            "peak von Mises (kPa) (/ static)",
            "point: von Mises at r = h, static / peak (kPa)",
        ],
        modal_rows,
    )
    print(
        "The static correction's share of the static point-load response (the modes above the "
        f"{MODES}th, held at their static value): " + "; ".join(shares) + ".\n"
    )
    for supports in SUPPORTS:
        live, modal = figures[supports]["live 0"], figures[supports]["modal gauss 0"]
        print(
            f"{SHORT[supports]}, Gaussian, zeta 0: live core {live:.5f}, modal superposition "
            f"{modal:.5f} (peak / static; difference {live / modal - 1:+.1e})."
        )
    print()
    return figures


def disks() -> dict[str, float]:
    """Tables 5 and 6."""
    rows, figures = [], {}
    comsol = fem.Plate(youngs_modulus=E, poisson=NU, thickness=0.01, density=RHO)
    equivalent = SIDE / math.sqrt(math.pi)
    cases = (
        ("COMSOL as written", 1.0, comsol, 1.0 / 15),
        ("area-equivalent", equivalent, SKIN, equivalent / 15),
    )
    transient_systems = {}
    for name, radius, plate, size in cases:
        d = plate.rigidity
        for supports in SUPPORTS:
            system = fem.assemble(fem.disk(radius, size), plate, supports)
            u = fem.solve(system, fem.point_load(system, P, (0.0, 0.0)))
            w = float(fem.sample(system, u, (0.0, 0.0)))
            closed = P * radius**2 / (16 * math.pi * d)
            if supports == "simply_supported":
                closed *= (3 + NU) / (1 + NU)
            modes = fem.modes(system, 1)
            f1 = float(modes.frequency[0])
            f1_closed = disk_frequency(plate, radius, supports)
            rows.append(
                [
                    name,
                    f"{radius * 1e3:.1f}",
                    f"{plate.thickness * 1e3:g}",
                    f"{d:.4e}",
                    SHORT[supports],
                    str(system.free),
                    f"{w * 1e3:.4g}",
                    f"{closed * 1e3:.4g}",
                    f"{w / closed - 1:+.1e}",
                    f"{w / plate.thickness:.3g}",
                    f"{f1:.4g} ({f1_closed:.4g})",
                    f"{1 / f1:.4g}" if f1 < 10 else f"{1e3 / f1:.4g} ms",
                ]
            )
            figures[f"{name} {supports}"] = w
            figures[f"{name} {supports} f1"] = f1
            if name == "COMSOL as written":
                coarse = fem.assemble(fem.disk(radius, 2 * size), plate, supports)
                transient_systems[supports] = (coarse, w)
    print(
        "Table 5. Disks under 1 N at the centre, point load, FEM (Argyris, element R / 15, "
        "4096 triangles) against P R^2 / (16 pi D) (clamped) and (3 + nu) / (1 + nu) "
        "P R^2 / (16 pi D) (simply supported).\n"
    )
    table(
        [
            "disk",
            "R (mm)",
            "h (mm)",
            "D (N m)",
            "supports",
            "free DOFs",
            "w (mm)",
            "closed form (mm)",
            "difference",
            "w / h",
            "f_1 (Hz) (closed form)",
            "first period (s)",
        ],
        rows,
    )
    times = np.arange(1, 11) * 0.1
    fine = np.linspace(0.0, 12.0, 12001)[1:]
    sqrt_dm = math.sqrt(comsol.rigidity * comsol.areal_density)
    infinite = P * times / (8 * sqrt_dm)
    columns, peaks = {}, []
    for supports, (system, w_static) in transient_systems.items():
        every = fem.modes(system, DISK_MODES[-1])
        load = fem.point_load(system, P, (0.0, 0.0))
        u_static = fem.solve(system, load)
        for count in DISK_MODES:
            modes = fem.Modes(every.omega[:count], every.shapes[:, :count])
            s = modes.shapes.T @ load
            residual = u_static - modes.shapes @ (s / modes.omega**2)
            phi0 = fem.sample(system, modes.shapes, (0.0, 0.0))
            w_res = float(fem.sample(system, residual, (0.0, 0.0)))
            columns[(supports, count)] = step_response(modes.omega, 0.0, times) @ (s * phi0)
            columns[(supports, count)] += w_res
            if count == DISK_MODES[-1]:
                history = step_response(modes.omega, 0.0, fine) @ (s * phi0) + w_res
                CURVES[f"comsol {supports}"] = history
                period = 2 * math.pi / float(every.omega[0])
                first = int(np.argmax(np.where(fine <= period, history, -np.inf)))
                peaks.append(
                    f"{SHORT[supports]}: largest within the first period ({period:.2f} s) "
                    f"{history[first] * 1e3:.1f} mm ({history[first] / w_static:.3f} x static) "
                    f"at t = {fine[first]:.2f} s"
                )
        figures[f"comsol {supports} w(1 s)"] = float(columns[(supports, DISK_MODES[-1])][-1])
        figures[f"comsol {supports} static"] = w_static
    CURVES["comsol t"] = fine
    print(
        "Table 6. The COMSOL geometry as written (R = 1 m, h = 10 mm), 1 N suddenly applied at "
        "t = 0 at the centre, undamped: w at the centre (mm) by modal superposition (100, 200 "
        "or 400 modes and the static correction of the rest; a coarser mesh, "
        f"{transient_systems['clamped'][0].free} free DOFs clamped), against the infinite "
        f"plate's P t / (8 sqrt(D rho h)) = {P / (8 * sqrt_dm) * 1e3:.2f} mm/s x t; "
        "/ static: over table 5's static w.\n"
    )
    rows = []
    last = DISK_MODES[-1]
    for k, t in enumerate(times):
        rows.append(
            [
                f"{t:.1f}",
                " / ".join(f"{columns[('clamped', n)][k] * 1e3:.3f}" for n in DISK_MODES),
                f"{columns[('clamped', last)][k] / figures['COMSOL as written clamped']:.3f}",
                f"{columns[('simply_supported', last)][k] * 1e3:.3f}",
                f"{columns[('simply_supported', last)][k] / figures[SS_COMSOL]:.3f}",
                f"{infinite[k] * 1e3:.3f}",
            ]
        )
    table(
        [
            "t (s)",
            "clamped, 100 / 200 / 400 modes (mm)",
            "clamped / static",
            f"simply supported, {last} modes (mm)",
            "simply supported / static",
            "infinite plate (mm)",
        ],
        rows,
    )
    print("Undamped, 400 modes: " + "; ".join(peaks) + ".\n")
    # Mindlin's shear deflection in closed form (axisymmetric: the same for both supports).
    shear = []
    for name, radius, plate in (
        ("area-equivalent, point load, at r = h", equivalent, SKIN),
        ("area-equivalent, 5 mm patch, at the centre", equivalent, SKIN),
        ("COMSOL as written, point load, at r = h", 1.0, comsol),
    ):
        kgh = 5 / 6 * E / (2 * (1 + NU)) * plate.thickness
        if "patch" in name:
            ws = P / (2 * math.pi * kgh) * (math.log(radius / TOOL) + 0.5)
        else:
            ws = P / (2 * math.pi * kgh) * math.log(radius / plate.thickness)
        key = "COMSOL as written clamped" if "COMSOL" in name else "area-equivalent clamped"
        shear.append([name, f"{kgh:.1f}", f"{ws * 1e3:.4f}", f"{ws / figures[key]:.4f}"])
    print(
        "Table 6b. Mindlin's shear deflection of a disk in closed form, w_s(r) = (1 / kappa G h)"
        " int_r^R |Q| dr: P / (2 pi kappa G h) ln(R / r) for a point load (unbounded at r = 0),"
        " P / (2 pi kappa G h) (ln(R / c) + 1/2) at the centre of a uniform patch of radius c;"
        " against the clamped point-load Kirchhoff w of table 5.\n"
    )
    table(["disk, load, where", "kappa G h (N/m)", "w_s (mm)", "w_s / w_K (clamped)"], shear)
    return figures


def summary(static: dict, dynamic: dict, disk: dict) -> None:
    """Table 7 (the factors) and table 8 (where linear theory stops)."""
    c, s = static["clamped"], static["simply_supported"]
    rows = [
        [
            "simply supported / clamped edges, point load, w",
            f"{s['w_point'] * 1e3:.3f} / {c['w_point'] * 1e3:.3f} mm",
            f"{s['w_point'] / c['w_point']:.3f}",
        ],
        [
            "simply supported / clamped, 5 mm patch, von Mises at the centre",
            f"{s['patch'] / 1e3:.1f} / {c['patch'] / 1e3:.1f} kPa",
            f"{s['patch'] / c['patch']:.3f}",
        ],
        [
            "point (at r = h) / 5 mm patch (centre), clamped, von Mises",
            f"{c['h'] / 1e3:.1f} / {c['patch'] / 1e3:.1f} kPa",
            f"{c['h'] / c['patch']:.3f}",
        ],
        [
            f"point (at the load, {SIDE / MESHES[-1] * 1e3:.2f} mm mesh) / 5 mm patch, clamped",
            f"{c['load'] / 1e3:.1f} / {c['patch'] / 1e3:.1f} kPa",
            f"{c['load'] / c['patch']:.3f}",
        ],
        [
            "point / 5 mm patch, clamped, w",
            f"{c['w_point'] * 1e3:.3f} / {c['w_patch'] * 1e3:.3f} mm",
            f"{c['w_point'] / c['w_patch']:.3f}",
        ],
        [
            "area-equivalent disk / square, clamped, point load, w",
            f"{disk['area-equivalent clamped'] * 1e3:.3f} / {c['w_point'] * 1e3:.3f} mm",
            f"{disk['area-equivalent clamped'] / c['w_point']:.3f}",
        ],
        [
            "COMSOL disk as written (R 1 m, h 10 mm) / square, clamped, w",
            f"{disk['COMSOL as written clamped'] * 1e3:.1f} / {c['w_point'] * 1e3:.3f} mm",
            f"{disk['COMSOL as written clamped'] / c['w_point']:.1f}",
        ],
        [
            "suddenly applied (undamped, largest in 40 ms) / static, clamped, point load, w "
            "(table 4)",
            f"{dynamic['clamped']['point peak w'] * 1e3:.3f} / "
            f"{dynamic['clamped']['point static w'] * 1e3:.3f} mm",
            f"{dynamic['clamped']['point 0']:.3f}",
        ],
        [
            "the same, first maximum at zeta 0.05 / zeta 0.12",
            "",
            f"{dynamic['clamped']['point 0.05 first']:.3f} / "
            f"{dynamic['clamped']['point 0.12 first']:.3f}",
        ],
        [
            "suddenly applied / static, clamped, von Mises at r = h from the point (table 4)",
            f"{dynamic['clamped']['point peak sigma h'] / 1e3:.1f} / "
            f"{dynamic['clamped']['point static sigma h'] / 1e3:.1f} kPa",
            f"{dynamic['clamped']['point peak sigma h'] / dynamic['clamped']['point static sigma h']:.3f}",  # noqa: E501
        ],
        [
            "Kirchhoff + shear (Mindlin estimate) / Kirchhoff, clamped, 5 mm patch, w",
            f"{(c['w_patch'] + c['ws_patch']) * 1e3:.3f} / {c['w_patch'] * 1e3:.3f} mm",
            f"{(c['w_patch'] + c['ws_patch']) / c['w_patch']:.3f}",
        ],
        [
            "COMSOL disk, clamped: w at t = 1 s (suddenly applied) / static",
            f"{disk['comsol clamped w(1 s)'] * 1e3:.1f} / "
            f"{disk['comsol clamped static'] * 1e3:.1f} mm",
            f"{disk['comsol clamped w(1 s)'] / disk['comsol clamped static']:.3f}",
        ],
    ]
    print(
        "Table 7. Factors between modelling choices (1 N; static rows: the finest square mesh "
        "of table 1; transient rows: table 4's 2.5 mm mesh, against its own static values).\n"
    )
    table(["choice", "values", "factor"], rows)
    rows = []
    for supports in SUPPORTS:
        figures = static[supports]
        for load in ("point", "patch"):
            w = figures[f"w_{load}"]
            rows.append(
                [
                    SHORT[supports],
                    "point" if load == "point" else "5 mm patch",
                    f"{w * 1e3:.3f}",
                    f"{w / H:.3f}",
                    f"{0.2 * H / w * P:.4f}",
                    f"{0.5 * H / w * P:.4f}",
                ]
            )
    print("Table 8. Linear theory's reach: w / h under 1 N and the loads that give w / h = 0.2")
    print("and 0.5 (linear scaling).\n")
    table(
        ["supports", "load", "w under 1 N (mm)", "w / h", "P at w/h = 0.2 (N)", "P at 0.5 (N)"],
        rows,
    )


def plot(path: Path) -> None:
    """The clamped patch's live-core histories and the COMSOL disk's, as one figure."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, (left, right) = plt.subplots(1, 2, figsize=(11, 4))
    t = CURVES["t"] * 1e3
    for zeta in ZETAS:
        left.plot(t, CURVES[f"clamped {zeta:g}"] * 1e3, label=f"zeta = {zeta:g}")
    left.axhline(CURVES["clamped static"][0] * 1e3, color="k", ls="--", lw=1, label="static")
    left.set(xlabel="t (ms)", ylabel="w at the centre (mm)", xlim=(0, 40))
    left.set_title("50 mm patch, clamped, 1 N suddenly applied (live core)", fontsize=10)
    left.legend(fontsize=8)
    times = CURVES["comsol t"]
    for supports in SUPPORTS:
        right.plot(times, CURVES[f"comsol {supports}"] * 1e3, label=SHORT[supports])
    right.axvspan(0, 1, color="0.9", label="the study's 1 s window")
    samples = np.arange(1, 11) * 0.1
    for supports in SUPPORTS:
        right.plot(samples, np.interp(samples, times, CURVES[f"comsol {supports}"]) * 1e3, "k.")
    right.set(xlabel="t (s)", ylabel="w at the centre (mm)", xlim=(0, 12))
    right.set_title("R = 1 m, h = 10 mm disk, 1 N suddenly applied (undamped)", fontsize=10)
    right.legend(fontsize=8)
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    print(f"wrote {path}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--plot", type=Path, help="write the transient figure (PNG) here")
    arguments = parser.parse_args()
    started = time.perf_counter()
    with threadpool_limits(1):
        print(f"D = {D:.4e} N m; kappa G h = {KAPPA_GH:.2f} N/m\n")
        static = static_square()
        dynamic = transient_square()
        disk = disks()
        summary(static, dynamic, disk)
    if arguments.plot:
        plot(arguments.plot)
    print(f"({time.perf_counter() - started:.0f} s)")


if __name__ == "__main__":
    main()
