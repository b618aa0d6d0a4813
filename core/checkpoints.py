"""Checkpoints of a run, so that a long run that was interrupted or failed resumes (``stratamap run
--resume``) after the last stage that finished instead of from the first frame.

After each stage before the first exporter, the run's blackboard (:class:`PipelineData`) and its
stage records are pickled into a folder beside the output, ``.<output name>.checkpoints`` (the
output itself is written whole at the end, or not at all: see ``core/atomic.py``). Only the latest
checkpoint is kept. Its name carries a digest of what produced it: the package versions, the
source's and those stages' plugins and full configs, and the size and time of every file or folder
the source's config names; a checkpoint of another pipeline, other settings or changed input is
never taken. Exporters write files into the output as they run, so they (and what follows them) run
again on resume.

The sensor stream is not pickled (a recording's frames are read from their files on demand): on
resume the source runs again, which is cheap and gives the same frames, and the stream is put back.
A stage that replaced the stream (odometry) has it pickled with the rest; where something cannot
be pickled, that stage is not checkpointed and the run says so once."""

from __future__ import annotations

import hashlib
import json
import os
import pickle
import shutil
from pathlib import Path
from typing import Any

from stratamap.core.stages import Exporter, PipelineData

#: Pickle protocol of checkpoints (5: large arrays are written without an extra copy).
PROTOCOL = 5


def checkpoint_folder(final: Path) -> Path:
    """Where the checkpoints of the output folder ``final`` (absolute) live: beside it."""
    return final.parent / f".{final.name}.checkpoints"


def clear_checkpoints(final: Path) -> None:
    """Remove the checkpoints of the output folder ``final``: a run into it finished."""
    shutil.rmtree(checkpoint_folder(final), ignore_errors=True)


def _inputs(config: Any) -> list[Any]:
    """The size and modification time of every existing file or folder a config's strings name (the
    recording a source reads): a checkpoint of changed input is not taken."""
    found = []

    def walk(value: Any) -> None:
        if isinstance(value, dict):
            for v in value.values():
                walk(v)
        elif isinstance(value, (list, tuple)):
            for v in value:
                walk(v)
        elif isinstance(value, str) and value and len(value) < 4096:
            path = Path(value).expanduser()
            try:
                st = path.stat()
            except (OSError, ValueError):
                return
            found.append([str(path), st.st_size, st.st_mtime_ns])

    walk(config)
    return found


class Checkpoints:
    """The checkpoints of one pipeline's run into one output folder."""

    def __init__(self, folder: Path, source: Any, stages: list[Any], versions: dict[str, str]) -> None:
        self.folder = folder
        source_config = source.config.model_dump(mode="json")
        head = [versions, source.spec.plugin, source_config, _inputs(source_config)]
        self.keys: list[str] = []
        self.last = -1  # the last stage that may be checkpointed: the one before the first exporter
        done: list[Any] = []
        for i, stage in enumerate(stages):
            if issubclass(stage.info.cls, Exporter):
                break
            done.append([stage.spec.plugin, stage.info.kind, stage.config.model_dump(mode="json")])
            text = json.dumps([*head, done], sort_keys=True, default=str)
            self.keys.append(hashlib.sha256(text.encode()).hexdigest()[:16])
            self.last = i
        self.failed: str | None = None  # why a stage could not be checkpointed, the first time

    def _file(self, index: int) -> Path:
        return self.folder / f"after-stage-{index:02d}-{self.keys[index]}.pkl"

    def latest(self) -> tuple[int, PipelineData, list[Any]] | None:
        """The latest checkpoint of this pipeline, settings and input: (the stage it was written
        after, the blackboard then, the stage records then); None when there is none."""
        for index in range(self.last, -1, -1):
            path = self._file(index)
            if not path.is_file():
                continue
            try:
                with open(path, "rb") as fh:
                    saved = pickle.load(fh)
            except Exception:  # noqa: BLE001 - a checkpoint cut short or of an older layout: run again
                continue
            return index, saved["data"], saved["records"]
        return None

    def save(self, index: int, data: PipelineData, records: list[Any], source_stream: Any) -> None:
        """Write the checkpoint after stage ``index`` (and drop the earlier ones); stages from the
        first exporter on are not checkpointed. The source's stream is left out (see the module)."""
        if index > self.last:
            return
        stream = data.stream
        try:
            if stream is source_stream:
                data.stream = None
            payload = pickle.dumps({"data": data, "records": records}, protocol=PROTOCOL)
        except Exception as exc:  # noqa: BLE001 - a plugin's layer that cannot be pickled
            if self.failed is None:
                self.failed = f"stage {index}'s output cannot be saved for --resume ({type(exc).__name__}: {exc})"
            return
        finally:
            data.stream = stream
        self.folder.mkdir(parents=True, exist_ok=True)
        target = self._file(index)
        partial = target.with_suffix(f".{os.getpid()}.tmp")
        partial.write_bytes(payload)
        partial.replace(target)
        for old in self.folder.iterdir():
            if old != target:
                old.unlink(missing_ok=True)
