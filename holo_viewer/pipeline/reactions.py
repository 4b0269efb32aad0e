"""The reaction link of the chain: listener reactions -> FLAME frames -> faces -> images.

* :func:`reaction_frames`: the shipped reaction model's listener reaction to a synthesized
  speaker clip, as per-frame FLAME parameters (the demo, ``apps/stream_sequence.py``);
* :func:`react_to_speaker`: the reaction to a speaker's WAV and FLAME parameters (``react``);
* :func:`with_behaviour`: the no-data behaviour layers (gaze, blinks, breathing, sway, pain
  dynamics; :mod:`holo_viewer.behaviour`) composed on a reaction, which both of the above apply by
  default;
* :class:`FaceStateRenderer`: renders reaction face states through a pipeline from one frontal
  camera; the reaction evaluation (FRRea, :func:`holo_viewer.reaction.frrea.frrea`) is given
  one, so the reaction package never builds an avatar or a renderer.
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np

from ..reaction.decoding import DEFAULT_TEMPERATURE, DEFAULT_TOP_K
from .core import Pipeline
from .settings import FaceControls, flame_sequence_frames

__all__ = ["reaction_frames", "react_to_speaker", "with_behaviour", "FaceStateRenderer"]

#: ``behaviour=DEFAULT_BEHAVIOUR`` (the default): every layer on with the default settings
DEFAULT_BEHAVIOUR: Any = "default"


def with_behaviour(params: dict[str, np.ndarray], behaviour: Any = DEFAULT_BEHAVIOUR, pain: Any = 0.0,
                   target: Any = None, audio: np.ndarray | None = None, seed: int = 0,
                   au_map: Any = None) -> dict[str, np.ndarray]:
    """A reaction's FLAME arrays with the behaviour layers composed on them.

    ``behaviour``: a :class:`~holo_viewer.behaviour.BehaviourConfig` (or the default); ``pain``: the
    instructor's level, a float or a :class:`~holo_viewer.behaviour.PainTimeline`; ``target``: the
    point the eyes look at (avatar frame; default a viewer 0.6 m in front of the panel); ``audio``:
    the speaker's 16 kHz samples, for the speech cues of blinks and gaze (None: speaking throughout).
    ``seed`` seeds the default configuration (a given config has its own); ``au_map``: the avatar's
    map (``Pipeline.au_map``), whose pain gains shape the pain face (None: the shipped default head's
    own). The result has ``pain_shown`` (T,): the pain in the face at each frame.
    """
    from ..behaviour import BehaviourConfig, apply_behaviour
    from ..reaction.speech import speech_cues

    cfg = BehaviourConfig(seed=int(seed)) if isinstance(behaviour, str) else behaviour
    T = int(np.asarray(params["expr"]).shape[0])
    sp = po = None
    if audio is not None:
        sp, po = speech_cues(audio, T)
    return apply_behaviour(params, cfg, pain=pain, target=target, speaking=sp, pause_onsets=po, au_map=au_map)


def reaction_frames(seconds: float = 2.0, pain: Any = 0.5, seed: int = 0, behaviour: Any = DEFAULT_BEHAVIOUR,
                    target: Any = None, au_map: Any = None, **kwargs: Any) -> tuple[list[dict[str, np.ndarray]], float]:
    """Listener FLAME frames reacting to a synthesized speaker clip, and their frame rate.

    Parameters
    ----------
    seconds : float
        Clip length (T = round(25 * seconds) frames).
    pain : float or PainTimeline
        The instructor's pain level in [0, 1] (or over time); with behaviour it drives the pain
        dynamics layer and the model is conditioned on 0 (the pain face is the layer's); with
        ``behaviour=None`` the model is conditioned on it (a float).
    seed : int
        Seeds the synthetic speaker and the sampling.
    behaviour : BehaviourConfig or None
        The no-data layers (:func:`with_behaviour`; default: all on); None: the model alone.
    target : (3,) point the eyes look at (avatar frame), optional
    au_map : AUMap, optional
        The avatar's map for the behaviour layers' pain face (``Pipeline.au_map``; None: the shipped
        default head's own, :func:`with_behaviour`).
    **kwargs
        Passed to :func:`holo_viewer.reaction.api.generate_demo_reaction` (temperature, top_k,
        checkpoint, warmup, smoothing).

    Returns
    -------
    frames : list of dict
        One dict of FLAME parameters per frame (see :func:`flame_sequence_frames`).
    fps : float
        Frame rate of the sequence.
    """
    from ..reaction.api import generate_demo_reaction

    if behaviour is None:
        params = generate_demo_reaction(seconds=seconds, pain=pain, seed=seed, **kwargs)
    else:
        params = with_behaviour(generate_demo_reaction(seconds=seconds, pain=0.0, seed=seed, **kwargs), behaviour,
                                pain=pain, target=target, seed=seed, au_map=au_map)
        params.pop("pain_shown")
    fps = float(params.get("fps", 25.0)) if isinstance(params, dict) else 25.0
    return flame_sequence_frames(params, source="reaction model output"), fps


def react_to_speaker(audio_path: str | os.PathLike, speaker_path: str | os.PathLike, *, pain: float = 0.0,
                     listener_past_path: str | os.PathLike | None = None, checkpoint: str | os.PathLike | None = None,
                     temperature: float = DEFAULT_TEMPERATURE, top_k: int | None = DEFAULT_TOP_K, seed: int = 0,
                     smoothing: float | None = None, behaviour: Any = DEFAULT_BEHAVIOUR,
                     target: Any = None, au_map: Any = None) -> tuple[dict[str, np.ndarray], int]:
    """The listener's FLAME parameters reacting to a speaker's audio and face.

    Parameters
    ----------
    audio_path : path
        Speaker audio, 16 kHz WAV.
    speaker_path : path
        Speaker FLAME parameters at 25 fps (``speaker.npz``, docs/reaction.md).
    pain : float or PainTimeline
        The instructor's pain level (see :func:`reaction_frames`).
    listener_past_path : path or None
        Listener frames before the clip (same keys as the speaker file).
    checkpoint : path or None
        Reaction checkpoint (default: ``assets/reaction_default.pt``).
    temperature, top_k, seed
        Decoding (temperature 0 = argmax; default: the model's default decoding,
        :mod:`holo_viewer.reaction.decoding`).
    smoothing : float or None
        Time constant (s) of the causal output smoothing (None = the animation default).
    behaviour : BehaviourConfig or None
        The no-data layers (default: all on; None: the model alone).
    target : (3,) point the eyes look at (avatar frame), optional
    au_map : AUMap, optional
        The avatar's map for the behaviour layers' pain face (see :func:`reaction_frames`).

    Returns
    -------
    params : dict of str to numpy.ndarray
        ``flame_param.npz`` arrays (``expr`` (T, n_expr), ``jaw_pose`` (T, 3), ...; with behaviour
        also ``pain_shown`` (T,), the pain in the face).
    n_frames : int
    """
    from ..flame.expressions import default_au_map
    from ..reaction.api import (ANIMATION_SMOOTHING_S, flame_params_from_states, load_default_bundle,
                                load_speaker_npz, react)
    from ..reaction.audio import read_wav

    bundle = load_default_bundle(checkpoint)
    states_map = default_au_map()  # the reaction model's AU space (its states), not the avatar's pain face
    speaker = load_speaker_npz(speaker_path, states_map)
    past = load_speaker_npz(listener_past_path, states_map) if listener_past_path else None
    audio, sr = read_wav(audio_path)
    states = react(bundle, audio, sr, speaker, pain=pain if behaviour is None else 0.0, listener_past=past,
                   temperature=temperature, top_k=top_k or None, seed=seed,
                   smoothing=ANIMATION_SMOOTHING_S if smoothing is None else smoothing)
    params = flame_params_from_states(states, states_map)
    if behaviour is not None:
        params = with_behaviour(params, behaviour, pain=pain, target=target, audio=audio, seed=seed, au_map=au_map)
    return params, int(states.shape[0])


class FaceStateRenderer:
    """Renders reaction face states (AU intensities + jaw + head rotation) of the default head.

    Each state is turned into FLAME parameters (``reaction.features.flame_from_state``), posed
    by a :class:`Pipeline` on the default avatar, and rendered from one frontal camera at
    ``size`` x ``size`` pixels. Callable: ``renderer(states)`` is :meth:`render`.

    Parameters
    ----------
    size : int
        Image side in pixels.
    n_gaussians : int
        Gaussians of the default avatar (SH degree 1).
    backend : str
        Renderer backend.
    """

    def __init__(self, size: int = 48, n_gaussians: int = 20000, backend: str = "fast") -> None:
        from ..avatar.default_gaussians import default_avatar
        from ..camera import Cameras, intrinsics, look_at
        from ..flame.expressions import default_au_map

        self.size, self.n_gaussians, self.backend = int(size), int(n_gaussians), backend
        self.au_map = default_au_map()
        self.pipeline = Pipeline(avatar=default_avatar(n_gaussians=self.n_gaussians, sh_degree=1), backend=backend)
        f = self.size * 2.2
        w2c = look_at((0.0, 0.0, 0.7), (0.0, 0.0, 0.0))[None]
        K = intrinsics(f, f, self.size / 2, self.size / 2)[None]
        self.cameras: Cameras = Cameras(world_to_cam=w2c, K=K, width=self.size, height=self.size, near=0.05, far=5.0)

    @property
    def state_dim(self) -> int:
        """S: the width of a face state (AUs + 3 jaw + 3 rotation)."""
        return int(self.au_map.matrix.shape[0]) + 6

    def render(self, states: np.ndarray) -> np.ndarray:
        """Render face states.

        Parameters
        ----------
        states : numpy.ndarray
            (B, S) face states.

        Returns
        -------
        numpy.ndarray
            (B, size, size, 3) float32 images.
        """
        from ..reaction.features import flame_from_state

        fl = flame_from_state(np.asarray(states, dtype=np.float64), self.au_map)
        n_expr = int(self.pipeline.model.n_expr)
        pipe, base = self.pipeline, self.pipeline.face
        imgs = []
        try:
            for t in range(fl["expr"].shape[0]):
                pipe.set_face(FaceControls(expr=fl["expr"][t, :n_expr], jaw_pose=fl["jaw_pose"][t],
                                           rotation=fl["rotation"][t]))
                imgs.append(pipe.render_view(0, cameras=self.cameras))
        finally:
            pipe.set_face(base)
        return np.stack(imgs)

    __call__ = render
