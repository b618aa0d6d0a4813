"""File formats, one module each, reader beside writer: RGB-D sequences, ROS bags, URDF, Nav2 maps,
ground-truth folders, point clouds and meshes."""


def brief(exc: BaseException, with_type: bool = False, limit: int = 300) -> str:
    """A library exception's message on one line (errors name the file and fit on one line), shortened."""
    text = " ".join(str(exc).split()) or type(exc).__name__
    if with_type:
        text = f"{type(exc).__name__}: {text}"
    return text if len(text) <= limit else text[: limit - 3] + "..."
