"""Frames in flight (holo_viewer.live.inflight): several renderers at once, frames shown in the order
started, the recording and ``replay --quality live`` still the displayed frames bit-exact."""

from __future__ import annotations

import threading
import time
import zlib
from pathlib import Path

import numpy as np
import pytest

from holo_viewer import media
from holo_viewer.live.inflight import FramesInFlight
from holo_viewer.live.render import RenderedFrame


class _HashRenderer:
    """A stand-in renderer whose native frame is a function of the render call alone (like group frames),
    taking a random 5-40 ms, so frames on two renderers finish out of order; ``twin()`` gives another."""

    def __init__(self, seed: int = 0, log: list | None = None) -> None:
        self.frames_independent = True
        self.rng = np.random.default_rng(seed)
        self.log = [] if log is None else log  # (renderer id, angle) of every call, shared by the twins
        self.calls = 0

    def twin(self, render_threads=None) -> "_HashRenderer":
        return _HashRenderer(int(self.rng.integers(1 << 30)), self.log)

    def render(self, listener, pain, named, angle, distance, tracked=True, others=()):
        time.sleep(float(self.rng.uniform(0.005, 0.04)))
        self.calls += 1
        self.log.append((id(self), float(angle)))
        key = np.concatenate([np.ravel(np.asarray(listener.get("expr", np.zeros(1)), np.float64)),
                              [pain, angle, distance, float(tracked)], np.ravel(np.asarray(others, np.float64))])
        seed = zlib.crc32(key.tobytes())
        native = np.random.default_rng(seed).integers(0, 256, (24, 32, 3), dtype=np.uint8)
        return RenderedFrame(native=native, preview=None, seconds=0.0)


def test_jobs_are_taken_in_the_order_started_even_when_a_later_one_finishes_first() -> None:
    class Slow:  # render i returns once gates[i] is set: the test says when each job finishes, no sleeps
        frames_independent = True

        def __init__(self, gates):
            self.gates = gates

        def twin(self, render_threads=None):
            return Slow(self.gates)

        def render(self, i):
            self.gates[i].wait(60)
            return RenderedFrame(native=None, preview=None, seconds=0.0)

    gates = {0: threading.Event(), 1: threading.Event()}
    pool = FramesInFlight(Slow(gates), 2, warmup=None)
    deadline = time.perf_counter() + 10
    while pool.renderers < 2 and time.perf_counter() < deadline:  # the twin joins from its thread
        pool.wait(0.01)
    assert pool.renderers == 2 and pool.threaded
    a = pool.submit((0,), tag="a")
    assert pool.can_submit()  # no render time known yet: no spacing
    b = pool.submit((1,), tag="b")
    assert not pool.can_submit()  # both renderers busy
    gates[1].set()  # the later job finishes first
    b.done.wait(60)
    assert b.done.is_set() and not a.done.is_set()
    assert pool.take() is None  # the newer frame waits for the older one
    gates[0].set()
    a.done.wait(60)
    assert [pool.take().tag, pool.take().tag] == ["a", "b"]
    assert a.renderer is not b.renderer
    pool.close()


def test_a_renderer_without_independent_frames_renders_alone_in_this_thread() -> None:
    class Stateful:
        def render(self):
            self.thread = threading.current_thread()
            return RenderedFrame(native=None, preview=None, seconds=0.0)

    r = Stateful()
    pool = FramesInFlight(r, 2)
    assert not pool.threaded and pool.n == 1
    job = pool.submit(())
    assert job.done.is_set() and r.thread is threading.current_thread()
    assert not pool.can_submit() and pool.take() is job and pool.can_submit()
    from holo_viewer.errors import InputError

    with pytest.raises(InputError, match="frames_in_flight: expected >= 1, found 0"):
        FramesInFlight(r, 0)


def test_a_twin_that_fails_leaves_one_renderer_in_flight() -> None:
    class NoTwin(_HashRenderer):
        def twin(self, render_threads=None):
            raise MemoryError("no room for a second renderer")

    pool = FramesInFlight(NoTwin(), 2)
    pool._builder.join(5)
    assert isinstance(pool.twin_error, MemoryError) and pool.renderers == 1
    job = pool.submit(({"expr": np.zeros(3)}, 0.0, (), 1.0, 0.6))
    assert not pool.can_submit()  # its one renderer is busy
    job.done.wait(5)
    assert pool.take() is job and job.result.native.shape == (24, 32, 3)
    pool.close()


def _session(tmp_path: Path, seconds: float, **config):
    from holo_viewer.live import sources
    from holo_viewer.live.loop import LiveSession, LiveSessionConfig
    from holo_viewer.pipeline.live_support import SyntheticSpeaker

    syn = SyntheticSpeaker(seconds)
    cfg = LiveSessionConfig(out=str(tmp_path / "s"), tile_scale=0.1, behaviour=None, **config)
    return LiveSession(cfg, sources.ArrayAudio(syn.waveform), None, syn)


