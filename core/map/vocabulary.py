"""The class vocabulary of a map: names, ids, and whether a class is a *thing* or *stuff*.

Things are countable objects that become instances (chairs, tables); stuff is layout without
instances (floor, walls, ceiling). Class id 0 is reserved for "unknown".
"""

from __future__ import annotations

from dataclasses import dataclass, field

UNKNOWN = 0

#: (name, is_thing). Order fixes the ids of the default vocabulary: append, never reorder.
DEFAULT_CLASSES: tuple[tuple[str, bool], ...] = (
    ("unknown", False),
    ("floor", False),
    ("wall", False),
    ("ceiling", False),
    ("chair", True),
    ("table", True),
    ("desk", True),
    ("cabinet", True),
    ("shelf", True),
    ("counter", True),
    ("sofa", True),
    ("fridge", True),
    ("microwave", True),
    ("oven", True),
    ("monitor", True),
    ("laptop", True),
    ("box", True),
    ("book", True),
    ("cup", True),
    ("bottle", True),
    ("plant", True),
    ("object", True),
    ("bench", True),
    # furniture fronts (the kitchen paper's level-2 labels): a door, a drawer, an appliance's face
    ("drawer", True),
    ("cupboard", True),
    ("appliance", True),
)

LAYOUT_CLASSES = ("floor", "wall", "ceiling")


@dataclass(frozen=True)
class Vocabulary:
    """Class names indexed by id, with a thing/stuff flag per class."""

    names: tuple[str, ...]
    is_thing: tuple[bool, ...]
    _index: dict[str, int] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if len(self.names) != len(self.is_thing):
            raise ValueError("names and is_thing must have the same length")
        if len(set(self.names)) != len(self.names):
            raise ValueError(f"duplicate class names in vocabulary: {self.names}")
        object.__setattr__(self, "_index", {n: i for i, n in enumerate(self.names)})

    @classmethod
    def default(cls) -> Vocabulary:
        return cls(tuple(n for n, _ in DEFAULT_CLASSES), tuple(t for _, t in DEFAULT_CLASSES))

    def id(self, name: str) -> int:
        try:
            return self._index[name]
        except KeyError:
            raise KeyError(f"class {name!r} is not in the vocabulary {list(self.names)}") from None

    def name(self, class_id: int) -> str:
        return self.names[int(class_id)]

    def thing_ids(self) -> list[int]:
        return [i for i, t in enumerate(self.is_thing) if t]

    def __contains__(self, name: object) -> bool:
        return name in self._index

    def __len__(self) -> int:
        return len(self.names)

    def to_dict(self) -> dict:
        return {"names": list(self.names), "is_thing": list(self.is_thing)}

    @classmethod
    def from_dict(cls, d: dict) -> Vocabulary:
        return cls(tuple(d["names"]), tuple(bool(x) for x in d["is_thing"]))
