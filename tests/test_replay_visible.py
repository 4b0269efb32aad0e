"""replay --quality live draws the visible-Gaussian mask the live session drew (issue 37).

``holo-viewer live`` skips the Gaussians nobody sees when their mask is cached (and draws every one on a
first start); session.json ``render.visible`` records which, with the mask's digest, and replay
--quality live repeats it: the frames of native.mkv again, bit for bit (tolerance 0), with the per-view
(V, N) mask (the default since 2026-11-28 19:30: each source view draws its own row), with the (N,) union
that sessions recorded before drew (their session.json has no ``per_view``), and without a mask; a digest
that is not this build's mask is refused, naming session.json and the field.
Cheap: tile scale 0.1, 0.4 s sessions, a one-pose mask in a test-local table cache.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from holo_viewer import media
from holo_viewer.errors import InputError


@pytest.fixture(scope="module")
def sessions(tmp_path_factory):
    """Three 0.4 s synthetic all_views sessions at tile scale 0.1 recorded as ``holo-viewer live`` records
    them (visible_only=True): ``plain`` before the mask was cached, ``masked`` with the per-view mask cached
    (two frames in flight: the twin draws the same mask), ``union`` as sessions before the per-view mask
    recorded it (the (N,) mask, session.json without ``per_view``)."""
    from holo_viewer.live import sources
    from holo_viewer.live.loop import LiveSession, LiveSessionConfig
    from holo_viewer.live.render import LiveAvatarRenderer
    from holo_viewer.pipeline import live_support

    root = tmp_path_factory.mktemp("vis")
    mp = pytest.MonkeyPatch()
    mp.setenv("HOLO_VIEWER_TABLE_CACHE", str(root / "cache"))
    mp.setenv("HOLO_VIEWER_BACKGROUND_BUILDS", "0")
    mp.setattr(live_support, "VISIBILITY_POSES", ({"jaw_pose": (0.3, 0.0, 0.0)},))  # one pose: ~1 s, not ~10
    syn = live_support.SyntheticSpeaker(0.4)
    out = {}
    try:
        for name in ("plain", "masked", "union"):
            renderer = LiveAvatarRenderer(tile_scale=0.1, native=True, preview=False, backend="fast",
                                          mode="all_views", visible_only=True, visible_per_view=name != "union")
            cfg = LiveSessionConfig(out=str(root / name), tile_scale=0.1, behaviour=None, pain=0.5,
                                    frames_in_flight=2 if name == "masked" else 1)
            LiveSession(cfg, sources.ArrayAudio(syn.waveform.copy()), None, syn).run(renderer)
            out[name] = (root / name, renderer)
            if name == "union":  # recorded before the per-view mask: no per_view field
                meta = _meta(root / name)
                assert meta["render"]["visible"].pop("per_view") is False
                (root / name / "session.json").write_text(json.dumps(meta))
            if name == "plain":  # what a first start leaves for the next: the cached mask
                built = LiveAvatarRenderer(tile_scale=0.1, native=False, backend="fast", mode="all_views",
                                           visible_only="build")
                assert built.visible_keep is not None
        yield out
    finally:
        mp.undo()


def _meta(folder: Path) -> dict:
    return json.loads((folder / "session.json").read_text())


def _replayed(folder: Path) -> list[np.ndarray]:
    from holo_viewer.live.replay import replay_timed_frames

    return [img for _, img in replay_timed_frames(folder)]


def test_session_json_records_the_mask(sessions) -> None:
    """The record describes the mask drawn: the per-view rows (shape, per-view counts, their digest)."""
    plain, masked = _meta(sessions["plain"][0]), _meta(sessions["masked"][0])
    vis = masked["render"]["visible"]
    keep = sessions["masked"][1].visible_keep
    assert keep.ndim == 2 and vis["per_view"] is True and vis["shape"] == list(keep.shape)
    assert keep.shape[0] == len(sessions["masked"][1].pipeline.cameras())
    assert vis["used"] is True and len(vis["digest"]) == 32
    assert 0 < vis["kept"] < vis["gaussians"]  # the mask drops some: the frames with and without it differ
    assert vis["kept"] == int(keep.any(axis=0).sum()) and vis["kept_per_view"][1] < vis["kept"]  # a view draws fewer
    assert vis == sessions["masked"][1].visible_record()
    union = _meta(sessions["union"][0])["render"]["visible"]
    assert sessions["union"][1].visible_keep.ndim == 1 and union["kept"] == vis["kept"]  # the same union
    assert union["digest"] != vis["digest"]
    assert plain["render"]["visible"] == {"used": False, "gaussians": vis["gaussians"], "kept": vis["gaussians"],
                                          "digest": None}


def test_twins_draw_their_renderers_mask_even_once_one_is_cached(sessions) -> None:
    """Frames in flight render on twins: the plain session's renderer started before the mask was cached,
    so its twin (built now, the mask cached) draws every Gaussian too; the masked one's twin its mask."""
    masked, plain = sessions["masked"][1], sessions["plain"][1]
    twin = masked.twin()
    assert twin.visible_keep is masked.visible_keep and twin.visible_record() == masked.visible_record()
    np.testing.assert_array_equal(twin._live._view_keep, masked.visible_keep)  # each source view its own row
    assert plain.visible_keep is None and plain.twin().visible_keep is None


