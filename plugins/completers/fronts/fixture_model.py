"""Handles and knobs by a trained classifier: every blob that any cue of a face's height map
(:mod:`.relief`) lifts a little is a candidate, and a gradient-boosting model over its measured
shape and cues says whether it is a fixture.

The cues are the relief (a bar standing off the face), the luminance contrast of registered colour
and the shares of frames whose colour showed a thin light or dark line there. No single threshold
on one of them tells a handle from a front's edge, a shadow or a worktop's lip: on rendered walks
the clean colour draws thin lines at every edge, on a real Kinect kitchen a 1 cm steel bar shows
in the colour of one frame in five and not in the depth at all. The model sees a candidate's
shape (length, width, whether it touches the face's outline, how far from it), each cue over the
blob and around it, and each cue relative to the same face's spread of it, so that it learns what a
bar looks like rather than one rendering's contrast.

Trained by ``scripts/train_fixtures.py`` on RGB-D walks of stratamap's procedural kitchens (the
fixtures' positions from the scenes' models); the shipped model and its data card are in
``models/``. The runtime needs onnxruntime only.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from stratamap.core.errors import DataError
from stratamap.core.furniture.fixtures import Fixture
from stratamap.core.io.onnx_models import OnnxModel, read_sidecar
from stratamap.plugins.completers.fronts.face import Face
from stratamap.plugins.completers.fronts.relief import HeightMap, lines_only

#: A candidate's cue rises this far over the face: the relief by half the standoff (or 1.5 noises),
#: the contrast by 1.5 spreads (at least 0.03), a thin-line share by this much.
CANDIDATE_SHARE = 0.1
#: Fewest cells of a candidate, and its longest side (m): a longer line is an edge.
CANDIDATE_CELLS = 4
CANDIDATE_LENGTH = 0.6
#: The ring around a candidate its surroundings are measured in (cells).
RING = 3
#: How far (m) beyond a candidate's ends along its axis the cues are measured: a handle ends, a
#: piece of a front's edge or a worktop's lip goes on.
CONTINUATION = 0.1
#: The features that come from the depth (a fixture standing off the face): a training copy of each
#: candidate has them as a depth camera that does not resolve a 1 cm bar sees them.
DEPTH_FEATURES: tuple[str, ...] = ("relief_median", "relief_max", "relief_over_noise")

FEATURES: tuple[str, ...] = (
    "length",
    "width",
    "aspect",
    "vertical",
    "cells",
    "fill",
    "relief_median",
    "relief_max",
    "relief_over_noise",
    "ring_relief",
    "contrast_median",
    "contrast_over_spread",
    "ring_contrast",
    "light_mean",
    "light_max",
    "light_over_face",
    "ring_light",
    "dark_mean",
    "dark_max",
    "dark_over_face",
    "ring_dark",
    "seen_share",
    "continues_relief",
    "continues_contrast",
    "continues_light",
    "continues_dark",
    "face_noise",
)


@dataclass
class FixtureCandidate:
    """A blob of a face's height map some cue lifts: its cells, centre (u, z), principal axis
    (u, z), length and width (m), and its features (:data:`FEATURES`)."""

    mask: np.ndarray
    center: np.ndarray
    axis: np.ndarray
    length: float
    width: float
    features: np.ndarray


def _spread(values: np.ndarray) -> float:
    v = values[np.isfinite(values)]
    return float(1.4826 * np.median(np.abs(v - np.median(v)))) if len(v) else 0.0


def _cue_masks(hm: HeightMap, standoff: tuple[float, float]) -> list[np.ndarray]:
    relief = np.nan_to_num(hm.relief, nan=0.0)
    below_max = np.nan_to_num(hm.heights, nan=0.0) < standoff[1]
    masks = [lines_only((relief > max(standoff[0] / 2, 1.5 * hm.noise)) & below_max, 3)]
    if hm.contrast is not None and np.isfinite(hm.contrast).any():
        c = np.nan_to_num(hm.contrast, nan=0.0)
        masks.append(lines_only(np.abs(c) > max(0.03, 1.5 * _spread(hm.contrast)), 3))
    for share in (hm.light_lines, hm.dark_lines):
        if share is not None and np.isfinite(share).any():
            masks.append(lines_only(np.nan_to_num(share, nan=0.0) > CANDIDATE_SHARE, 3))
    return masks


def _mean_abs(values: np.ndarray) -> float:
    return float(np.mean(np.abs(values)))


def _median_abs(values: np.ndarray) -> float:
    return float(np.median(np.abs(values)))


def _stat(values: np.ndarray | None, mask: np.ndarray, how) -> float:
    if values is None:
        return 0.0
    v = values[mask]
    v = v[np.isfinite(v)]
    return float(how(v)) if len(v) else 0.0


def _beyond_ends(
    blob: np.ndarray, center: np.ndarray, axis2: np.ndarray, length: float, width: float, hm: HeightMap
) -> np.ndarray:
    """The cells in the two windows beyond a blob's ends along its axis (CONTINUATION long, as wide
    as the blob)."""
    ii, jj = np.indices(blob.shape)
    u = hm.u0 + (jj + 0.5) * hm.cell - center[0]
    z = hm.z0 + (ii + 0.5) * hm.cell - center[1]
    along = np.abs(u * axis2[0] + z * axis2[1])
    across = np.abs(-u * axis2[1] + z * axis2[0])
    return (
        (along > length / 2 + hm.cell) & (along <= length / 2 + CONTINUATION) & (across <= max(width, 2 * hm.cell) / 2)
    )


def fixture_candidates(hm: HeightMap, standoff: tuple[float, float]) -> list[FixtureCandidate]:
    """Every blob one of the height map's cues lifts (a blob of the first cue that lifts it; one
    that touches the face's outline, is under CANDIDATE_CELLS cells or longer than CANDIDATE_LENGTH
    is none), with its features."""
    from scipy import ndimage

    from stratamap.plugins.completers.fronts.fronts import blobs

    found: list[tuple] = []
    taken = np.zeros(hm.relief.shape, bool)
    for mask in _cue_masks(hm, standoff):
        labels, count = ndimage.label(mask, structure=np.ones((3, 3)))
        for blob, mean, axis2, length, width in blobs(labels, count, hm):
            if length > CANDIDATE_LENGTH or blob.sum() < CANDIDATE_CELLS:
                continue
            # The same fixture lifted by two cues is one candidate.
            if (blob & taken).sum() >= 0.3 * blob.sum():
                continue
            taken |= blob
            found.append((blob, mean, axis2, length, width))
    if not found:
        return []
    noise = max(hm.noise, 1e-4)
    contrast_spread = max(_spread(hm.contrast), 1e-3) if hm.contrast is not None else 1.0
    light_face = (
        float(np.nanpercentile(hm.light_lines, 99))
        if hm.light_lines is not None and np.isfinite(hm.light_lines).any()
        else 0.0
    )
    dark_face = (
        float(np.nanpercentile(hm.dark_lines, 99))
        if hm.dark_lines is not None and np.isfinite(hm.dark_lines).any()
        else 0.0
    )
    seen = np.isfinite(hm.relief)
    out = []
    for blob, mean, axis2, length, width in found:
        ring = ndimage.binary_dilation(blob, iterations=RING) & ~ndimage.binary_dilation(blob, iterations=1)
        beyond = _beyond_ends(blob, mean, axis2, length, width, hm)
        box_cells = max(1.0, (length / hm.cell) * (width / hm.cell))
        light_mean = _stat(hm.light_lines, blob, np.mean)
        dark_mean = _stat(hm.dark_lines, blob, np.mean)
        contrast_median = _stat(hm.contrast, blob, np.median)
        relief_median = _stat(hm.relief, blob, np.median)
        features = [
            length,
            width,
            length / max(width, hm.cell),
            abs(float(axis2[1])),
            float(blob.sum()),
            float(blob.sum()) / box_cells,
            relief_median,
            _stat(hm.relief, blob, np.max),
            relief_median / noise,
            _stat(hm.relief, ring, _median_abs),
            contrast_median,
            contrast_median / contrast_spread,
            _stat(hm.contrast, ring, _median_abs),
            light_mean,
            _stat(hm.light_lines, blob, np.max),
            light_mean / light_face if light_face > 0 else 0.0,
            _stat(hm.light_lines, ring, np.mean),
            dark_mean,
            _stat(hm.dark_lines, blob, np.max),
            dark_mean / dark_face if dark_face > 0 else 0.0,
            _stat(hm.dark_lines, ring, np.mean),
            float(seen[blob].mean()),
            _stat(hm.relief, beyond, _mean_abs),
            _stat(hm.contrast, beyond, _mean_abs),
            _stat(hm.light_lines, beyond, np.mean),
            _stat(hm.dark_lines, beyond, np.mean),
            hm.noise,
        ]
        out.append(
            FixtureCandidate(
                blob, np.asarray(mean, float), np.asarray(axis2, float), length, width, np.asarray(features, np.float32)
            )
        )
    return out


def as_fixture(cand: FixtureCandidate, hm: HeightMap, face: Face) -> Fixture:
    """The handle (at least 6 cm long and 2.5 times as long as wide) or knob a candidate is, on the
    face (standing at its median height where the depth shows it)."""
    heights = hm.heights[cand.mask]
    heights = heights[np.isfinite(heights)]
    height = float(np.median(heights)) if len(heights) else 0.0
    center = cand.center[0] * face.u_axis - (face.d - height) * face.normal
    center[2] = cand.center[1]
    if cand.length >= 0.06 and cand.length >= 2.5 * cand.width:
        direction = cand.axis[0] * face.u_axis + np.array([0.0, 0.0, cand.axis[1]])
        return Fixture("handle", center, direction / np.linalg.norm(direction), cand.length, 0.0, int(cand.mask.sum()))
    return Fixture("knob", center, None, 0.0, max(cand.length, cand.width) / 2, int(cand.mask.sum()))


class FixtureModel:
    """The fixture classifier of a sidecar JSON (``model``: the ONNX file beside it, ``features``:
    :data:`FEATURES`, ``threshold``, ``sha256``), run by onnxruntime on one thread."""

    def __init__(self, sidecar: Path):
        side = read_sidecar(sidecar, "fixture-model", ("model", "features", "threshold"))
        if tuple(side["features"]) != FEATURES:
            raise DataError(f"{sidecar}: its features are not those fronts measures (retrain the model)")
        self.threshold = float(side["threshold"])
        self.model = OnnxModel(sidecar, side, "fixture model")

    def scores(self, features: np.ndarray) -> np.ndarray:
        """Each row's probability of being a fixture."""
        return self.model.probabilities(features, 2)[:, 1]

    def fixtures(self, hm: HeightMap, face: Face, standoff: tuple[float, float]) -> list[Fixture]:
        """The candidates of ``face``'s height map the model scores at or above its threshold, as fixtures."""
        cands = fixture_candidates(hm, standoff)
        if not cands:
            return []
        scores = self.scores(np.stack([c.features for c in cands]))
        return [as_fixture(c, hm, face) for c, s in zip(cands, scores, strict=True) if s >= self.threshold]


@lru_cache(maxsize=4)
def load_fixture_model(sidecar: str) -> FixtureModel:
    """The model of ``sidecar``, loaded once per process."""
    return FixtureModel(Path(sidecar))
