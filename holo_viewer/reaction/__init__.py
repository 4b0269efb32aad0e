"""Listener-reaction generator (seed paper), REACT metrics and baselines.

Modules (import what you need; this package imports nothing heavy on its own):

``features``      face-state / FLAME / 25-D REACT attribute layouts and the attribute map
``audio``         log-mel frames at 25 fps (torch) + numpy reference, WAV I/O
``speech``        speech features that survive the microphone (VAD, level, pitch, pauses), streaming tracker
``tts``           espeak-ng speakers in rooms (the shipped model's training speech)
``data``          seeded synthetic dyadic dataset (harmonic or text-to-speech speakers)
``decoding``      the default decoding (seeded top-k sampling at temperature 0.8)
``listening``     listener-behaviour measures on FLAME sequences (nods, contingency, blinks, gaze)
``react_format``  reader for REACT 2023/2024-format data
``tokens``        k-means codebook tokenizer of face states
``model``         1-D conv encoders, cross-modal fusion, Transformer encoder-decoder, token head; streaming
``train``         training with resumable atomic checkpoints, early stopping
``metrics``       FRCorr, FRDist, FRDiv, FRVar, FRDvs, FRSyn (+ robust), Fréchet distance
``baselines``     GT, Random, Mime, MeanFr, MeanSeq
``evaluate``      model vs baselines table, pain following
``api``           speaker files -> listener FLAME params; ``generate_demo_reaction``
"""

__all__ = ["generate_demo_reaction"]


def generate_demo_reaction(seconds: float = 2.0, pain: float = 0.5, seed: int = 0, **kwargs):
    """Listener FLAME parameters (dict of arrays, 25 fps) from the shipped checkpoint; see
    :func:`holo_viewer.reaction.api.generate_demo_reaction`."""
    from .api import generate_demo_reaction as _impl

    return _impl(seconds=seconds, pain=pain, seed=seed, **kwargs)
