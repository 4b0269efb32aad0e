"""render-batch and the behaviour layers: manifest fields, the job hash, the frames a reaction job renders."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from holo_viewer.batch import job_hash, read_manifest
from holo_viewer.batch.jobs import resolve_job
from holo_viewer.batch.manifest import RowError


def _write(path: Path, rows: list[dict]) -> Path:
    path.write_text("\n".join(json.dumps(r) for r in rows) + "\n")
    return path


def test_manifest_behaviour_and_pain_timeline_fields(tmp_path):
    (tmp_path / "tl.json").write_text(json.dumps({"pain_timeline": [{"t": 0, "level": 0.2}, {"t": 0.2, "level": 0.9}]}))
    rows = [{"seconds": 0.4}, {"seconds": 0.4, "behaviour": {"gaze": False}}, {"seconds": 0.4, "behaviour": False},
            {"seconds": 0.4, "seed": 1}, {"seconds": 0.4, "pain_timeline": "tl.json"},
            {"frames": 10, "pain_timeline": [{"t": 0, "level": 0.2}, {"t": 0.2, "level": 0.9}]},
            {"frames": 2, "behaviour": {"gaze": False}}, {"seconds": 0.4, "behaviour": {"stare": 1}},
            {"seconds": 0.4, "pain_timeline": [{"t": 0, "level": 2}]},
            {"seconds": 0.4, "pain": 0.3, "pain_timeline": [{"t": 0, "level": 0.1}]}, {"frames": 2}]
    jobs = read_manifest(_write(tmp_path / "m.jsonl", rows))
    ok = jobs[:7]
    assert all(not isinstance(j, RowError) for j in jobs[:6])
    assert dict(ok[0].behaviour)["gaze"] is True and dict(ok[1].behaviour)["gaze"] is False and ok[2].behaviour is None
    assert dict(ok[3].behaviour)["seed"] == 1
    assert ok[4].pain_timeline == ((0.0, 0.2), (0.2, 0.9)) == ok[5].pain_timeline
    errors = [j.error for j in jobs[6:10]]
    assert "behaviour: expected only with a reaction driver" in errors[0]
    assert "unknown keys ['stare']" in errors[1]
    assert "pain_timeline[0].level" in errors[2] and "instead of pain" in errors[3]
    hashes = [job_hash(j) for j in ok[:6]]
    assert len(set(hashes)) == 6  # each setting changes the hash: cached outputs without it are not reused
    # a still without the new fields keeps the hash it had before them
    assert job_hash(jobs[10]) == job_hash(read_manifest(_write(tmp_path / "n.jsonl", [{"frames": 2}]))[0])


def test_the_job_hash_follows_the_reaction_checkpoint(tmp_path, monkeypatch):
    """A retrained checkpoint is another job for the reaction drivers (its contents are hashed), not for a
    job that only replays FLAME parameters."""
    from holo_viewer.batch import manifest

    np.savez(tmp_path / "f.npz", expr=np.zeros((2, 4), np.float32), rotation=np.zeros((2, 3), np.float32))
    ck = tmp_path / "ck.pt"
    ck.write_bytes(b"checkpoint one")
    monkeypatch.setitem(manifest.SHIPPED_ASSETS, "reaction_checkpoint", str(ck))
    react, replay = read_manifest(_write(tmp_path / "m.jsonl", [{"seconds": 0.4}, {"flame_params": "f.npz"}]))
    before = job_hash(react), job_hash(replay)
    ck.write_bytes(b"checkpoint two, retrained")  # another size: the digest cache keys on size and mtime
    assert job_hash(react) != before[0] and job_hash(replay) == before[1]


def test_csv_cells_hold_json(tmp_path):
    (tmp_path / "m.csv").write_text('seconds,behaviour,pain_timeline\n0.4,"{""blinks"": false}",'
                                    '"[{""t"": 0, ""level"": 0.5}]"\n0.4,false,\n')
    a, b = read_manifest(tmp_path / "m.csv")
    assert dict(a.behaviour)["blinks"] is False and a.pain_timeline == ((0.0, 0.5),) and b.behaviour is None


def test_a_synthetic_reaction_job_renders_the_layers(tmp_path):
    from holo_viewer.reaction.api import default_checkpoint_path

    if not default_checkpoint_path().is_file():
        pytest.skip("no shipped reaction checkpoint")
    on, off, tl = read_manifest(_write(tmp_path / "m.jsonl", [
        {"seconds": 1.0}, {"seconds": 1.0, "behaviour": False},
        {"frames": 25, "pain_timeline": [{"t": 0, "level": 0.0}, {"t": 0.5, "level": 0.6}]}]))
    a, b = resolve_job(on, "a"), resolve_job(off, "b")
    eyes = np.stack([f["eyes_pose"] for f in a.frames])
    assert np.ptp(eyes, axis=0).max() > 1e-3 and not np.any(np.stack([f["eyes_pose"] for f in b.frames]))
    assert a.pain == 0.0 and all("pain" not in f for f in a.frames)  # pain is in the expressions, not added again
    still = resolve_job(tl, "c")
    assert [f["pain"] for f in still.frames][11:14] == [0.0, 0.0, 0.6]


def test_render_batch_flags_switch_layers_off(tmp_path):
    from holo_viewer.batch.manifest import switch_behaviour_off
    from holo_viewer.cli import main

    spec = read_manifest(_write(tmp_path / "m.jsonl", [{"seconds": 0.4}]))[0]
    nogaze = switch_behaviour_off(spec, ("gaze",))
    assert dict(nogaze.behaviour)["gaze"] is False and dict(nogaze.behaviour)["blinks"] is True
    assert switch_behaviour_off(spec, ("behaviour",)).behaviour is None
    assert len({job_hash(spec), job_hash(nogaze), job_hash(switch_behaviour_off(spec, ("behaviour",)))}) == 3
    m = _write(tmp_path / "s.jsonl", [{"frames": 1, "tile_scale": 0.05, "outputs": ["quilt_png"]}])
    assert main(["render-batch", str(m), "--out", str(tmp_path / "o"), "--in-process", "--no-progress",
                 "--no-gaze", "--no-blinks"]) == 0


@pytest.mark.slow
def test_manifest_viewer_fields_set_the_gaze_target(tmp_path):
    from holo_viewer.reaction.api import default_checkpoint_path

    rows = [{"seconds": 0.4}, {"seconds": 0.4, "viewer_angle": 20, "viewer_distance": 0.8},
            {"frames": 2, "viewer_angle": 10}, {"seconds": 0.4, "viewer_angle": 90}]
    a, b, still, bad = read_manifest(_write(tmp_path / "m.jsonl", rows))
    assert b.viewer_angle == 20.0 and b.viewer_distance == 0.8 and job_hash(a) != job_hash(b)
    assert "viewer_angle: expected only with a reaction driver" in still.error
    assert "viewer_angle: expected a value in [-60, 60]" in bad.error
    if not default_checkpoint_path().is_file():
        pytest.skip("no shipped reaction checkpoint")
    ya = np.mean([f["eyes_pose"][1] for f in resolve_job(a, "a").frames])
    yb = np.mean([f["eyes_pose"][1] for f in resolve_job(b, "b").frames])
    assert yb > ya + 0.1  # the eyes turn toward the viewer at +20 deg (+x)


def test_a_reaction_job_gives_the_layers_its_avatars_map(tmp_path, monkeypatch):
    """Issue 35: a reaction job's layers draw the pain face with its avatar's AU map (the scene pipeline's
    ``au_map``: the default head's brow gain, a patient's none); a job without layers loads no scene."""
    from types import SimpleNamespace

    from holo_viewer.batch import worker
    from holo_viewer.flame.expressions import default_au_map
    from holo_viewer.pipeline import reactions
    from holo_viewer.reaction.api import default_checkpoint_path

    if not default_checkpoint_path().is_file():
        pytest.skip("no shipped reaction checkpoint")
    am = default_au_map().with_pain_gains({"AU6": 1.2})
    scenes, seen = [], []
    monkeypatch.setattr(worker, "load_scene_pipeline", lambda scene: scenes.append(scene) or SimpleNamespace(au_map=am))

    def frames(**kw):
        seen.append(kw["au_map"])
        return [{} for _ in range(25)], 25.0

    monkeypatch.setattr(reactions, "reaction_frames", frames)
    on, off = read_manifest(_write(tmp_path / "m.jsonl", [{"seconds": 1.0}, {"seconds": 1.0, "behaviour": False}]))
    a = resolve_job(on, "a")
    resolve_job(off, "b")
    assert len(seen) == 2 and seen[0] is am and seen[1] is None and scenes == [a.scene]
