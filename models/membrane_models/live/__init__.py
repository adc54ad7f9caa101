"""Live engines: the tissue answers loads and probes, step by step.

``ModalEngine`` is the exact modal engine for the string and the membrane (``engine``); every
live engine offers the ``LiveEngine`` interface (``interface``): a state in, loads and probes
in; a new state, the frame and the probes' readings out. Bad input raises a ``LiveError`` (a
``membrane_errors.UserError``) and changes nothing. docs/LIVE.md has the conventions and the
measured figures.
"""

from membrane_models.live.engine import ModalEngine, ModalState
from membrane_models.live.errors import (
    InvalidEngineSettings,
    InvalidGrasp,
    InvalidLoad,
    InvalidProbe,
    InvalidShape,
    InvalidState,
    InvalidTool,
    LiveError,
)
from membrane_models.live.factory import build_modal_engine
from membrane_models.live.film import film_frames, film_load
from membrane_models.live.interface import (
    ENGINE_INPUTS,
    BatchedEngine,
    BoundedEngine,
    Grasp,
    GraspReading,
    Hold,
    LiveEngine,
    Load,
    LookaheadEngine,
    PreparingEngine,
    Probe,
    ProbeReading,
    Start,
    StepResult,
    Tool,
    ToolReading,
    WaitingEngine,
)

__all__ = [
    "ENGINE_INPUTS",
    "BatchedEngine",
    "BoundedEngine",
    "Grasp",
    "GraspReading",
    "Hold",
    "InvalidEngineSettings",
    "InvalidGrasp",
    "InvalidLoad",
    "InvalidProbe",
    "InvalidShape",
    "InvalidState",
    "InvalidTool",
    "LiveEngine",
    "LiveError",
    "Load",
    "LookaheadEngine",
    "ModalEngine",
    "ModalState",
    "PreparingEngine",
    "Probe",
    "ProbeReading",
    "Start",
    "StepResult",
    "Tool",
    "ToolReading",
    "WaitingEngine",
    "build_modal_engine",
    "film_frames",
    "film_load",
]
