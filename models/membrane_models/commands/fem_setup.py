"""What every `membrane fem` subcommand builds first: the domain, the model and the supports.

``tissue(args)`` reads the common options (quantities with units, ``physical.units``), checks
them with messages naming the flag, and builds a ``Tissue``; ``describe`` writes its model and
mesh lines. Imported by the handlers only: it imports the fem room (scikit-fem, scipy).
"""

from __future__ import annotations

import argparse
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from membrane_cli.arguments import UsageError
from membrane_models import fem
from membrane_models.physical.units import format_quantity, parse_quantity

__all__ = [
    "Tissue",
    "centroid",
    "describe",
    "load_point",
    "millimetres",
    "parse_point",
    "positive",
    "tissue",
]

FloatArray = NDArray[np.float64]
_PER_SIDE = 20  # default element size: the shape's size / 20 (3.315 mm within 0.1 %: see tests)
_PER_DIAMETER = 15  # a disk's: scikit-fem's disk halves its edges per level; /15 keeps the
# level whose longest edge is 0.129 R (1,024 triangles), /20 would take the next (4,096)


@dataclass(frozen=True)
class Tissue:
    """A model on a domain with its supports, and what the closed forms need to know.

    Attributes:
        shape: one of ``fem.SHAPES``.
        dimensions: square (side,), rectangle and ellipse (x axis, y axis), disk (diameter,),
            polygon and mesh () (m).
        domain, model, supports: what ``fem.assemble`` takes.
        element_size: the target edge length asked of the mesher (m; a read mesh: its longest).
        label: the shape in words ("square 50 mm", "mesh plate.msh").
    """

    shape: str
    dimensions: tuple[float, ...]
    domain: fem.Domain
    model: fem.Model
    supports: str | dict[str, str]
    element_size: float
    label: str

    @property
    def uniform_support(self) -> str | None:
        """The one condition on every part, or None when parts differ."""
        if isinstance(self.supports, str):
            return self.supports
        conditions = set(self.supports.values())
        if len(conditions) == 1 and set(self.supports) == set(self.domain.parts):
            return conditions.pop()
        return None


def tissue(args: argparse.Namespace) -> Tissue:
    """The tissue the common options describe (bad input: ``UsageError``, ``FemError``)."""
    model = _model(args)
    shape, dimensions = args.shape, _dimensions(args)
    size = _element_size(args, shape, dimensions)
    domain = _domain(args, shape, dimensions, size)
    if shape == "mesh":
        size = domain.size
    label = _label(args, shape, dimensions)
    return Tissue(shape, dimensions, domain, model, _supports(args.supports), size, label)


def positive(text: str, kind: str, flag: str, *, zero: bool = False) -> float:
    """A quantity > 0 (>= 0 with ``zero``), its flag named when it is not."""
    value = parse_quantity(text, kind, name=flag)
    if not (value >= 0.0 if zero else value > 0.0):
        raise UsageError(f"{flag} {text}: must be {'>= 0' if zero else 'positive'}")
    return value


def parse_point(text: str, flag: str) -> FloatArray:
    """``"X,Y"`` in mm (or with units) -> (x, y) in m."""
    parts = text.split(",")
    if len(parts) != 2:
        raise UsageError(f"{flag} {text}: give X,Y in mm, e.g. {flag} 25,25")
    return np.array(
        [parse_quantity(p.strip(), "length", name=flag, default_unit="mm") for p in parts]
    )


def load_point(args: argparse.Namespace, domain: fem.Domain) -> FloatArray:
    """``--at`` (default: the centroid), refused when it is off the mesh."""
    at = parse_point(args.at, "--at") if args.at is not None else centroid(domain)
    try:
        domain.mesh.element_finder()(at[:1], at[1:])
    except ValueError:
        where = "the mesh's centroid" if args.at is None else f"--at {args.at}:"
        raise UsageError(
            f"{where} {millimetres(at)} is off the mesh: give --at X,Y in mm"
        ) from None
    return at


