"""Property-based fuzzing of the map format (``LayeredMap.load``): a saved map folder gets its files' bytes
mutated, arrays of its .npz files replaced by arrays of random dtype and shape or removed, and values in its
JSON files replaced by random JSON. Whatever the folder holds, loading gives a map or a one-line
``MapFormatError`` naming a file of the map, never another exception."""

from __future__ import annotations

import json
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from stratamap.core.errors import DataError, MapFormatError
from stratamap.core.map.layers import LayeredMap
from tests.core.io.test_fuzz_readers import fuzz, inputs
from tests.core.map.test_format import full_map

# Bounded (about 10 s per file): `make test` runs them, `make test-fast` leaves them out.
pytestmark = pytest.mark.slow


def saved_files() -> dict[str, bytes]:
    with tempfile.TemporaryDirectory() as tmp:
        full_map().save(Path(tmp) / "m")
        return {p.name: p.read_bytes() for p in (Path(tmp) / "m").iterdir()}


FILES = saved_files()
NPZ = sorted(n for n in FILES if n.endswith(".npz"))
JSONS = sorted(n for n in FILES if n.endswith(".json"))


def load(files: dict[str, bytes]) -> None:
    with tempfile.TemporaryDirectory(prefix="stratamap-fuzz-") as tmp:
        folder = Path(tmp) / "m"
        folder.mkdir()
        for name, data in files.items():
            (folder / name).write_bytes(data)
        try:
            m = LayeredMap.load(folder)
        except (MapFormatError, DataError) as err:
            text = str(err)
            assert text and "\n" not in text and str(folder) in text, text
            return
    if m.geometry is not None:
        assert m.geometry.points.shape[1] == 3 and np.isfinite(m.geometry.points).all()
        if m.semantics is not None:
            assert len(m.semantics) == len(m.geometry)
        if m.geometry.mesh is not None and len(m.geometry.mesh.faces):
            assert m.geometry.mesh.faces.max() < len(m.geometry.mesh.vertices)
    m.layer_counts()  # every layer is usable


@given(st.sampled_from(sorted(FILES)).flatmap(lambda name: st.tuples(st.just(name), inputs(FILES[name], 300))))
@fuzz(200)
def test_fuzz_map_file_bytes(change):
    name, data = change
    load({**FILES, name: data})


ARRAYS = hnp.arrays(
    dtype=st.sampled_from([np.float64, np.float32, np.int64, np.int8, np.uint8, np.bool_, np.complex64, "U3"]),
    shape=hnp.array_shapes(min_dims=0, max_dims=3, min_side=0, max_side=5),
)


def npz_bytes(arrays: dict[str, np.ndarray]) -> bytes:
    import io

    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return buf.getvalue()


@given(st.sampled_from(NPZ), st.data())
@fuzz(200)
def test_fuzz_map_arrays(name, data):
    with np.load(__import__("io").BytesIO(FILES[name])) as npz:
        arrays = {k: npz[k] for k in npz.files}
    key = data.draw(st.sampled_from(sorted(arrays)))
    action = data.draw(st.sampled_from(["replace", "remove", "nan", "shrink", "rename"]))
    if action == "replace":
        arrays[key] = data.draw(ARRAYS)
    elif action == "remove":
        del arrays[key]
    elif action == "nan" and arrays[key].dtype.kind == "f" and arrays[key].size:
        arrays[key] = arrays[key].copy()
        arrays[key].reshape(-1)[data.draw(st.integers(0, arrays[key].size - 1))] = np.nan
    elif action == "shrink" and arrays[key].ndim:
        arrays[key] = arrays[key][: data.draw(st.integers(0, len(arrays[key])))]
    elif action == "rename":
        arrays[key + "x"] = arrays.pop(key)
    load({**FILES, name: npz_bytes(arrays)})


JSON_VALUES = st.recursive(
    st.none() | st.booleans() | st.integers(-3, 2**70) | st.floats() | st.text(max_size=6),
    lambda children: st.lists(children, max_size=4) | st.dictionaries(st.text(max_size=6), children, max_size=4),
    max_leaves=8,
)


def paths(obj, prefix=()):
    yield prefix
    if isinstance(obj, dict):
        for k, v in obj.items():
            yield from paths(v, (*prefix, k))
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            yield from paths(v, (*prefix, i))


@given(st.sampled_from(JSONS), st.data())
@fuzz(250)
def test_fuzz_map_json_values(name, data):
    obj = json.loads(FILES[name])
    where = data.draw(st.sampled_from(list(paths(obj))))
    value = data.draw(JSON_VALUES)
    if where:
        parent = obj
        for k in where[:-1]:
            parent = parent[k]
        if data.draw(st.booleans()) and isinstance(parent, dict):
            del parent[where[-1]]
        else:
            parent[where[-1]] = value
    else:
        obj = value
    load({**FILES, name: json.dumps(obj).encode()})
