"""``holo-viewer react``: listener FLAME parameters reacting to a speaker's audio and face."""

from __future__ import annotations

import argparse

__all__ = ["add_arguments", "run"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``react``."""
    parser.add_argument("--audio", required=True, metavar="SPEAKER.wav", help="speaker audio, 16 kHz WAV")
    parser.add_argument("--speaker", required=True, metavar="SPEAKER.npz",
                        help="speaker FLAME parameters at 25 fps: expr (T, n_expr), jaw_pose (T, 3), rotation (T, 3)")
    parser.add_argument("--listener-past", metavar="F.npz", help="listener frames before the clip "
                        "(same keys as --speaker) to continue from")
    parser.add_argument("--pain", type=float, default=0.0, help="requested pain level in [0, 1] (default 0)")
    parser.add_argument("--out", required=True, metavar="OUT.npz", help="output flame_param.npz (written atomically)")
    parser.add_argument("--checkpoint", metavar="CKPT", help="reaction checkpoint (default: assets/reaction_default.pt)")
    parser.add_argument("--temperature", type=float, default=0.0, help="sampling temperature (0 = argmax, default)")
    parser.add_argument("--top-k", type=int, default=20, help="top-k sampling when temperature > 0")
    parser.add_argument("--seed", type=int, default=0, help="sampling seed")
    parser.add_argument("--smoothing", type=float, default=None, metavar="SECONDS",
                        help="time constant of the causal output smoothing (default 0.12 s; 0 = raw model tokens, "
                             "piecewise constant per k-frame window)")


def run(args: argparse.Namespace) -> int:
    """Generate and write OUT.npz; returns 0."""
    from ..fileio import save_npz
    from ..flame.expressions import default_au_map
    from ..reaction.api import (ANIMATION_SMOOTHING_S, flame_params_from_states, load_default_bundle,
                                load_speaker_npz, react)
    from ..reaction.audio import read_wav

    bundle = load_default_bundle(args.checkpoint)
    au_map = default_au_map()
    speaker = load_speaker_npz(args.speaker, au_map)
    past = load_speaker_npz(args.listener_past, au_map) if args.listener_past else None
    audio, sr = read_wav(args.audio)
    states = react(bundle, audio, sr, speaker, pain=args.pain, listener_past=past, temperature=args.temperature,
                   top_k=args.top_k or None, seed=args.seed,
                   smoothing=ANIMATION_SMOOTHING_S if args.smoothing is None else args.smoothing)
    params = flame_params_from_states(states, au_map)
    save_npz(args.out, **params)
    print(f"wrote {args.out}: {states.shape[0]} frames at 25 fps, keys {sorted(params)}")
    return 0
