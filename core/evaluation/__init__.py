"""Evaluation against ground truth: one module per metric family, navigation safety, and the benchmark runner."""