def centroid(domain: fem.Domain) -> FloatArray:
    """The mesh's area centroid (m)."""
    p, t = domain.mesh.p, domain.mesh.t
    corners = p[:, t]  # (2, 3, triangles)
    e1, e2 = corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]
    area = 0.5 * np.abs(e1[0] * e2[1] - e1[1] * e2[0])
    middle = np.asarray(corners.mean(axis=1) @ area / area.sum(), dtype=np.float64)
    extent = float(np.ptp(p, axis=1).max())
    return np.where(np.abs(middle) < 1e-12 * extent, 0.0, middle)  # a disk's: 0, not 1e-18


def describe(item: Tissue, system: fem.System) -> list[str]:
    """The model's line and the mesh's line."""
    model = item.model
    if isinstance(model, fem.Plate):
        parts = [
            f"plate: E {format_quantity(model.youngs_modulus, 'pressure')}",
            f"nu {model.poisson:g}",
            f"h {format_quantity(model.thickness, 'length')}",
            f"rho {format_quantity(model.density, 'density')}",
        ]
        if model.pretension:
            parts.append(f"pre-tension {format_quantity(model.pretension, 'tension')}")
        if model.foundation:
            parts.append(f"foundation {format_quantity(model.foundation, 'foundation')}")
        model_line = ", ".join(parts) + f"; D = {model.rigidity:.4g} N m"
    else:
        model_line = (
            f"membrane: T {format_quantity(model.tension, 'tension')}, "
            f"rho h {model.areal_density:.4g} kg/m2; c = {model.wave_speed:.4g} m/s"
        )
    supports = (
        item.supports
        if isinstance(item.supports, str)
        else ", ".join(f"{part} {condition}" for part, condition in item.supports.items())
    )
    mesh_line = (
        f"mesh: {item.label}, {item.domain.triangles} triangles ({system.element}), "
        f"{system.dofs} DOFs, element size {_mm_value(item.element_size)} mm; {supports}"
    )
    return [model_line, mesh_line]


def _model(args: argparse.Namespace) -> fem.Model:
    thickness = positive(args.thickness, "length", "--thickness")
    density = positive(args.density, "density", "--density")
    tension = (
        None if args.tension is None else positive(args.tension, "tension", "--tension", zero=True)
    )
    foundation = 0.0
    if args.foundation is not None:
        foundation = positive(args.foundation, "foundation", "--foundation", zero=True)
    if args.model == "membrane":
        if tension is None or tension == 0.0:
            raise UsageError("--model membrane needs --tension, e.g. --tension 50N/m")
        if foundation:
            raise UsageError("--foundation is a plate's: a membrane here has none")
        return fem.Membrane(tension, density * thickness)
    modulus = positive(args.youngs_modulus, "pressure", "--E")
    if not -1.0 < args.poisson <= 0.5:
        raise UsageError(f"--nu {args.poisson:g}: Poisson's ratio lies in (-1, 0.5]")
    return fem.Plate(modulus, args.poisson, thickness, density, tension or 0.0, foundation)


def _dimensions(args: argparse.Namespace) -> tuple[float, ...]:
    shape = args.shape
    if shape in ("polygon", "mesh"):
        if args.size is not None:
            raise UsageError(
                f"--size is not for --shape {shape}: its "
                f"{'vertices' if shape == 'polygon' else 'file'} give the size"
            )
        return ()
    if args.size is None:
        example = "40mmx30mm" if shape in ("rectangle", "ellipse") else "50mm"
        raise UsageError(f"--shape {shape} needs --size, e.g. --size {example}")
    pieces = args.size.split("x")
    if shape in ("rectangle", "ellipse"):
        if len(pieces) != 2:
            raise UsageError(f"--size {args.size}: --shape {shape} takes AxB, e.g. 40mmx30mm")
        return tuple(positive(p.strip(), "length", "--size") for p in pieces)
    if len(pieces) != 1:
        what = "a diameter" if shape == "disk" else "a side (--shape rectangle takes AxB)"
        raise UsageError(f"--size {args.size}: --shape {shape} takes {what}, e.g. 50mm")
    return (positive(args.size, "length", "--size"),)