def test_two_frames_in_flight_show_in_order_and_replay_bit_exact(tmp_path: Path, monkeypatch) -> None:
    """A 1.2 s session on two renderers whose frames finish out of order: both render, the displayed frames
    are in the order of their listener frames and session times, native.mkv holds them bit-exact, and
    replay --quality live (one renderer, the recorded calls) gives the same frames."""
    from holo_viewer.live import replay

    first = _HashRenderer()
    session = _session(tmp_path, 1.2, frames_in_flight=2)
    shown = []
    session.run(first, on_frame=lambda res: shown.append(res.native))
    with np.load(tmp_path / "s" / "tracks.npz") as z:
        tr = {k: z[k] for k in z.files}
    assert session.frames_in_flight.n == 2 and len({who for who, _ in first.log}) == 2  # both renderers drew
    assert len(shown) == len(tr["display_frame"]) >= 6
    assert (np.diff(tr["display_frame"]) > 0).all() and (np.diff(tr["display_time_s"]) > 0).all()
    stored = list(media.read_frames(tmp_path / "s" / "native.mkv"))
    assert len(stored) == len(shown) and all(np.array_equal(a, b) for a, b in zip(shown, stored))
    monkeypatch.setattr(replay, "_renderer", lambda *a, **k: _HashRenderer(7))
    again = [img for _, img in replay.replay_timed_frames(tmp_path / "s")]
    assert len(again) == len(stored) and all(np.array_equal(a, b) for a, b in zip(stored, again))


def test_frames_limit_counts_frames_in_flight(tmp_path: Path) -> None:
    """--frames 3 with two in flight: exactly 3 frames shown and recorded, none started beyond them."""
    first = _HashRenderer()
    session = _session(tmp_path, 0.8, frames_in_flight=2, frames=3)
    session.run(first)
    with np.load(tmp_path / "s" / "tracks.npz") as z:
        assert len(z["display_frame"]) == 3
    renderers = len({who for who, _ in first.log})
    assert len(first.log) - renderers <= 3  # each renderer's warm-up call, then at most the frames shown


# ---------------------------------------------------------------- the real renderer's frames
@pytest.fixture(scope="module")
def renderers():
    from holo_viewer.live.render import LiveAvatarRenderer
    from holo_viewer.pipeline import Pipeline, ViewSettings

    # a per-view visible mask, as `holo-viewer live` draws (each source view its own row; random here: the
    # frames' independence must not depend on which), shared by the twin
    pipe = Pipeline(view=ViewSettings(tile_scale=0.1))
    keep = np.random.default_rng(11).random((len(pipe.cameras()), len(pipe.gaussians()))) < 0.9
    a = LiveAvatarRenderer(tile_scale=0.1, native=True, preview=False, mode="auto", render_threads=2,
                           visible_keep=keep)
    return a, a.twin(render_threads=1)


def test_group_frames_do_not_depend_on_earlier_frames_or_the_thread_count(renderers) -> None:
    """What frames in flight rely on: two renderers with the live settings (2 and 1 threads) give
    bit-identical frames for the same call whatever each rendered before (tracked, untracked, other
    faces), so a frame rendered by a twin equals replay's render of it on one renderer."""
    a, b = renderers
    assert a.frames_independent and b.frames_independent and b.mode == a.mode == "auto"
    assert a.visible_keep.ndim == 2 and b.visible_keep is a.visible_keep  # the twin draws the same per-view mask
    np.testing.assert_array_equal(b._live._view_keep, a._live._view_keep)
    rng = np.random.default_rng(3)
    calls = []
    for i in range(5):
        lf = {"expr": rng.normal(0, 0.6, 50), "jaw_pose": np.array([0.15 * rng.random(), 0.0, 0.0])}
        others = ((12.0, 0.8),) if i == 2 else ()
        calls.append(((lf, 0.2 * i, (), -8.0 + 5 * i, 0.55 + 0.05 * i, i != 3), {"others": others} if others else {}))
    seq = [a.render(*args, **kw).native for args, kw in calls]  # in order on one renderer
    for i in (4, 1, 3, 2):  # out of order, with other histories, on the twin
        args, kw = calls[i]
        assert np.array_equal(b.render(*args, **kw).native, seq[i]), i
    assert not np.array_equal(seq[2], seq[3])
    a.set_render_threads(1)  # what the live loop does to the first renderer once its twin has joined
    assert a.render_threads == 1 and a._live.config.render.num_threads == 1
    args, kw = calls[2]
    assert np.array_equal(a.render(*args, **kw).native, seq[2])


def test_which_modes_render_frames_in_flight() -> None:
    """group and all_views on the CPU; not tracked (it updates the last frame), cone or gsplat (the flag's
    logic on unbuilt renderers: building each costs a second)."""
    from holo_viewer.live.render import LiveAvatarRenderer
    from holo_viewer.pipeline.live_modes import SESSION_MODE

    def unbuilt(mode, backend="fast"):
        r = LiveAvatarRenderer.__new__(LiveAvatarRenderer)
        r.session_mode, r.backend, r._live = SESSION_MODE[mode], backend, None if mode == "cone" else object()
        return r.frames_independent

    assert unbuilt("auto") and unbuilt("all_views")
    assert not unbuilt("tracked") and not unbuilt("cone") and not unbuilt("auto", "gsplat")


