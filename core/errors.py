"""Exceptions that carry enough context for a user to fix their input."""


class StratamapError(Exception):
    """Base class of every error stratamap raises on purpose."""


class ConfigError(StratamapError):
    """A pipeline or stage configuration is invalid.

    ``problems`` lists ``(yaml_path, message)`` pairs, e.g. ``("stages[2].params.voxel_sise", "extra field")``.
    """

    def __init__(self, problems: list[tuple[str, str]], source: str | None = None):
        self.problems = problems
        self.source = source
        where = f"{source}: " if source else ""
        lines = [f"{where}{path}: {msg}" if path else f"{where}{msg}" for path, msg in problems]
        super().__init__("\n".join(lines))

    def __reduce__(self):
        # Benchmark workers send errors back by pickling; the default would call __init__ with the message.
        return (type(self), (self.problems, self.source))


class PluginError(StratamapError):
    """A plugin could not be found, loaded or registered."""


class DataError(StratamapError):
    """Input data is missing, corrupt or inconsistent; the message names the file and what was expected."""


class MapFormatError(DataError):
    """A saved map directory is incomplete or of an unknown format version."""
