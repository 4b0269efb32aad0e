"""``holo-viewer react``: listener FLAME parameters reacting to a speaker's audio and face."""

from __future__ import annotations

import argparse

from ..validation import seed_arg

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
    from ..reaction.decoding import DEFAULT_TEMPERATURE

    parser.add_argument("--temperature", type=float, default=DEFAULT_TEMPERATURE,
                        help=f"sampling temperature (0 = argmax; default {DEFAULT_TEMPERATURE}: seeded top-k sampling, "
                             "see docs/reaction.md)")
    parser.add_argument("--top-k", type=int, default=20, help="top-k sampling when temperature > 0")
    parser.add_argument("--seed", type=seed_arg, default=0, help="sampling seed")
    parser.add_argument("--smoothing", type=float, default=None, metavar="SECONDS",
                        help="time constant of the causal output smoothing (default 0.12 s; 0 = raw model tokens, "
                             "piecewise constant per k-frame window)")
    parser.add_argument("--viewer-angle", type=float, default=0.0, metavar="DEG",
                        help="the gaze target: a viewer at this angle from the panel's axis (+ = the avatar's "
                             "left, the viewer's right; default 0)")
    parser.add_argument("--viewer-distance", type=float, default=0.6, metavar="M",
                        help="... and this distance from the panel in metres (default 0.6)")
    from .behaviour_args import add_behaviour_arguments

    add_behaviour_arguments(parser)


def run(args: argparse.Namespace) -> int:
    """Generate and write OUT.npz; returns 0."""
    from ..behaviour import viewer_target
    from ..errors import InputError
    from ..fileio import save_npz
    from ..pipeline import react_to_speaker
    from .behaviour_args import behaviour_from_args, pain_from_args

    if not (-60.0 <= args.viewer_angle <= 60.0) or not (0.05 <= args.viewer_distance <= 20.0):
        raise InputError(f"--viewer-angle/--viewer-distance: expected an angle in [-60, 60] deg and a distance in "
                         f"[0.05, 20] m, found {args.viewer_angle} and {args.viewer_distance}")
    behaviour = behaviour_from_args(args, seed=args.seed)
    pain = pain_from_args(args)
    if behaviour is None and not isinstance(pain, float):
        raise InputError("--pain-timeline: needs the behaviour layers (the model alone takes one --pain level)")
    params, n_frames = react_to_speaker(args.audio, args.speaker, pain=pain, listener_past_path=args.listener_past,
                                        checkpoint=args.checkpoint, temperature=args.temperature, top_k=args.top_k,
                                        seed=args.seed, smoothing=args.smoothing, behaviour=behaviour,
                                        target=viewer_target(args.viewer_angle, args.viewer_distance))
    save_npz(args.out, **params)
    print(f"wrote {args.out}: {n_frames} frames at 25 fps, keys {sorted(params)}")
    return 0