def test_live_command_takes_frames_in_flight(capsys) -> None:
    from holo_viewer.cli import main
    from holo_viewer.live.loop import LiveSessionConfig
    from holo_viewer.errors import InputError

    with pytest.raises(SystemExit):
        main(["live", "--synthetic", "--headless", "--frames-in-flight", "0"])
    assert "--frames-in-flight: expected an integer >= 1, found '0'" in capsys.readouterr().err
    with pytest.raises(InputError, match="frames_in_flight: expected an integer >= 1, found 1.5"):
        LiveSessionConfig(frames_in_flight=1.5)


def test_deforming_only_the_drawn_gaussians_changes_no_frame(renderers) -> None:
    """With a visible mask the live renderer deforms only the Gaussians its frames draw (the union of the
    per-view rows, and the faces they sit on): those rows equal the whole avatar's deform bit for bit, and
    so do the frames against a renderer that deforms everything (what replay --quality live compares)."""
    keep = renderers[0].visible_keep.copy()
    keep[:, np.random.default_rng(6).random(keep.shape[1]) < 0.4] = False  # ~40 % drawn by no view
    a = type(renderers[0])(**{**renderers[0]._args, "visible_keep": keep})
    full = a.twin()
    full._drawn = None  # deform the whole avatar, as before
    assert a._drawn is not None and 0.5 * keep.shape[1] < a._drawn["index"].size < 0.7 * keep.shape[1]
    idx = a._drawn["index"]
    rng = np.random.default_rng(5)
    for i in range(3):
        lf = {"expr": rng.normal(0, 0.6, 50), "jaw_pose": np.array([0.2 * rng.random(), 0.0, 0.0]),
              "rotation": np.array([0.0, 0.1 * rng.normal(), 0.0])}
        g, ref = a.deform(lf, 0.3 * i, ()), full.deform(lf, 0.3 * i, ())
        for f in ("means", "quats", "log_scales"):
            assert np.array_equal(getattr(g, f).numpy()[idx], getattr(ref, f).numpy()[idx]), (i, f)
        args = (lf, 0.3 * i, (), -5.0 + 5 * i, 0.6, i != 1)
        assert np.array_equal(a.render(*args).native, full.render(*args).native), i


def test_the_background_compile_names_the_kernels_live_frames_call(renderers, monkeypatch) -> None:
    """live/precompile.py's KERNELS are the view-synthesis numba kernels a live frame calls, and every one
    of them: a name no frame calls (``_warp`` until 2026-11-28, with the C++ warp built) is never cached by a
    session, so the children started at every start."""
    from numba.core.registry import CPUDispatcher

    from holo_viewer.live import precompile
    from holo_viewer.render import view_synthesis as vs

    called = set()
    for name, fn in list(vars(vs).items()):
        if isinstance(fn, CPUDispatcher):
            monkeypatch.setattr(vs, name, lambda *a, _f=fn, _n=name, **k: (called.add(_n), _f(*a, **k))[1])
    a, _ = renderers
    a.render({"expr": np.zeros(50)}, 0.0, (), 5.0, 0.6, True, others=((10.0, 0.7),))
    a.render({"expr": np.zeros(50)}, 0.0, (), 5.0, 0.6, False)
    cpp = vs._warp_cpp()
    assert {"_zbuffer"} <= called <= set(precompile.KERNELS), called
    assert ("_row_extents" in called) == ("_row_extents" in precompile.KERNELS) == (
        cpp is None or not hasattr(cpp, "row_extents"))
    assert ("_warp_u8" in precompile.KERNELS) == (cpp is None)
    assert "_warp" not in precompile.KERNELS and set(precompile.KERNELS) == {
        k for g in precompile.GROUPS.values() for k in g}


def test_frames_are_handed_out_without_a_copy_and_never_overwritten(renderers) -> None:
    """Group frames render straight into a native buffer nobody holds any more (no 9.4 MB copy): a frame
    still held is never written again, a released buffer is reused (its old bytes fully overwritten), and
    the bytes equal the copying path's (NATIVE_BUFFERS 0)."""
    a, b = renderers
    b.NATIVE_BUFFERS, b._natives = 0, []  # this renderer copies every frame, as before
    calls = [({"expr": np.full(50, 0.1 * i)}, 0.2 * i, (), -6.0 + 4 * i, 0.6, i != 1) for i in range(6)]
    held = [a.render(*c).native for c in calls[:5]]  # 4 buffers handed out, then copies
    assert len(a._natives) == a.NATIVE_BUFFERS and len({id(x) for x in held}) == 5
    kept = [x.copy() for x in held]
    for buf in a._natives:
        buf[:] = 0xAB  # what a consumer could have left there: the next frame must write every byte
    del held, buf
    out = a.render(*calls[5]).native
    assert any(out is x for x in a._natives) and len(a._natives) == a.NATIVE_BUFFERS  # reused, not a new one
    for c, k in zip(calls[:5] + calls[5:], kept + [out]):
        assert np.array_equal(b.render(*c).native, k)
    assert not any(b.render(*calls[0]).native is x for x in b._natives) and not b._natives
