"""`stratamap bench` runs: records, tables, figures and resuming after a kill (Ray: test_ray_completion.py)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from stratamap.core.evaluation.bench import run_bench, safe
from tests.core.evaluation.test_bench import tiny_bench


@pytest.fixture(scope="module")
def local_run(tmp_path_factory):
    """The tiny benchmark run once by the local executor (shared by the tests below)."""
    tmp = tmp_path_factory.mktemp("bench")
    config = tiny_bench(tmp)
    return config, tmp / "out", run_bench(config, tmp / "out", progress=False)


def test_bench_writes_records_tables_and_figures_and_skips_done_runs(local_run):
    config, out, summary = local_run
    assert summary["records"] == summary["ran"] == 2
    results = json.loads((out / "results.json").read_text())
    assert set(results) >= {"versions", "records"} and results["versions"]["numpy"]
    for rec in results["records"]:
        assert {"scene", "variant", "plugins", "seconds", "peak_memory_mb", "metrics"} <= set(rec)
        assert {"detection", "completion", "panoptic", "instances", "graph", "physics", "navigation"} <= set(
            rec["metrics"]
        )
        assert {"precision", "recall", "f1"} <= set(rec["metrics"]["detection"])
        assert {"chamfer_l1", "fscore_2cm", "fscore_5cm", "chamfer_l1_by_class"} <= set(rec["metrics"]["completion"])
        assert {"ged", "wrong_support", "missing", "extra"} <= set(rec["metrics"]["graph"])
    by_variant = {r["variant"]: r for r in results["records"]}
    # The mapping stages ran once: the same timings appear in both records.
    shared = [k for k in by_variant["bbox"]["seconds"] if "tsdf" in k]
    assert shared and by_variant["bbox"]["seconds"][shared[0]] == by_variant["none"]["seconds"][shared[0]]
    assert any(k.endswith(":bbox") for k in by_variant["bbox"]["seconds"]) and not any(
        k.endswith(":bbox") for k in by_variant["none"]["seconds"]
    )
    md = (out / "results.md").read_text()
    assert "| metric | none | bbox |" in md and "## completion" in md and "**" in md
    header = (out / "results.csv").read_text().splitlines()[0].split(",")
    assert header[:2] == ["scene", "variant"] and "detection.f1" in header
    assert len(list(out.glob("*.png"))) >= 2 and (out / "navigation.png").is_file()
    # The first results.md already links every figure the run drew.
    figures = sorted(p.name for p in out.glob("*.png"))
    assert "## Figures" in md and all(f"![{name}]({name})" in md for name in figures), md
    # Planned paths stay inside the room's walls (the outermost true obstacles).
    rec = by_variant["bbox"]
    grids = np.load(out / "runs" / safe(rec["scene"]) / "bbox" / "navigation.npz")
    rows, cols = np.nonzero(grids["truth"] == 100)
    walls_lo = grids["truth_origin"][:2] + (np.array([cols.min(), rows.min()]) + 0.5) * grids["truth_resolution"]
    walls_hi = grids["truth_origin"][:2] + (np.array([cols.max(), rows.max()]) + 0.5) * grids["truth_resolution"]
    assert rec["details"]["navigation"]
    for path in rec["details"]["navigation"]:
        for key in ("laser_only", "multimap"):
            xy = np.asarray(path[key])
            assert (xy > walls_lo).all() and (xy < walls_hi).all(), (key, xy.min(0), xy.max(0), walls_lo, walls_hi)
    again = run_bench(config, out, progress=False)
    assert again["ran"] == 0 and again["records"] == 2


def test_killed_benchmark_resumes_without_redoing_runs(tmp_path):
    config = tiny_bench(tmp_path, seeds=(3, 4))
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "stratamap.core.cli", "bench", str(config), "--out", str(out)]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    deadline = time.time() + 300
    while time.time() < deadline and len(list((out / "records").glob("*/*.json"))) < 2 and proc.poll() is None:
        time.sleep(0.2)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    done = {p: p.stat().st_mtime_ns for p in (out / "records").glob("*/*.json")}
    assert 2 <= len(done) < 4
    for p in done:
        json.loads(p.read_text())  # whole records only
    assert not (out / "results.json").exists() or json.loads((out / "results.json").read_text())
    summary = run_bench(config, out, progress=False)
    assert summary["records"] == 4 and summary["ran"] == 4 - len(done)
    assert all(p.stat().st_mtime_ns == t for p, t in done.items())


def test_tune_walks_scores_cached_prefixes_as_the_benchmark_does(local_run, tmp_path):
    """scripts/tune_walks.py caches a variant's early stages per walk and runs only the rest: its
    figures are the benchmark's own for the same walk and variant. A validation walk is printed only in
    its group's mean, never object by object."""
    from pathlib import Path

    script = Path(__file__).resolve().parents[2] / "scripts" / "tune_walks.py"
    config, out, _ = local_run
    cache = ["--variant", "none", "--stages", "2", "--cache", str(tmp_path / "cache")]

    def tune(command: str, *extra: str) -> subprocess.CompletedProcess:
        return subprocess.run(
            [sys.executable, str(script), command, str(config), *cache, *extra], capture_output=True, text=True
        )

    missing = tune("score")
    assert missing.returncode == 2 and "run `prefix` first" in missing.stderr
    assert tune("prefix").returncode == 0
    scored = tune("score")
    assert scored.returncode == 0, scored.stderr
    line = next(row for row in scored.stdout.splitlines() if row.startswith("office-s3"))
    record = json.loads((out / "records" / "office-s3" / "none.json").read_text())["metrics"]
    expected = [record["detection"]["f1_iou25"], record["detection"]["f1_iou25_agnostic"], record["panoptic"]["pq"]]
    assert [float(x) for x in line.split()[1:]] == pytest.approx(expected, abs=5e-4)
    # What the tuning walk's true objects were called, as the benchmark's record says.
    labels = json.loads((out / "records" / "office-s3" / "none.json").read_text())["details"]["labels_iou25"]
    printed = scored.stdout.split("what the true objects were called")[1].splitlines()[1:]
    for true, row in labels["called"].items():
        counts = sorted(f"{name} {n}" for name, n in row.items())
        named = [sorted(p.strip()[len(true) :].strip().split(", ")) for p in printed if p.split()[0] == true]
        assert named == [counts]
    # A tuning walk's objects are printed one by one; a validation walk's are not, nor its own figures:
    # it is read only in its group's mean.
    listed = tune("score", "--objects")
    assert listed.returncode == 0 and "-> #" in listed.stdout and "truth #0" in listed.stdout
    held_out = tune("score", "--objects", "--validation-seeds", "3")
    assert held_out.returncode == 0, held_out.stderr
    assert not any(row.startswith("office-s3") for row in held_out.stdout.splitlines())
    assert "-> #" not in held_out.stdout and "truth #" not in held_out.stdout
    mean = next(row for row in held_out.stdout.splitlines() if row.startswith("validation mean of 1"))
    assert [float(x) for x in mean.split()[4:]] == pytest.approx(expected, abs=5e-4)


