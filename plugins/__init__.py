"""stratamap's built-in plugins, one stage per module, registered through the same entry points
and hooks as third-party plugins (see ``stratamap.core.registry``)."""
