"""Batch rendering without Ray: manifests, job hashes, chunking, segment joins, the in-process runner."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

from holo_viewer.batch import InProcessExecutor, RowError, job_hash, plan_chunks, read_manifest, run_batch
from holo_viewer.batch.jobs import resolve_job
from holo_viewer.batch.video import encode_segment, join_segments, read_video_frames
from holo_viewer.batch.worker import load_scene_pipeline, render_frames
from holo_viewer.cli import main
from holo_viewer.errors import ManifestError

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "apps" / "batch_example.jsonl"
TINY = 0.05  # quilt tile scale of the rendering tests (21x28 tiles): the avatar is still fully processed


def write_jsonl(path: Path, rows: list[dict | str]) -> Path:
    path.write_text("\n".join(r if isinstance(r, str) else json.dumps(r) for r in rows) + "\n")
    return path


def flame_npz(path: Path, frames: int, seed: int = 0) -> Path:
    rng = np.random.default_rng(seed)
    np.savez(path, expr=rng.normal(0, 0.5, (frames, 20)).astype(np.float32),
             jaw_pose=np.abs(rng.normal(0, 0.05, (frames, 3))).astype(np.float32),
             rotation=rng.normal(0, 0.05, (frames, 3)).astype(np.float32))
    return path


def no_temp_files(root: Path) -> list[Path]:
    return [p for p in root.rglob("*") if ".tmp" in p.name]


# ------------------------------------------------------------------------------- manifests


def test_jsonl_and_csv_manifests_give_the_same_jobs(tmp_path):
    flame_npz(tmp_path / "seq.npz", 4)
    write_jsonl(tmp_path / "m.jsonl", [
        {"id": "a", "flame_params": "seq.npz", "start": 1, "pain": 0.5, "scenario": "pulse",
         "expressions": {"smile": 0.8, "mouth_open": 0.2}, "outputs": ["native_mp4", "quilt_mp4"], "tile_scale": 0.5},
        "# a comment line",
        "",
        {"id": "b", "frames": 3},
    ])
    (tmp_path / "m.csv").write_text(
        "id,flame_params,start,pain,scenario,expressions,outputs,tile_scale,frames\n"
        "a,seq.npz,1,0.5,pulse,smile=0.8;mouth_open=0.2,quilt_mp4;native_mp4,0.5,\n"
        "b,,,,,,,,3\n")
    js, cs = read_manifest(tmp_path / "m.jsonl"), read_manifest(tmp_path / "m.csv")
    assert [type(x) for x in js] == [type(x) for x in cs] == [type(js[0])] * 2
    assert js[0].driver == "flame_params" and js[1].driver == "still" and js[1].frames == 3
    assert js[0].flame_params == str((tmp_path / "seq.npz").resolve())  # relative to the manifest
    assert js[0].outputs == ("quilt_mp4", "native_mp4")
    for a, b in zip(js, cs):
        assert job_hash(a) == job_hash(b)
    assert [j.line for j in js] == [1, 4] and [j.line for j in cs] == [2, 3]


@pytest.mark.parametrize("row, field, found", [
    ({"frames": 2, "pian": 0.3}, "unknown field", "pian"),
    ({"frames": 2, "pain": 1.5}, "pain", "1.5"),
    ({"frames": 2, "pain": "high"}, "pain", "'high'"),
    ({"flame_params": "missing.npz"}, "flame_params: file not found", "missing.npz"),
    ({"flame_params": "seq.npz", "seconds": 2}, "driver", "seconds"),
    ({"speaker_audio": "seq.npz"}, "speaker_params", "speaker_audio"),
    ({"seconds": 1, "scenario": "rising"}, "scenario", "rising"),
    ({"frames": 2, "scenario": "wavy"}, "scenario", "wavy"),
    ({"frames": 2, "outputs": ["quilt_gif"]}, "outputs", "quilt_gif"),
    ({"frames": 2, "expressions": {"grin": 0.5}}, "expressions", "grin"),
    ({"frames": 0}, "frames", "0"),
    ({"flame_params": "seq.npz", "start": 3, "stop": 2}, "stop", "2"),
    ({"seconds": 1, "fps": 30}, "fps", "25 fps"),
    ({"avatar": "default", "flame_model": "seq.npz", "frames": 1}, "flame_model", "avatar 'default'"),
])
def test_a_bad_row_is_an_error_naming_line_field_and_value(tmp_path, row, field, found):
    flame_npz(tmp_path / "seq.npz", 4)
    m = write_jsonl(tmp_path / "m.jsonl", [{"frames": 1}, dict(row, id="bad"), "[1, 2]", "{not json"])
    good, bad, arr, broken = read_manifest(m)
    assert not isinstance(good, RowError)
    assert isinstance(bad, RowError) and bad.line == 2 and bad.id == "bad"
    assert f"{m} line 2 (bad): " in bad.error and field in bad.error and found in bad.error, bad.error
    assert isinstance(arr, RowError) and "expected a JSON object, found list" in arr.error
    assert isinstance(broken, RowError) and "invalid JSON" in broken.error


def test_unreadable_manifests_raise(tmp_path):
    with pytest.raises(ManifestError, match="manifest not found"):
        read_manifest(tmp_path / "none.jsonl")
    (tmp_path / "m.txt").write_text("{}")
    with pytest.raises(ManifestError, match="expected a .jsonl, .ndjson or .csv manifest"):
        read_manifest(tmp_path / "m.txt")
    (tmp_path / "e.jsonl").write_text("\n# only a comment\n")
    with pytest.raises(ManifestError, match="at least one job row"):
        read_manifest(tmp_path / "e.jsonl")


def test_job_hash_follows_content_not_names(tmp_path):
    flame_npz(tmp_path / "a.npz", 4, seed=1)
    flame_npz(tmp_path / "b.npz", 4, seed=1)  # same bytes, other name
    flame_npz(tmp_path / "c.npz", 4, seed=2)
    rows = [{"id": "x", "flame_params": "a.npz"}, {"id": "y", "flame_params": "b.npz"},
            {"flame_params": "c.npz"}, {"flame_params": "a.npz", "pain": 0.1},
            {"flame_params": "a.npz", "outputs": ["native_mp4", "quilt_mp4"]},
            {"flame_params": "a.npz", "outputs": ["quilt_mp4", "native_mp4"]}]
    h = [job_hash(j) for j in read_manifest(write_jsonl(tmp_path / "m.jsonl", rows))]
    assert h[0] == h[1]  # id and file name do not matter
    assert len({h[0], h[2], h[3], h[4]}) == 4  # file content, pain and outputs do
    assert h[4] == h[5]  # the order of outputs does not
    assert len(h[0]) == 32 and int(h[0], 16) >= 0


def test_the_hash_covers_the_code_and_the_renderer_settings(tmp_path, monkeypatch):
    """What a job produces changes with the code (renderer, behaviour layers, reaction decoding, encoders)
    and with the renderer's settings, not only with the row: each moves the hash."""
    import functools

    from holo_viewer.batch import manifest
    from holo_viewer.render import config

    flame_npz(tmp_path / "a.npz", 4, seed=1)
    spec = read_manifest(write_jsonl(tmp_path / "m.jsonl", [{"flame_params": "a.npz"}]))[0]
    before = job_hash(spec)
    assert manifest.FORMAT_VERSION == 2
    # the renderer settings the workers use (RenderConfig's defaults): another t_min is another job
    monkeypatch.setattr(config, "RenderConfig", functools.partial(config.RenderConfig, t_min=1e-3))
    assert manifest.render_settings()["t_min"] == 1e-3 and job_hash(spec) != before
    monkeypatch.undo()
    assert job_hash(spec) == before
    # the code: a digest of the package's sources; any edit (here a copy with one line changed) moves it
    src = tmp_path / "pkg"
    (src / "render").mkdir(parents=True)
    (src / "render" / "fast.py").write_text("T_MIN = 1e-4\n")
    (src / "render" / "splat.cpp").write_text("int f();\n")
    (src / "notes.txt").write_text("not code")
    first = manifest.code_digest(src)
    (src / "notes.txt").write_text("still not code")
    manifest.code_digest.cache_clear()
    assert manifest.code_digest(src) == first
    (src / "render" / "splat.cpp").write_text("int f(); // changed\n")
    manifest.code_digest.cache_clear()
    assert manifest.code_digest(src) != first
    monkeypatch.setattr(manifest, "code_digest", lambda root=None: "0" * 64)
    assert job_hash(spec) != before
    monkeypatch.undo()
    manifest.code_digest.cache_clear()
    assert job_hash(spec) == before and manifest.code_digest() != first


