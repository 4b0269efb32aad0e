"""``holo-viewer evaluate-reactions``: REACT metrics of the model and the baselines on the synthetic test split."""

from __future__ import annotations

import argparse

from ..validation import seed_arg
import json

__all__ = ["add_arguments", "run"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``evaluate-reactions``."""
    parser.add_argument("--checkpoint", metavar="CKPT", help="reaction checkpoint (default: assets/reaction_default.pt)")
    parser.add_argument("--json", metavar="FILE", help="also write the table, pain check and settings as JSON")
    parser.add_argument("--samples", type=int, default=10, help="reactions per speaker clip K (default 10)")
    parser.add_argument("--temperature", type=float, default=1.0, help="sampling temperature (0 = argmax)")
    parser.add_argument("--top-k", type=int, default=20, help="top-k sampling (default 20; 0 = all tokens)")
    parser.add_argument("--seed", type=seed_arg, default=0, help="sampling and Random-baseline seed")
    parser.add_argument("--threads", type=int, default=2, help="torch CPU threads")
    parser.add_argument("--frrea-frames", type=int, default=48, help="frames rendered per method for FRRea "
                        "(48x48 frontal renders, simple features, NOT Inception; 0 = skip)")


def run(args: argparse.Namespace) -> int:
    """Print the table (seed paper, Table 1 layout); returns 0."""
    import torch

    from ..errors import InputError
    from ..fileio import atomic_write, check_writable
    from ..reaction.api import load_default_bundle
    from ..reaction.data import make_synthetic_split
    from ..reaction.evaluate import evaluate, format_table

    if args.samples < 1:
        raise InputError(f"--samples: expected >= 1, found {args.samples}")
    if args.json:
        check_writable(args.json, "results JSON")  # before minutes of evaluation, not after
    torch.set_num_threads(max(1, args.threads))
    bundle = load_default_bundle(args.checkpoint)
    data_cfg = bundle.train_config.data
    print(f"generating the synthetic test split (seed {data_cfg.seed}) ...")
    test = make_synthetic_split("test", data_cfg)
    train = make_synthetic_split("train", data_cfg)
    render = None
    if args.frrea_frames > 0:
        from ..pipeline import FaceStateRenderer

        render = FaceStateRenderer()  # 48x48 frontal renders of the default avatar (20k Gaussians)
    result = evaluate(bundle, test, train, k_samples=args.samples, temperature=args.temperature,
                      top_k=args.top_k or None, seed=args.seed, frrea_frames=args.frrea_frames, render=render)
    print(format_table(result))
    if args.json:
        with atomic_write(args.json, "w") as fh:
            json.dump(result.to_dict(), fh, indent=2)
        print(f"wrote {args.json}")
    return 0
