"""Geometry that knows no map: SE(3) transforms, oriented boxes and footprints, point-set helpers."""
