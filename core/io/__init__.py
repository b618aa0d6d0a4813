"""File formats, one module each, reader beside writer: RGB-D sequences, ROS bags, URDF, Nav2 maps,
ground-truth folders."""