def test_the_hash_reads_the_shipped_assets_the_stages_load():
    from holo_viewer.avatar.default_gaussians import fitted_asset_path
    from holo_viewer.batch.manifest import SHIPPED_ASSETS, assets_dir
    from holo_viewer.display.calibration import default_calibration_path
    from holo_viewer.flame.default_head import default_head_path
    from holo_viewer.reaction.api import default_checkpoint_path

    paths = {"default_head": default_head_path(), "default_avatar": fitted_asset_path(),
             "reaction_checkpoint": default_checkpoint_path(), "calibration": default_calibration_path()}
    assert {k: assets_dir() / v for k, v in SHIPPED_ASSETS.items()} == {k: Path(v) for k, v in paths.items()}


def test_plan_chunks_covers_the_clip_evenly():
    for n in (1, 2, 24, 25, 26, 51, 750):
        for c in (1, 7, 25, 1000):
            ranges = plan_chunks(n, c)
            assert ranges[0][0] == 0 and ranges[-1][1] == n
            assert all(a < b and b == a2 for (a, b), (a2, _) in zip(ranges, ranges[1:] + [(n, None)]))
            sizes = [b - a for a, b in ranges]
            assert max(sizes) <= c and max(sizes) - min(sizes) <= 1 and len(ranges) == -(-n // c)


# ------------------------------------------------------------------------------- video segments


def test_segments_join_by_stream_copy(tmp_path):
    rng = np.random.default_rng(3)
    base = rng.integers(0, 255, (37, 51, 3), dtype=np.uint8)  # odd sizes: padded for yuv420p
    frames = [np.roll(base, 3 * k, axis=1) for k in range(11)]
    bounds = [(0, 4), (4, 8), (8, 11)]
    for rgb, crf in ((False, 18), (True, 0)):
        paths = []
        for i, (a, b) in enumerate(bounds):
            data, n = encode_segment(frames[a:b], 25.0, rgb=rgb, crf=crf)
            assert n == b - a
            paths.append(tmp_path / f"s{i}_{rgb}.ts")
            paths[-1].write_bytes(data)
        out = join_segments(paths, tmp_path / f"joined_{rgb}.mp4")
        joined = list(read_video_frames(out))
        separate = [f for p in paths for f in read_video_frames(p)]
        assert len(joined) == len(frames) == len(separate)
        # the join copies packets: it decodes to exactly the segments' frames
        assert all(np.array_equal(a, b) for a, b in zip(joined, separate))
        if rgb:  # libx264rgb at crf 0 is lossless
            assert all(np.array_equal(a, b) for a, b in zip(joined, frames))
        else:
            assert joined[0].shape == (38, 52, 3)
    assert not no_temp_files(tmp_path)


# ------------------------------------------------------------------------------- runs


def test_in_process_run_resume_and_bad_rows(tmp_path):
    flame_npz(tmp_path / "seq.npz", 3)
    rows = [
        {"id": "still", "frames": 3, "expressions": {"smile": 0.8}, "pain": 0.8, "scenario": "rising",
         "tile_scale": TINY, "outputs": ["quilt_mp4", "native_mp4", "quilt_png", "native_png"]},
        {"id": "seq", "flame_params": "seq.npz", "tile_scale": TINY},
        {"id": "missing", "flame_params": "nope.npz", "tile_scale": TINY},
        {"id": "bad-renderer", "frames": 2, "renderer": "warp-drive", "tile_scale": TINY},
        {"id": "seq-again", "flame_params": str(tmp_path / "seq.npz"), "tile_scale": TINY},
    ]
    m = write_jsonl(tmp_path / "m.jsonl", rows)
    out = tmp_path / "out"
    s = run_batch(m, out, InProcessExecutor(), chunk_frames=2, progress=False, log=lambda _: None)
    status = {j.id: j.status for j in s.jobs}
    assert status == {"still": "done", "seq": "done", "missing": "failed", "bad-renderer": "failed",
                      "seq-again": "duplicate"}
    assert s.frames_rendered == 6
    err = {j.id: j.error for j in s.jobs}
    assert "line 3 (missing): flame_params: file not found" in err["missing"]
    assert "line 4 (bad-renderer)" in err["bad-renderer"] and "warp-drive" in err["bad-renderer"]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["counts"] == {"done": 2, "failed": 2, "duplicate": 1}
    still = next(j for j in summary["jobs"] if j["id"] == "still")
    assert still["frames"] == 3 and still["chunks"] == 2 and still["seconds"] > 0 and still["error"] is None
    jdir = out / still["hash"]
    assert (jdir / "job.json").is_file() and not (out / ".work").exists() and not no_temp_files(out)
    assert still["outputs"]["quilt_mp4"] == f"{still['hash']}/quilt_qs8x6a0.75.mp4"
    quilts = list(read_video_frames(out / still["outputs"]["quilt_mp4"]))
    natives = list(read_video_frames(out / still["outputs"]["native_mp4"]))
    assert len(quilts) == len(natives) == 3 and natives[0].shape == (2048, 1536, 3)
    assert len(list((jdir / "frames").glob("quilt_*_qs8x6a0.75.png"))) == 3
    assert len(list((jdir / "frames").glob("native_*.png"))) == 3

    # the chunked, joined native video holds exactly the pipeline's native images (lossless)
    spec = read_manifest(m)[0]
    job = resolve_job(spec, still["hash"])
    pipe = load_scene_pipeline(job.scene)
    pipe.set_view(tile_scale=TINY)
    direct = [n for _, n in render_frames(pipe, job.frames, job.named, job.pain, native=True)]
    assert all(np.array_equal(a, b) for a, b in zip(natives, direct))
    assert not np.array_equal(direct[0], direct[2])  # the pain rises over the clip

    # a re-run skips the finished jobs and says so; the failed rows fail again
    s2 = run_batch(m, out, InProcessExecutor(), chunk_frames=2, progress=False, log=lambda _: None)
    assert {j.id: j.status for j in s2.jobs} == dict(status, still="skipped", seq="skipped")
    assert s2.frames_rendered == 0
    assert json.loads((out / "summary.json").read_text())["counts"] == {"skipped": 2, "failed": 2, "duplicate": 1}


class _StopAfter(InProcessExecutor):
    """Renders ``n`` chunks, then stops as a killed driver would."""

    def __init__(self, n: int) -> None:
        super().__init__()
        self.n = n

    def run(self, tasks):
        for k, res in enumerate(super().run(tasks)):
            if k == self.n:
                raise KeyboardInterrupt
            yield res


def test_an_interrupted_run_resumes_from_its_finished_chunks(tmp_path):
    m = write_jsonl(tmp_path / "m.jsonl", [{"id": "j", "frames": 5, "pain": 0.5, "scenario": "pulse",
                                             "tile_scale": TINY, "outputs": ["quilt_png"]}])
    out = tmp_path / "out"
    with pytest.raises(KeyboardInterrupt):
        run_batch(m, out, _StopAfter(2), chunk_frames=2, progress=False)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["jobs"][0]["status"] == "pending"
    h = summary["jobs"][0]["hash"]
    assert sorted(p.name for p in (out / ".work" / h).glob("chunk_*.json")) == ["chunk_00000.json",
                                                                                  "chunk_00001.json"]
    assert not (out / h).exists()
    s = run_batch(m, out, InProcessExecutor(), chunk_frames=2, progress=False)
    a, b = plan_chunks(5, 2)[2]
    assert s.jobs[0].status == "done" and s.frames_rendered == b - a  # only the third chunk
    pattern = str(out / s.jobs[0].outputs["quilt_png"])
    from holo_viewer.fileio import load_image

    pngs = [np.rint(load_image(pattern % k) * 255).astype(np.uint8) for k in range(5)]
    job = resolve_job(read_manifest(m)[0], h)
    pipe = load_scene_pipeline(job.scene)
    pipe.set_view(tile_scale=TINY)
    direct = [q for q, _ in render_frames(pipe, job.frames, job.named, job.pain, native=False)]
    assert all(np.array_equal(a, b) for a, b in zip(pngs, direct))
    assert not (out / ".work").exists() and not no_temp_files(out)


def test_cli_without_ray_runs_in_process_and_says_how_to_install(tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "ray", None)  # `import ray` raises ImportError
    m = write_jsonl(tmp_path / "m.jsonl", [{"id": "one", "frames": 1, "tile_scale": TINY}])
    assert main(["render-batch", str(m), "--out", str(tmp_path / "out"), "--no-progress"]) == 0
    cap = capsys.readouterr()
    assert "Ray is not installed" in cap.err and 'pip install "holo_viewer[cluster]"' in cap.err
    assert "1 done" in cap.out
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["executor"]["executor"] == "in-process" and summary["counts"] == {"done": 1}
    # joining a cluster needs Ray: a reported error (exit 1), not a traceback
    assert main(["render-batch", str(m), "--out", str(tmp_path / "o2"), "--address", "auto"]) == 1
    assert 'pip install "holo_viewer[cluster]"' in capsys.readouterr().err


def test_cli_reports_failed_jobs_and_usage_errors(tmp_path, capsys):
    m = write_jsonl(tmp_path / "m.jsonl", [{"id": "bad", "frames": 1, "pain": 2}])
    assert main(["render-batch", str(m), "--out", str(tmp_path / "o"), "--in-process", "--no-progress"]) == 1
    err = capsys.readouterr().err
    assert "line 1 (bad): pain: expected a value in [0, 1], found 2" in err
    assert main(["render-batch", str(m), "--out", str(tmp_path / "o"), "--workers", "0"]) == 1
    assert "--workers: expected a positive integer, found 0" in capsys.readouterr().err
    assert main(["render-batch", str(tmp_path / "none.csv"), "--out", str(tmp_path / "o")]) == 1
    assert "manifest not found" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:
        main(["render-batch", str(m)])  # --out is required
    assert exc.value.code == 2


def test_the_example_manifest_is_three_short_default_avatar_clips():
    jobs = read_manifest(EXAMPLE)
    assert len(jobs) == 3 and not any(isinstance(j, RowError) for j in jobs)
    assert all(j.avatar == "default" for j in jobs)
    assert len({job_hash(j) for j in jobs}) == 3


def test_a_speaker_driver_runs_the_reaction_model_once_in_the_driver(tmp_path):
    from holo_viewer.flame.expressions import default_au_map, jaw_for_expression
    from holo_viewer.reaction.api import flame_params_from_states
    from holo_viewer.reaction.audio import write_wav
    from holo_viewer.reaction.data import SyntheticConfig, synth_speaker

    au = default_au_map()
    sp = synth_speaker(np.random.default_rng(5), SyntheticConfig(seconds=0.4), au.names,
                       jaw_for_expression("mouth_open", 1.0))
    write_wav(tmp_path / "s.wav", sp.waveform, 16000)
    np.savez(tmp_path / "s.npz", **flame_params_from_states(sp.state, au))
    m = write_jsonl(tmp_path / "m.jsonl", [
        {"id": "r", "speaker_audio": "s.wav", "speaker_params": "s.npz", "pain": 0.8, "seed": 3},
        {"id": "r-pain0", "speaker_audio": "s.wav", "speaker_params": "s.npz", "pain": 0.0, "seed": 3}])
    a, b = read_manifest(m)
    assert a.driver == "reaction" and job_hash(a) != job_hash(b)
    ja, jb = resolve_job(a, "x"), resolve_job(b, "y")
    assert ja.n_frames == sp.state.shape[0] == 10 and ja.fps == 25.0
    assert ja.pain == 0.0  # the model's expressions carry the requested pain; none is added on top
    assert set(ja.frames[0]) >= {"expr", "jaw_pose", "rotation"}
    assert not np.allclose(np.stack([f["expr"] for f in ja.frames]), np.stack([f["expr"] for f in jb.frames]))
    (tmp_path / "s.npz").write_bytes(b"not an npz")
    with pytest.raises(Exception, match="s.npz"):
        resolve_job(read_manifest(m)[0], "x")


def test_a_ply_avatar_row_renders_like_the_default_avatar(tmp_path):
    from holo_viewer.avatar.default_gaussians import default_avatar

    default_avatar().save_ply(tmp_path / "avatar.ply")  # a GaussianAvatars PLY of the default head
    m = write_jsonl(tmp_path / "m.jsonl", [
        {"id": "ply", "avatar": "avatar.ply", "frames": 1, "pain": 0.4, "tile_scale": TINY, "outputs": ["quilt_png"]},
        {"id": "default", "frames": 1, "pain": 0.4, "tile_scale": TINY, "outputs": ["quilt_png"]}])
    s = run_batch(m, tmp_path / "out", InProcessExecutor(), progress=False)
    assert [j.status for j in s.jobs] == ["done", "done"] and s.jobs[0].hash != s.jobs[1].hash
    from holo_viewer.fileio import load_image

    a, b = (load_image(tmp_path / "out" / (j.outputs["quilt_png"] % 0)) for j in s.jobs)
    assert np.array_equal(a, b)
