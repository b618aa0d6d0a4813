"""Furniture with fronts: faces, fixtures (handles, knobs), fronts and the kitchen paper's CRF,
shared by the stages that look for doors and drawers."""
