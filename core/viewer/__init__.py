"""``stratamap view``: a local web viewer of a saved map (viser, offline).

``scene`` computes what is drawn from a :class:`~stratamap.core.map.layers.LayeredMap` with numpy
only (subsampled geometry coloured by RGB, class or instance; object boxes and labels; completed
models split into parts with forward kinematics per joint; contact-graph edges; occupancy layers
and the costmap as floor textures; the text shown for a clicked object). ``app`` serves it with
viser, an optional dependency (``pip install 'stratamap[viz]'``) imported only when a viewer starts.
"""
