"""Step 2 of the pipeline: the environment model, which tells the objects from what holds them.

Per request, on the preprocessed cloud, from the cameras and geometry alone (no container's dimensions):
- "up": against gravity when given, else the normal of the dominant plane, oriented toward the cameras;
- support levels: large up-facing planes at any height (the table; a container's floor raised above it; a
  platform's top), each larger than anything the hand could lift.  The lowest is `support` (a half-space the
  hand stays above, in closed form); each raised level is a solid slab down to the level below it;
- walls: near-vertical planar patches longer than any graspable object that rise from a level (tray, bin,
  box and shelf walls, either face; two-wall corners), modelled as boxes down to the lowest support;
- rims: long, thin horizontal lines of points above a level (thin sheet walls seen from above), modelled as
  thin walls down to the lowest support;
- what the caller declares (a support plane, boxes), which overrides what is found.
Every surface is reported (kind, plane, extent, confidence), and when the stage is unsure it says so in
`warnings`.  Candidates are sampled on object points only, their closing region must hold no environment
point, and no part of the hand or its approach path may enter the environment (see hand_hits_environment).
Everything is in the cloud frame, metres.
"""

from __future__ import annotations

from graspd.gpd.environment.collision import hand_hits_environment
from graspd.gpd.environment.levels import Level, find_inner_floor, find_levels
from graspd.gpd.environment.model import model_environment
from graspd.gpd.environment.planes import find_support, fit_plane
from graspd.gpd.environment.types import (
    ENVIRONMENT_MODES,
    Box,
    Environment,
    EnvironmentMode,
    EnvironmentParams,
    Label,
    Plane,
    Surface,
    SurfaceKind,
)
from graspd.gpd.environment.walls import find_rims, find_walls

__all__ = ["ENVIRONMENT_MODES", "Box", "Environment", "EnvironmentMode", "EnvironmentParams", "Label", "Level",
           "Plane", "Surface", "SurfaceKind", "find_inner_floor", "find_levels", "find_rims", "find_support",
           "find_walls", "fit_plane", "hand_hits_environment", "model_environment"]
