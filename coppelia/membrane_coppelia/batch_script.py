"""The Lua script the adapter installs in the scene to move the whole lattice in one call.

The script text ships as package data (``batch_script.lua``). It defines one global function,
:data:`BATCH_FUNCTION`, called through ``sim.callScriptFunction(BATCH_FUNCTION, script, handles,
xyz, frame)``: ``handles`` a list of object handles, ``xyz`` their positions as one flat list of
floats (x1, y1, z1, x2, ...), ``frame`` the object the positions are relative to. It returns the
number of objects moved and raises a Lua error when the lengths disagree.
"""

from __future__ import annotations

from importlib import resources

__all__ = ["BATCH_FUNCTION", "BATCH_SCRIPT", "BATCH_SCRIPT_FILE"]

BATCH_FUNCTION = "membraneSetPositions"
BATCH_SCRIPT_FILE = "batch_script.lua"
BATCH_SCRIPT: str = (resources.files("membrane_coppelia") / BATCH_SCRIPT_FILE).read_text("utf-8")
