"""What the live session needs from the chain: renders of the project's own head through a webcam,
a synthetic speaker, and face-state <-> FLAME conversions (so ``live/`` never wires stages itself).

:class:`HeadRenderer` poses the default Gaussian avatar with FLAME parameters and renders it
with the fast splat renderer through a pinhole "webcam" (:func:`webcam_camera`), so a tracker
can be checked against the parameters that drove it (closed loop), and `live` can be run end
to end from a rendered video of the head speaking (:func:`write_talking_head_clip`).
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from ..cache import keep_recent
from ..camera import Cameras, intrinsics, look_at
from ..errors import InputError
from ..validation import check_finite_scalar

__all__ = ["webcam_camera", "HeadRenderer", "write_talking_head_clip", "HEAD_CENTRE", "SyntheticSpeaker",
           "speaker_clip", "FaceStates", "VISIBILITY_POSES", "visible_mask", "build_visible_mask_later"]

#: a point between the default head's eyes (FLAME frame, metres): the webcam's look-at target
HEAD_CENTRE = np.array([0.0, 0.02, 0.06])


def webcam_camera(width: int = 640, height: int = 480, hfov_deg: float = 60.0, distance: float = 0.5,
                  yaw_deg: float = 0.0, pitch_deg: float = 0.0, target: Any = None) -> Cameras:
    """A pinhole webcam at ``distance`` metres from ``target``, seen from yaw/pitch (degrees).

    Yaw 0, pitch 0 looks straight at the face (FLAME +z toward the camera); positive yaw moves
    the camera toward the head's +x (its left), positive pitch moves it up. Intrinsics from the
    horizontal field of view: ``fx = fy = (width / 2) / tan(hfov / 2)``, principal point at the
    image centre.
    """
    hfov = check_finite_scalar(hfov_deg, "hfov_deg", low=1.0, high=170.0)
    d = check_finite_scalar(distance, "distance", low=0.05, high=20.0)
    tgt = HEAD_CENTRE if target is None else np.asarray(target, dtype=np.float64)
    yaw, pitch = math.radians(float(yaw_deg)), math.radians(float(pitch_deg))
    direction = np.array([math.sin(yaw) * math.cos(pitch), math.sin(pitch), math.cos(yaw) * math.cos(pitch)])
    f = 0.5 * width / math.tan(math.radians(hfov) / 2)
    K = intrinsics(f, f, width / 2.0, height / 2.0)
    return Cameras(look_at(tgt + d * direction, tgt), K, int(width), int(height), near=0.02, far=20.0)


class HeadRenderer:
    """Render the default avatar posed by FLAME parameters into webcam images.

    Parameters
    ----------
    n_gaussians : int
        Avatar size (fewer Gaussians render faster; 100k is the shipped default).
    background : (float, float, float)
        Background RGB in [0, 1].
    backend : str
        Renderer backend (``holo_viewer.render.render_views``).
    """

    def __init__(self, n_gaussians: int = 100_000, background: tuple[float, float, float] = (0.35, 0.38, 0.42),
                 backend: str = "fast") -> None:
        from ..avatar.default_gaussians import default_avatar
        from ..render.config import RenderConfig

        self.avatar = default_avatar(n_gaussians=n_gaussians)
        self.model = self.avatar.flame_model
        self.backend = backend
        self.config = RenderConfig(background=tuple(float(c) for c in background))

    def vertices(self, params: Mapping[str, Any]) -> np.ndarray:
        """(V, 3) posed vertices (with teeth) for one frame of FLAME parameters."""
        import torch

        kw = {k: torch.as_tensor(np.asarray(v, dtype=np.float64)[None], dtype=self.model.dtype)
              for k, v in params.items() if k in ("expr", "jaw_pose", "rotation", "neck_pose", "eyes_pose",
                                                  "translation")}
        with torch.no_grad():
            return self.model(**kw).vertices[0].numpy().astype(np.float64)

    def render(self, params: Mapping[str, Any], camera: Cameras, noise_std: float = 0.0,
               rng: np.random.Generator | None = None) -> np.ndarray:
        """(H, W, 3) uint8 image of the head posed by ``params`` (keys ``expr``, ``jaw_pose``,
        ``rotation``, ... one frame each), with optional Gaussian pixel noise (std in [0, 1] units)."""
        from ..render.api import render_views

        g = self.avatar.deform(self.vertices(params))
        img = render_views(g, camera, backend=self.backend, config=self.config).images[0]
        if noise_std > 0:
            rng = rng or np.random.default_rng(0)
            img = img + rng.normal(0.0, float(noise_std), img.shape).astype(np.float32)
        return (np.clip(img, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


#: this process's synthetic speakers, (seconds, seed, salt, espeak-ng present) -> SpeakerClip (the last few)
_CLIPS: dict = {}
_CLIPS_KEPT = 4


def speaker_clip(seconds: float, seed: int, salt: int) -> Any:
    """A synthetic speaker (:class:`holo_viewer.reaction.data.SpeakerClip`) of at least 10 s whose
    voice the reaction model hears as speech: an espeak-ng text-to-speech voice with a face moving
    with it (:func:`holo_viewer.reaction.data.tts_speaker`). Where espeak-ng is not installed, the
    harmonic synthetic voice, with a RuntimeWarning saying that the model does not hear it as speech.
    (At least 10 s are synthesized: the generators normalise slow sway per clip.) Synthesized once per
    process and arguments (text-to-speech and voice detection, ~0.75 s of CPU); each call returns its own copy."""
    import copy
    import warnings
    from dataclasses import replace

    from ..flame.expressions import default_au_map, jaw_for_expression
    from ..reaction.data import SyntheticConfig, synth_speaker, tts_speaker
    from ..reaction.tts import espeak_available

    cfg = SyntheticConfig(seconds=max(float(seconds), 10.0))
    espeak = espeak_available()
    if not espeak:
        warnings.warn("espeak-ng not found: the synthetic speaker is the harmonic voice, which the reaction model "
                      "does not hear as speech, so the patient will hardly react (apt-get install espeak-ng)",
                      RuntimeWarning, stacklevel=3)
    key = (cfg.seconds, int(seed), int(salt), espeak)
    if key not in _CLIPS:
        au = default_au_map()
        rng = np.random.default_rng(np.random.SeedSequence([int(seed), int(salt)]))
        jaw = np.asarray(jaw_for_expression("mouth_open", 1.0), dtype=np.float64)
        if espeak:
            sp, _ = tts_speaker(rng, replace(cfg, still_face_fraction=0.0), au.names, jaw)
        else:
            sp = synth_speaker(rng, cfg, au.names, jaw)
        keep_recent(_CLIPS, key, sp, _CLIPS_KEPT)
    return copy.deepcopy(_CLIPS[key])


def write_talking_head_clip(out_dir: str | os.PathLike, seconds: float = 4.0, seed: int = 0,
                            width: int = 480, height: int = 360, hfov_deg: float = 60.0, distance: float = 0.45,
                            n_gaussians: int = 30_000, fps: int = 25) -> dict[str, Path]:
    """Write ``speaker.wav`` (16 kHz) + ``speaker.mp4`` (the head speaking) + ``truth.npz``.

    The speaker is :func:`speaker_clip`'s (an espeak-ng voice with a face moving with it: mouth
    with the level, brows on pitch accents, smiles, nods; the harmonic voice where espeak-ng is
    missing); the head is rendered frame by frame at 25 fps. ``truth.npz`` holds the driving
    FLAME parameters (``expr``, ``jaw_pose``, ``rotation``) and the states.
    """
    from ..fileio import save_npz
    from ..media import VideoWriter
    from ..flame.expressions import default_au_map
    from ..reaction.audio import write_wav
    from ..reaction.features import flame_from_state

    seconds = check_finite_scalar(seconds, "seconds", low=0.2, high=600.0)
    if fps != 25:
        raise InputError(f"fps: expected 25 (the reaction model's rate), found {fps}")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    au_map = default_au_map()
    sp = speaker_clip(seconds, seed, 15)
    T = int(round(seconds * fps))
    state = sp.state[:T]
    waveform = sp.waveform[: T * 640]
    fl = flame_from_state(state, au_map)
    renderer = HeadRenderer(n_gaussians=n_gaussians)
    cam = webcam_camera(width, height, hfov_deg, distance)
    wav = out / "speaker.wav"
    write_wav(wav, waveform, 16000)
    video = out / "speaker.mp4"
    with VideoWriter(video, fps, content="preview", quality=8, what="speaker video") as writer:
        for t in range(fl["expr"].shape[0]):
            writer.write(renderer.render({k: fl[k][t] for k in fl}, cam))
    truth = out / "truth.npz"
    save_npz(truth, expr=fl["expr"], jaw_pose=fl["jaw_pose"], rotation=fl["rotation"], state=state,
             fps=np.array(fps))
    return {"wav": wav, "video": video, "truth": truth}


class SyntheticSpeaker:
    """A synthetic speaker (voice + face states at 25 fps) and a slowly moving synthetic viewer.

    ``states`` (T, n_au + 6) and ``waveform`` (T * 640,) float32 at 16 kHz: :func:`speaker_clip`'s
    text-to-speech speaker (the harmonic voice, with a warning, where espeak-ng is missing).
    """

    def __init__(self, seconds: float, seed: int = 0) -> None:
        seconds = check_finite_scalar(seconds, "seconds", low=0.04, high=3600.0)
        sp = speaker_clip(seconds, seed, 16)
        T = int(round(seconds * 25))
        self.states = sp.state[:T]
        self.waveform = sp.waveform[: T * 640]

    @staticmethod
    def viewer(t: float) -> tuple[float, float]:
        """(angle deg, distance m) at ``t`` s: a viewer walking slowly across the cone."""
        return 12.0 * math.sin(2 * math.pi * t / 8.0), 0.6 + 0.1 * math.sin(2 * math.pi * t / 11.0)


class FaceStates:
    """Face states of the reaction model (n_au + 6,) -> GaussianAvatars FLAME arrays of the default head.

    ``default_au_map()`` here is the reaction model's AU space (its state's AU order and AU -> FLAME matrix),
    which carries no pain: the pain face, with the avatar's pain gains, is the behaviour layers' (the live
    loop's ``session_behaviour``) or the renderer's ``FaceControls(pain)``, both with the avatar's map."""

    def __init__(self) -> None:
        from ..flame.expressions import default_au_map

        self.au_map = default_au_map()

    def speaker(self, state: np.ndarray) -> dict[str, np.ndarray]:
        """``expr``, ``jaw_pose``, ``rotation`` (one frame each) of a speaker state."""
        from ..reaction.features import flame_from_state

        return {k: v[0] for k, v in flame_from_state(np.asarray(state, np.float64)[None], self.au_map).items()}

    def listener(self, state: np.ndarray) -> dict[str, np.ndarray]:
        """The six per-frame flame_param arrays (``expr`` ... ``translation``) of a listener state."""
        from ..reaction.api import flame_params_from_states

        fl = flame_params_from_states(np.asarray(state, np.float64)[None], self.au_map, n_shape=0)
        return {k: v[0] for k, v in fl.items() if k != "shape"}


#: the poses :func:`visible_mask` looks at (FaceControls keywords; radians): the extremes a live face reaches
#: (pain with a nod, the jaw slider's limit, a smile speaking, nods, the head turned and rolled, the eyes
#: turned), each showing Gaussians the others hide. On the default avatar (48 views, 0.5/255) each pose alone
#: keeps 56-58k of 102k, the union 70k; a neutral face adds nothing to the others
VISIBILITY_POSES: tuple[dict, ...] = (
    {"pain": 1.0, "rotation": (0.2, 0.0, 0.0)}, {"jaw_pose": (0.5, 0.0, 0.0)},
    {"named": (("smile", 1.0),), "jaw_pose": (0.3, 0.0, 0.0)}, {"rotation": (-0.2, 0.0, 0.0)},
    {"rotation": (0.0, 0.3, 0.0)}, {"rotation": (0.0, -0.3, 0.0)}, {"rotation": (0.0, 0.0, 0.15)},
    {"rotation": (0.0, 0.0, -0.15)}, {"eyes_pose": (0.3, 0.45, 0.0, 0.3, 0.45, 0.0)},
    {"eyes_pose": (-0.3, -0.45, 0.0, -0.3, -0.45, 0.0)})


def visible_mask(pipe: Any, threshold: float | None = None, poses: tuple[dict, ...] | None = None,
                 cached_only: bool = False, per_view: bool = False) -> np.ndarray | None:
    """(N,) bool: the Gaussians of ``pipe``'s avatar that anybody can see in its quilt views: largest
    blending weight (:func:`holo_viewer.render.visibility.max_weights`, float64) over ``pipe.cameras()`` at
    any of ``poses`` (default :data:`VISIBILITY_POSES`) above ``threshold`` (default
    :data:`~holo_viewer.render.visibility.KEEP_WEIGHT`, 1/255). Cached on disk
    (:func:`holo_viewer.display.table_cache.cached_tables`, kind ``visible_gaussians``), keyed by the avatar's
    neutral Gaussians, the cameras, the poses, the threshold and the visibility code: ~5-7 s of CPU per pose
    at 48 views of 420x560 the first time (~3 s at tile scale 0.5). ``pipe``'s face is restored afterwards.
    ``cached_only``: None instead of building a mask that is not cached (:func:`build_visible_mask_later`).
    ``per_view``: (V, N) bool instead, per quilt view the Gaussians above the threshold *in that view* at any
    of the poses (its union over the views is the (N,) mask; the same build and cache entry), for
    :class:`~holo_viewer.pipeline.live.NativeFrameRenderer`'s ``keep``: each rendered view then draws only its
    own row (default avatar, 2026-11-28: 53.0-54.5k of the 66.2k kept per view over the 10 poses; 40-41k
    at one pose)."""
    import hashlib
    from pathlib import Path

    from ..display.table_cache import cached_tables, table_key, table_path
    from ..render import visibility
    from .settings import FaceControls

    thr = visibility.KEEP_WEIGHT if threshold is None else float(threshold)
    poses = VISIBILITY_POSES if poses is None else tuple(poses)
    face0 = pipe.face
    try:
        pipe.set_face(FaceControls())
        g = pipe.gaussians().numpy()
    finally:
        pipe.set_face(face0)
    n = len(g)
    h = hashlib.sha256()
    for a in (g.means, g.quats, g.log_scales, g.opacity_logits, g.sh):
        h.update(np.ascontiguousarray(a).tobytes())
    cams = pipe.cameras()
    for a in (cams.R, cams.t, cams.fx, cams.fy, cams.cx, cams.cy):
        h.update(np.ascontiguousarray(a, dtype=np.float64).tobytes())
    h.update(repr((cams.width, cams.height, cams.near)).encode())
    h.update(Path(visibility.__file__).read_bytes())
    key = table_key("visible_gaussians", None, avatar=h.hexdigest(), poses=repr(poses), threshold=thr)

    if cached_only and (os.environ.get("HOLO_VIEWER_TABLE_CACHE", "1") == "0"
                        or not table_path("visible_gaussians", key).is_file()):
        return None

    def build() -> dict[str, np.ndarray]:
        best = np.zeros((len(cams), n))
        try:
            for kw in poses:
                pipe.set_face(FaceControls(**{k: (np.asarray(v, dtype=np.float64) if k != "named" else v)
                                              for k, v in kw.items()}))
                np.maximum(best, visibility.max_weights(pipe.gaussians(), cams, per_view=True), out=best)
        finally:
            pipe.set_face(face0)
        views = best > thr
        return {"keep": views.any(axis=0), "keep_views": views}

    tables = cached_tables("visible_gaussians", key, {"keep": ((n,), "bool"), "keep_views": ((len(cams), n), "bool")},
                           build)
    return tables["keep_views"] if per_view else tables["keep"]


_later: set = set()  # (avatar, tile_scale) whose mask this process has asked a background build of


def build_visible_mask_later(avatar: str = "default", tile_scale: float = 1.0) -> bool:
    """Start, once per process and (``avatar``, ``tile_scale``), a separate process at the lowest CPU
    priority (nice 19) that builds and caches :func:`visible_mask` for that avatar's quilt cameras on the
    default calibration, so that a live session's first start on an avatar does not wait ~30 s of CPU for
    it: that session draws every Gaussian, the next ones load the mask. Returns whether one was started.
    ``HOLO_VIEWER_BACKGROUND_BUILDS=0`` starts none (the test suite: a build per tile scale, ~30 s of CPU each,
    would outlive the tests that started it)."""
    import subprocess
    import sys

    if (avatar, float(tile_scale)) in _later or os.environ.get("HOLO_VIEWER_TABLE_CACHE", "1") == "0" \
            or os.environ.get("HOLO_VIEWER_BACKGROUND_BUILDS", "1") == "0":
        return False
    _later.add((avatar, float(tile_scale)))
    cmd = [sys.executable, "-m", "holo_viewer.pipeline.live_support", str(avatar), repr(float(tile_scale))]
    try:
        subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                         start_new_session=True, preexec_fn=lambda: os.nice(19))  # noqa: PLW1509 - only os.nice
    except OSError:
        return False
    return True


def _build_visible_mask_main(argv: list[str]) -> int:
    """``python -m holo_viewer.pipeline.live_support AVATAR TILE_SCALE``: cache :func:`visible_mask`."""
    from ..display.calibration import DisplayCalibration
    from . import Pipeline, ViewSettings

    avatar, tile_scale = argv[0], float(argv[1])
    who = {}
    if avatar != "default":
        from .scene import load_avatar

        model, av, _, _ = load_avatar(avatar, need_gaussians=True)
        who = {"model": model, "avatar": av}
    pipe = Pipeline(calibration=DisplayCalibration.load(None), view=ViewSettings(tile_scale=tile_scale), **who)
    visible_mask(pipe)
    return 0


if __name__ == "__main__":
    import sys

    raise SystemExit(_build_visible_mask_main(sys.argv[1:]))