def _element_size(args: argparse.Namespace, shape: str, dimensions: tuple[float, ...]) -> float:
    if args.element_size is not None:
        if shape == "mesh":
            raise UsageError("--element-size is not for --shape mesh: the file is the mesh")
        return positive(args.element_size, "length", "--element-size")
    if shape == "disk":
        return dimensions[0] / _PER_DIAMETER
    if shape == "polygon":
        vertices = _loop(args.vertices, "--vertices")
        return float(np.ptp(vertices, axis=0).max()) / _PER_SIDE
    return max(dimensions, default=math.nan) / _PER_SIDE


def _domain(
    args: argparse.Namespace, shape: str, dimensions: tuple[float, ...], size: float
) -> fem.Domain:
    if shape == "square":
        return fem.rectangle(dimensions[0], dimensions[0], size)
    if shape == "rectangle":
        return fem.rectangle(dimensions[0], dimensions[1], size)
    if shape == "disk":
        return fem.disk(dimensions[0] / 2, size)
    if shape == "ellipse":
        return fem.ellipse(dimensions[0] / 2, dimensions[1] / 2, size)
    if shape == "polygon":
        holes = [_loop(hole, "--hole") for hole in args.hole]
        return fem.polygon(_loop(args.vertices, "--vertices"), size, holes)
    if args.mesh is None:
        raise UsageError("--shape mesh needs --mesh FILE (.msh, .vtk)")
    return fem.read_mesh(args.mesh)


def _loop(text: str | None, flag: str) -> FloatArray:
    """``"x,y;x,y;..."`` in mm -> (n, 2) in m."""
    if text is None:
        raise UsageError(
            '--shape polygon needs --vertices "x,y;x,y;..." in mm, e.g. "0,0;40,0;40,30;0,30"'
        )
    points = [point for point in text.split(";") if point.strip()]
    if len(points) < 3:
        raise UsageError(f'{flag} "{text}": give at least 3 points "x,y;x,y;x,y" in mm')
    return np.stack([parse_point(point, flag) for point in points])


def _supports(text: str) -> str | dict[str, str]:
    """``clamped`` or ``left=clamped,top=free`` (parts the domain lacks: fem refuses them)."""
    if "=" not in text:
        _condition(text, "--supports")
        return text
    supports = {}
    for item in text.split(","):
        part, _, condition = (piece.strip() for piece in item.partition("="))
        if not part or not condition:
            raise UsageError(f"--supports {text}: give PART=CONDITION,..., e.g. left=clamped")
        supports[part] = _condition(condition, "--supports")
    return supports


def _condition(text: str, flag: str) -> str:
    if text not in fem.CONDITIONS:
        raise UsageError(f"{flag} {text}: one of {', '.join(fem.CONDITIONS)}")
    return text


def _label(args: argparse.Namespace, shape: str, dimensions: tuple[float, ...]) -> str:
    sizes = "x".join(f"{_mm_value(d)}" for d in dimensions)
    if shape == "disk":
        return f"disk {sizes} mm diameter"
    if shape == "polygon":
        holes = f", {len(args.hole)} hole{'s' if len(args.hole) != 1 else ''}" if args.hole else ""
        return f"polygon{holes}"
    if shape == "mesh":
        return f"mesh {args.mesh}"
    return f"{shape} {sizes} mm"


def _mm_value(metres: float) -> str:
    return f"{metres * 1e3:.4g}"


def millimetres(point: FloatArray) -> str:
    """``(x, y)`` in m as ``"(x, y) mm"``."""
    return f"({_mm_value(float(point[0]))}, {_mm_value(float(point[1]))}) mm"