@pytest.mark.parametrize("name", ["masked", "union", "plain"])
def test_replay_live_is_bit_exact_with_and_without_the_mask(sessions, name, monkeypatch) -> None:
    folder = sessions[name][0]
    # replay finds the mask in the cache (masked) or draws every Gaussian (plain), whatever is cached now
    monkeypatch.setenv("HOLO_VIEWER_TABLE_CACHE", str(folder.parent / "cache"))
    monkeypatch.setenv("HOLO_VIEWER_BACKGROUND_BUILDS", "0")
    from holo_viewer.pipeline import live_support

    monkeypatch.setattr(live_support, "VISIBILITY_POSES", ({"jaw_pose": (0.3, 0.0, 0.0)},))
    live = list(media.read_frames(folder / "native.mkv"))
    again = _replayed(folder)
    assert len(live) == len(again) >= 1
    assert all(np.array_equal(a, b) for a, b in zip(live, again))
    if name == "union":  # the per-view mask draws other frames: replaying the old session with it would not do
        call = ({"expr": np.zeros(1), "jaw_pose": np.array([0.2, 0.0, 0.0])}, 0.5, (), 0.0, 0.6)
        union, per_view = (sessions[k][1].render(*call).native for k in ("union", "masked"))
        assert not np.array_equal(union, per_view)


def test_replay_rebuilds_a_missing_mask_and_refuses_another(sessions, tmp_path, monkeypatch) -> None:
    """No cache: the mask is built again (deterministic) and the frames are the same; a session whose
    digest is not this build's mask is refused; one recorded before the field draws every Gaussian."""
    import shutil

    from holo_viewer.pipeline import live_support

    monkeypatch.setenv("HOLO_VIEWER_TABLE_CACHE", str(tmp_path / "empty"))
    monkeypatch.setenv("HOLO_VIEWER_BACKGROUND_BUILDS", "0")
    monkeypatch.setattr(live_support, "VISIBILITY_POSES", ({"jaw_pose": (0.3, 0.0, 0.0)},))
    folder = sessions["masked"][0]
    live = list(media.read_frames(folder / "native.mkv"))
    assert all(np.array_equal(a, b) for a, b in zip(live, _replayed(folder)))

    other = tmp_path / "other"
    shutil.copytree(folder, other)
    meta = _meta(other)
    meta["render"]["visible"]["digest"] = "0" * 32
    (other / "session.json").write_text(json.dumps(meta))
    with pytest.raises(InputError, match=r"session\.json: render\.visible\.digest: .*0{32}"):
        _replayed(other)
    meta["render"]["visible"]["digest"] = _meta(folder)["render"]["visible"]["digest"]
    meta["render"]["visible"]["per_view"] = False  # the per-view digest, but the (N,) mask: not what was drawn
    (other / "session.json").write_text(json.dumps(meta))
    with pytest.raises(InputError, match=r"session\.json: render\.visible\.digest: "):
        _replayed(other)
    meta["render"]["visible"]["per_view"] = "yes"
    (other / "session.json").write_text(json.dumps(meta))
    with pytest.raises(InputError, match=r"session\.json: render\.visible\.per_view: expected true or false"):
        _replayed(other)

    del meta["render"]["visible"]  # a session from before the field: every Gaussian, as before
    (other / "session.json").write_text(json.dumps(meta))
    old = _replayed(other)
    assert len(old) == len(live) and not all(np.array_equal(a, b) for a, b in zip(live, old))


def test_a_mask_of_another_shape_is_ignored(sessions) -> None:
    """A given mask of another avatar (other N) or other cameras (other V) is not drawn: every Gaussian,
    recorded as such, as a first start before the mask is cached."""
    from holo_viewer.live.render import LiveAvatarRenderer

    keep = sessions["masked"][1].visible_keep
    v, n = keep.shape
    for wrong in (np.ones((v + 1, n), bool), keep[0, :-1]):
        r = LiveAvatarRenderer(tile_scale=0.1, native=False, backend="fast", mode="all_views", visible_keep=wrong)
        assert r.visible_keep is None and r._live._keep is None and r._live._view_keep is None
        assert r.visible_record()["used"] is False
