"""Scenes as simulators see them: kinematic trees, physical plausibility, MJCF scenes, virtual
laser scans of URDF scenes."""
