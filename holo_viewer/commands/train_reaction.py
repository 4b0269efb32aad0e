"""``holo-viewer train-reaction``: train the listener-reaction model on the synthetic dyadic data."""

from __future__ import annotations

import argparse

from ..validation import seed_arg
import json

__all__ = ["add_arguments", "run"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``train-reaction``."""
    parser.add_argument("--config", metavar="JSON", help="training config (any subset of TrainConfig's nested "
                        "fields, e.g. {\"max_steps\": 2000, \"data\": {\"seed\": 1}}); default: built-in defaults")
    parser.add_argument("--out", required=True, metavar="CKPT", help="final checkpoint path (.pt); the resumable "
                        "state goes to CKPT.partial.pt while training")
    parser.add_argument("--resume", action="store_true", help="continue from CKPT.partial.pt when it exists")
    parser.add_argument("--seed", type=seed_arg, default=None, help="override the config's seed (training and data)")
    parser.add_argument("--max-steps", type=int, default=None, help="override the config's max_steps")
    parser.add_argument("--threads", type=int, default=None, help="torch CPU threads (default from config: 2)")
    parser.add_argument("--config-out", metavar="JSON", help="also write the effective config as JSON")
    parser.add_argument("--no-progress", action="store_true", help="hide the progress bar")


def run(args: argparse.Namespace) -> int:
    """Train and write the checkpoint; returns 0."""
    from dataclasses import replace

    from ..fileio import atomic_write
    from ..reaction.train import TrainConfig, load_train_config, train, validate_train_config

    cfg = load_train_config(args.config) if args.config else TrainConfig()
    if args.seed is not None:
        cfg = replace(cfg, seed=args.seed, data=replace(cfg.data, seed=args.seed))
    if args.max_steps is not None:
        cfg = replace(cfg, max_steps=args.max_steps)
    if args.threads is not None:
        cfg = replace(cfg, threads=args.threads)
    cfg = validate_train_config(cfg, "train-reaction (config and overrides)")  # before anything is written
    if args.config_out:
        with atomic_write(args.config_out, "w") as fh:
            json.dump(cfg.to_dict(), fh, indent=2)
    train(cfg, args.out, resume=args.resume, progress=not args.no_progress)
    return 0
