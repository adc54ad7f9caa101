"""The fem room's errors: bad input, refused before anything is meshed, assembled or solved.

Every class is a ``membrane_errors.UserError`` (and so a ``ValueError``) with a one-line
message: a shape or a file that cannot be meshed, a material out of range, a boundary condition
naming a part the domain lacks, a model whose supports leave it free to move as a rigid body, a
point off the domain, a request a system cannot answer.
"""

from __future__ import annotations

from membrane_errors import UserError

__all__ = [
    "FemError",
    "InvalidGeometry",
    "InvalidLoad",
    "InvalidModel",
    "InvalidSolve",
    "InvalidSupports",
    "MissingMesher",
    "OutsideDomain",
    "RigidBodyModes",
]


class FemError(UserError):
    """Bad input to the fem room; nothing was built."""


class InvalidGeometry(FemError):
    """A shape, a mesh or a mesh file that cannot make a domain."""


class MissingMesher(FemError):
    """The shape needs gmsh, which the ``mesh`` extra installs."""


class InvalidModel(FemError):
    """A material or a damping setting out of range."""


class InvalidSupports(FemError):
    """A boundary condition naming an unknown part or condition."""


class RigidBodyModes(FemError):
    """The supports leave a rigid-body motion free: no static solution, a zero frequency."""


class OutsideDomain(FemError):
    """A point (a load's, a sample's) that is not on the mesh."""


class InvalidLoad(FemError):
    """A load whose size or extent cannot be applied."""


class InvalidSolve(FemError):
    """A request this system cannot answer (a mode count, a field it cannot sample)."""
