"""Floor 1: pure math (quaternions, cameras, trajectories). Imports nothing else from fixer4d but errors."""
from fixer4d.geometry.camera import Camera, rig_extent

__all__ = ["Camera", "rig_extent"]
