"""Passes ``name_by_model`` (``naming: model``): every thing instance is named by a trained classifier
over its measured features (``features.instance_features``), run by onnxruntime; and
``name_after_rules_by_model`` (``naming: rules_then_model``): only what the rules left unnamed or
named by its shape alone. The shipped model
(``models/naming.onnx``, its sidecar ``models/naming.json`` and data card ``models/README.md``) was
trained by scripts/train_naming.py; scikit-learn is needed to train it, never to run it. Below
``naming_threshold`` the instance is ``object``; either way its score is in ``naming``."""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

import numpy as np

from stratamap.core.errors import DataError
from stratamap.core.io.onnx_models import OnnxModel, read_sidecar
from stratamap.core.map.priors import UNNAMED
from stratamap.plugins.segmenters.clusters.features import feature_names, instance_features
from stratamap.plugins.segmenters.clusters.labelling import Labelling
from stratamap.plugins.segmenters.clusters.shapes import Shape, ruled_out, taller_than_class

MODELS = Path(__file__).resolve().parent / "models"
#: The shipped model's sidecar; the ONNX file it names lies beside it.
SHIPPED = MODELS / "naming.json"
#: The catch-all class an instance keeps below the threshold.
CATCH_ALL = UNNAMED


class NamingModel:
    """A naming classifier: its ONNX session, its classes (the output's columns) and its features."""

    def __init__(self, sidecar: Path) -> None:
        side = read_sidecar(sidecar, "naming-model", ("model", "classes", "vote_classes", "features"))
        self.classes = [str(c) for c in side["classes"]]
        self.vote_classes = [str(c) for c in side["vote_classes"]]
        if list(side["features"]) != feature_names(self.vote_classes):
            raise DataError(f"{sidecar}: its features are not those clusters measures (retrain the model)")
        self.model = OnnxModel(sidecar, side, "naming model")
        self.path = self.model.path

    def scores(self, features: np.ndarray) -> np.ndarray:
        """Per row of ``features``, the probability of each of ``classes``."""
        return self.model.probabilities(features, len(self.classes))


@lru_cache(maxsize=4)
def load_model(sidecar: str) -> NamingModel:
    """The model of ``sidecar``, loaded once per process."""
    return NamingModel(Path(sidecar))


def name_by_model(lab: Labelling) -> None:
    """With ``naming: model``: names each thing instance by the model's most likely class where its
    score reaches ``naming_threshold``, else ``object``. Sets ``class_ids``, ``naming`` and
    ``scores``; each change of class is noted (``recognition``)."""
    if lab.cfg.naming == "model":
        _name(lab, after_rules=False)


def name_after_rules_by_model(lab: Labelling) -> None:
    """With ``naming: rules_then_model``, after the rule passes: each thing instance they left
    ``object`` takes the model's most likely class the class facts allow where its score reaches
    ``naming_threshold``; one they named by its shape alone (``naming`` by ``shape``) takes another
    class only so. The names the detector's votes or masks gave stay."""
    if lab.cfg.naming == "rules_then_model":
        _name(lab, after_rules=True)


#: How the rules named an instance when its shape alone gave the name (no votes, no masks): the
#: naming model, which reads the shape and the votes together, may name it otherwise.
BY_SHAPE = "shape"


def _open_to_the_model(lab: Labelling, iid: int, name: str) -> bool:
    return name == CATCH_ALL or lab.naming.get(iid, ("",))[0] == BY_SHAPE


def _name(lab: Labelling, after_rules: bool) -> None:
    cfg = lab.cfg
    members = lab.thing_shapes()
    if after_rules and not any(_open_to_the_model(lab, iid, info[0]) for iid, info in members.items()):
        return  # the votes and masks named everything: no features to measure
    model = load_model(str(Path(cfg.naming_model) if cfg.naming_model else SHIPPED))
    ids, features = instance_features(lab, model.vote_classes)
    scores = model.scores(features)
    changes = []
    for iid, row in zip(ids, scores, strict=True):
        if after_rules and not _open_to_the_model(lab, iid, members[iid][0]):
            continue
        best = int(np.argmax(row))
        if after_rules:  # under the same class facts as the rules
            fitting = _best_fitting(model.classes, row, members[iid][1])
            # Named by its shape: renamed only to another class scoring the threshold that the
            # object is not too tall for (the rules' class fits its height; a 1.7 m filing cabinet
            # is no counter: clutter on a worktop is why the rules leave a counter run unnamed).
            if members[iid][0] != CATCH_ALL and (
                fitting is None
                or model.classes[fitting] in (CATCH_ALL, members[iid][0])
                or row[fitting] < cfg.naming_threshold
                or taller_than_class(model.classes[fitting], members[iid][1])
            ):
                continue
            if fitting is None:
                lab.naming[iid] = ("model", "the class facts rule out every class of the model")
                lab.scores[iid] = 0.0
                continue
            best = fitting
        name, score = model.classes[best], float(row[best])
        if name not in lab.vocab or not lab.vocab.is_thing[lab.vocab.id(name)]:
            name, why = CATCH_ALL, f"the model's class {name!r} is none of the vocabulary's things"
        elif score < cfg.naming_threshold:
            fitting = " of a class the class facts allow" if after_rules else ""
            why = f"the model's best{fitting}, {name}, scored {score:.2f} < naming_threshold {cfg.naming_threshold:g}"
            name = CATCH_ALL
        else:
            why = f"{name} scored {score:.2f} over measured features"
        if name not in lab.vocab:
            continue
        was = members[iid][0]
        if name != was:
            lab.relabel(members[iid][2], cls=lab.vocab.id(name))
            changes.append({"instance": iid, "from": was, "to": name, "why": why, "score": round(score, 3)})
        lab.naming[iid] = ("model", f"{why} (was {was})" if name != was else why)
        lab.scores[iid] = round(score, 4)
    lab.note("recognition", changes)


def _best_fitting(classes: list[str], row: np.ndarray, shape: Shape) -> int | None:
    """The column of the highest-scoring class, ``object`` aside, that the class facts do not rule
    out (``ruled_out``: a 0.3 m thing on a wall is no fridge, however the model scores it).
    The model's own ``object`` column when it outscores that class or when no class fits; None when
    no class fits and the model has no ``object`` column."""
    order = [int(k) for k in np.argsort(-row, kind="stable")]
    catch_all = next((k for k in order if classes[k] == CATCH_ALL), None)
    for k in order:
        if classes[k] != CATCH_ALL and not ruled_out(classes[k], shape):
            return k if catch_all is None or row[k] >= row[catch_all] else catch_all
    return catch_all
