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

__all__ = ["DEFAULT_TEMPERATURE", "DEFAULT_TOP_K"]