def test_tune_walks_frames_reads_a_segmenters_labels_against_the_ground_truth(local_run, tmp_path):
    """`tune_walks.py frames` runs the source and the variant's segmenter only, and says how its
    per-frame labels fall on the ground truth's: the oracle's fall where they are; a walk chosen only
    among the validation walks is refused (they are read as means)."""
    from pathlib import Path

    script = Path(__file__).resolve().parents[2] / "scripts" / "tune_walks.py"
    config, _, _ = local_run

    def frames(*extra: str) -> subprocess.CompletedProcess:
        args = [sys.executable, str(script), "frames", str(config), "--variant", "none", "--cache", str(tmp_path)]
        return subprocess.run([*args, *extra], capture_output=True, text=True)

    done = frames()
    assert done.returncode == 0, done.stderr
    rows = [line.split() for line in done.stdout.splitlines() if line.startswith("  ")]
    assert {row[0] for row in rows} >= {"chair", "table"}
    for row in rows:  # "chair 12345 px: chair 1.000"
        assert row[3] == row[0] and float(row[4].rstrip(",")) > 0.99, row
    refused = frames("--validation-seeds", "3")
    assert refused.returncode == 2 and "validation walks" in refused.stderr


def test_tune_walks_cache_keeps_where_each_frame_was_taken(monkeypatch):
    """A cached prefix keeps the stream's poses and metadata, and of its images only the depth of the
    frames that give clusters its rays: clusters turns its normals to the cameras, reads the source's
    floor from the stream and asks the rays what they saw through, so a cache without them (as the
    script once wrote) scores another pipeline than the benchmark's."""
    import importlib.util
    import pickle
    from pathlib import Path

    from stratamap.core.map.sensors import sensor_viewpoints
    from stratamap.core.synthetic import SceneSpec
    from stratamap.core.synthetic.generate import generate_sequence
    from stratamap.plugins.segmenters.clusters.sightlines import Sightlines, ray_frames

    script = Path(__file__).resolve().parents[2] / "scripts" / "tune_walks.py"
    spec = importlib.util.spec_from_file_location("tune_walks", script)
    tune_walks = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(tune_walks)
    from stratamap.plugins.segmenters.clusters import sightlines as _sightlines

    monkeypatch.setattr(_sightlines, "MAX_FRAMES", 5)  # rays from 5 of the 12 frames
    scene = {"type": "office", "camera": {"width": 80, "height": 60}, "trajectory": {"frames": 12}}
    stream = generate_sequence(SceneSpec.model_validate(scene)).stream
    stream.metadata["gravity_alignment"] = {"floor_inliers": 10}
    light = tune_walks.light_stream(stream)
    assert len(light.frames) == 12 and all(f.rgb.size == 3 for f in light.frames)
    kept = [k for k, f in enumerate(light.frames) if f.depth.size > 1]
    assert kept == ray_frames(12).tolist() and len(kept) == 5
    cached = pickle.loads(pickle.dumps(light))
    cells = np.random.default_rng(0).uniform(0, 4, (50, 3))
    assert np.array_equal(sensor_viewpoints(stream, cells), sensor_viewpoints(cached, cells))
    assert cached.metadata == stream.metadata
    assert tune_walks.holds_rays(cached)
    rays, cached_rays = Sightlines.from_stream(stream), Sightlines.from_stream(cached)
    assert len(rays) > 0 and np.array_equal(rays.ends, cached_rays.ends)
    assert np.array_equal(rays.origins, cached_rays.origins)
