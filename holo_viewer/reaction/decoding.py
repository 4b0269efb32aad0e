"""The reaction model's default decoding (light: no torch), shared by ``react``, ``live``, render-batch
and the demo.

The shipped model hears speech but, decoded by argmax, stays still: at every window the single most
likely code is the neutral listener (a nod is likelier than not only summed over the many codes of
its phases and amplitudes). Seeded top-k sampling at a temperature below 1 keeps the model's own
timing of nods and smiles after the speaker's pauses while dropping its least likely codes.
``temperature = 0`` still means argmax everywhere. 0.8 was chosen among 0.6-1.0 on the librispeech
recording and six 20-s text-to-speech clips of the training voices (docs/reaction.md, "Decoding"),
never on the held-out recording or voices: argmax 0 deg of head motion; 0.8: 6.3 deg, 4.9 nods/min
with contingency ratio 3.8 on pause onsets, 4.5 smiles/min.
"""

#: sampling temperature of the default decoding (0 = argmax)
DEFAULT_TEMPERATURE = 0.8
#: top-k of the default decoding
DEFAULT_TOP_K = 20

#: frames between two model steps when a listener is animated (``react``, ``ReactionStream`` and so ``live``):
#: each step predicts the model's k = 8 frames and keeps the first 4 (0.16 s), so the listener answers a
#: pause up to 0.16 s sooner, and its nod after a pause is drawn at twice as many points of the speech
#: (docs/reaction.md, "Stepping"). Must be a multiple of ``speech.PITCH_BLOCK`` (the pitch channel is
#: complete per block). ``generate`` (the REACT metrics) steps k frames unless told.
LISTENING_STRIDE = 4

__all__ = ["DEFAULT_TEMPERATURE", "DEFAULT_TOP_K", "LISTENING_STRIDE", "listening_stride"]


def listening_stride(k: int) -> int:
    """The animation paths' frames per model step for a model predicting ``k`` frames: min(4, k)."""
    return max(1, min(LISTENING_STRIDE, int(k)))
