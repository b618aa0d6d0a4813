"""Model libraries (the CAD database completers match against) and their cached index."""
