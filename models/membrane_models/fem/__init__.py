"""The fem room: membranes and Kirchhoff plates on triangle meshes, in SI units.

Physics as small weak forms assembled with scikit-fem, one job per module:

- ``geometry``: ``Domain`` (a ``MeshTri``, named boundary parts, exact curves) and its
  builders ``rectangle``, ``disk``, ``ellipse``, ``polygon``; ``mesh_file.read_mesh``;
  ``gmsh_mesher`` (the ``mesh`` extra) meshes the ellipse and the polygon;
- ``models``: ``Membrane`` and ``Plate``; ``damping``: ``Damping``;
- ``forms``: the weak forms; ``boundary``: clamped / simply supported / free per part, the
  constrained space, the rigid-body check; ``assembly``: ``assemble`` -> ``System``;
- ``static``: point, pressure and patch loads, ``solve``; ``contact``: ``press``, rigid tools
  pressed in, the exact static contact on the mesh's vertices; ``modal``: ``modes``;
  ``sampling``: ``sample`` a field at points; ``stress``: von Mises at a point;
- ``von_karman``: the large-deflection plate's energy, residual and tangent; ``nonlinear``:
  ``solve_nonlinear``, its static state by Newton with load stepping, in-plane supports per
  part; ``nonlinear_transient``: ``step_nonlinear``, Newmark with Newton at every step;
  ``nonlinear_press``: rigid tools pressed into it on every DOF (the reduced engine's
  reference);
- ``reduced_plate``: the von Karman plate reduced to a few modes, the in-plane field condensed
  (``condensation``; its stretching energy a quartic, its force cubic); ``reduced_dynamics``:
  its energy-consistent step and static press with rigid tools; ``reduced_cache``: reduced
  plates kept beside the tables; ``adapted_basis``: a tool's static response added to the
  modes incrementally; ``basis_follower``: those kept where the tools are, built off the step;
  ``nonlinear_engine``: the ``fem-nonlinear`` engine kind.

Bad input raises a ``FemError`` (a ``membrane_errors.UserError``). Nothing here imports torch.
"""

from membrane_models.fem.assembly import System, assemble
from membrane_models.fem.boundary import CONDITIONS, Condition
from membrane_models.fem.contact import Pressed, press
from membrane_models.fem.damping import Damping
from membrane_models.fem.errors import (
    FemError,
    InvalidGeometry,
    InvalidLoad,
    InvalidModel,
    InvalidSolve,
    InvalidSupports,
    MissingMesher,
    OutsideDomain,
    RigidBodyModes,
)
from membrane_models.fem.geometry import (
    Circle,
    Curve,
    Domain,
    Ellipse,
    Frame,
    disk,
    ellipse,
    from_triangles,
    polygon,
    rectangle,
)
from membrane_models.fem.mesh_file import read_mesh
from membrane_models.fem.modal import Modes, modes
from membrane_models.fem.models import Membrane, Model, Plate
from membrane_models.fem.nonlinear import NonlinearSolution, membrane_force, solve_nonlinear
from membrane_models.fem.nonlinear_transient import NonlinearHistory, step_nonlinear
from membrane_models.fem.sampling import derivatives, sample, sampler
from membrane_models.fem.static import patch_load, point_load, pressure_load, solve
from membrane_models.fem.stress import SurfaceStress, surface_stress

__all__ = [
    "CONDITIONS",
    "Circle",
    "Condition",
    "Curve",
    "Damping",
    "Domain",
    "Ellipse",
    "FemError",
    "Frame",
    "InvalidGeometry",
    "InvalidLoad",
    "InvalidModel",
    "InvalidSolve",
    "InvalidSupports",
    "Membrane",
    "MissingMesher",
    "Model",
    "Modes",
    "NonlinearHistory",
    "NonlinearSolution",
    "OutsideDomain",
    "Plate",
    "Pressed",
    "RigidBodyModes",
    "SurfaceStress",
    "System",
    "assemble",
    "derivatives",
    "disk",
    "ellipse",
    "from_triangles",
    "membrane_force",
    "modes",
    "patch_load",
    "point_load",
    "polygon",
    "press",
    "pressure_load",
    "read_mesh",
    "rectangle",
    "sample",
    "sampler",
    "solve",
    "solve_nonlinear",
    "step_nonlinear",
    "surface_stress",
]
