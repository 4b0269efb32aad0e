"""Evaluation of the reaction model against the REACT baselines on a split (seed paper, Table 1 layout)."""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import torch

from .baselines import all_baselines
from .data import ReactionSplit
from .features import attributes_from_state, flame_from_state
from .metrics import ReactMetrics, compute_metrics
from .model import generate
from .train import ReactionBundle

__all__ = ["generate_reactions", "pain_following", "EvalResult", "evaluate", "format_table"]

#: columns of the seed paper's Table 1 (+ our robust FRSyn*), with the better direction
TABLE_COLUMNS: tuple[tuple[str, str, str], ...] = (
    ("frcorr", "FRCorr", "up"), ("frdist", "FRDist", "down"), ("frdiv", "FRDiv", "up"), ("frvar", "FRVar", "up"),
    ("frdvs", "FRDvs", "up"), ("frrea", "FRRea", "down"), ("frsyn", "FRSyn", "down"),
    ("frsyn_robust", "FRSyn*", "down"),
)


def generate_reactions(bundle: ReactionBundle, split: ReactionSplit, k_samples: int = 10, temperature: float = 1.0,
                       top_k: int | None = 20, seed: int = 0, pain: np.ndarray | None = None,
                       batch: int = 512) -> np.ndarray:
    """K streamed listener reactions per clip of a split.

    Parameters
    ----------
    bundle : ReactionBundle
    split : ReactionSplit
    k_samples : int
        Reactions per clip (K).
    temperature, top_k : decoding (``temperature=0``: argmax, then all K are identical)
    seed : int
    pain : numpy.ndarray, shape (N,), optional
        Requested pain per clip (default: the split's pain levels).
    batch : int
        Sequences generated together.

    Returns
    -------
    numpy.ndarray, shape (N, K, T, S) float32: face states.
    """
    N, T, S = split.listener_state.shape
    pain = split.pain if pain is None else np.asarray(pain, dtype=np.float32)
    audio = torch.from_numpy(np.repeat(split.clip_audio(), k_samples, axis=0))
    speaker = torch.from_numpy(np.repeat(split.speaker_state, k_samples, axis=0))
    pains = torch.from_numpy(np.repeat(pain.astype(np.float32), k_samples))
    cent = bundle.centroids()
    out = []
    for b, s in enumerate(range(0, N * k_samples, batch)):
        out.append(generate(bundle.model, cent, audio[s:s + batch], speaker[s:s + batch], pains[s:s + batch],
                            temperature=temperature, top_k=top_k, seed=seed * 1000 + b).numpy())
    return np.concatenate(out).reshape(N, k_samples, T, S)


def pain_following(states: np.ndarray, requested: np.ndarray, au_map) -> tuple[float, np.ndarray]:
    """Spearman correlation between requested pain and the mean PSPI of the generated frames.

    Parameters
    ----------
    states : numpy.ndarray, shape (N, K, T, S)
    requested : numpy.ndarray, shape (N,)
    au_map : AUMap of the default head

    Returns
    -------
    (rho, mean_pspi (N,))
    """
    from scipy.stats import spearmanr

    from ..flame.expressions import pspi

    N, K, T, S = states.shape
    expr = flame_from_state(states.reshape(-1, S), au_map)["expr"].astype(np.float64)
    mean_pspi = np.asarray(pspi(expr, au_map), dtype=np.float64).reshape(N, K * T).mean(axis=1)
    rho = float(spearmanr(requested, mean_pspi).statistic)
    return rho, mean_pspi


@dataclass
class EvalResult:
    """Metrics per method, the pain check and the evaluation settings."""

    metrics: dict[str, ReactMetrics]
    pain_spearman: float
    settings: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        """JSON-ready dict."""
        return {"metrics": {k: v.to_dict() for k, v in self.metrics.items()}, "pain_spearman": self.pain_spearman,
                "settings": self.settings}


def evaluate(bundle: ReactionBundle, test: ReactionSplit, train: ReactionSplit, k_samples: int = 10,
             temperature: float = 1.0, top_k: int | None = 20, seed: int = 0, frrea_frames: int = 0,
             log=print, render=None) -> EvalResult:
    """Model and baselines on one split; the model's K reactions are streamed from the speaker only.

    ``train`` gives the MeanFr / MeanSeq baselines. ``frrea_frames > 0`` renders that many random
    frames per method (and of the ground truth) for FRRea (:mod:`holo_viewer.reaction.frrea`) with
    ``render`` (face states (B, S) -> images (B, H, W, 3); e.g. ``holo_viewer.pipeline.FaceStateRenderer()``),
    which the caller must then pass.
    """
    if frrea_frames > 0 and render is None:
        from ..errors import InputError

        raise InputError("render: FRRea (frrea_frames > 0) needs a face-state renderer, e.g. "
                         "holo_viewer.pipeline.FaceStateRenderer(); found None")
    from ..flame.expressions import default_au_map

    t0 = time.time()
    states = generate_reactions(bundle, test, k_samples, temperature, top_k, seed)
    t_gen = time.time() - t0
    preds = {"Ours": attributes_from_state(states, bundle.au_names)}
    preds.update(all_baselines(test.listener_attr, test.speaker_attr, train.listener_attr, k_samples, seed))
    order = ["GT", "Random", "Mime", "MeanFr", "MeanSeq", "Ours"]
    metrics = {}
    for name in order:
        t1 = time.time()
        metrics[name] = compute_metrics(preds[name], test.listener_attr, test.speaker_attr, test.neighbour)
        log(f"  {name}: metrics in {time.time() - t1:.1f} s")
    if frrea_frames > 0:
        from dataclasses import replace as _replace

        from .baselines import state_baselines
        from .frrea import frrea

        st = {"Ours": states, **state_baselines(test.listener_state, test.speaker_state, train.listener_state,
                                                len(bundle.au_names), k_samples, seed)}
        for name in order:
            t1 = time.time()
            v = frrea(test.listener_state, st[name], render, n_frames=frrea_frames, seed=seed)
            metrics[name] = _replace(metrics[name], frrea=v)
            log(f"  {name}: FRRea in {time.time() - t1:.1f} s")
    rho, _ = pain_following(states, test.pain, default_au_map())
    settings = {"split": test.name, "n_clips": test.n_clips, "frames": test.n_frames, "k_samples": k_samples,
                "temperature": temperature, "top_k": top_k, "seed": seed, "generation_seconds": t_gen,
                "frrea": (f"{frrea_frames} random frames per set, 48x48 frontal renders, simple_image_features "
                          "(NOT Inception)") if frrea_frames > 0 else "not computed"}
    return EvalResult(metrics, rho, settings)


def format_table(result: EvalResult) -> str:
    """Text table in the layout of the seed paper's Table 1 (arrows: better direction)."""
    head = f"{'Method':<10}" + "".join(f"{lab + ('↑' if d == 'up' else '↓'):>10}" for _, lab, d in TABLE_COLUMNS)
    lines = [head, "-" * len(head)]
    for name, m in result.metrics.items():
        row = m.to_dict()
        cells = []
        for key, _, _ in TABLE_COLUMNS:
            v = row.get(key)
            cells.append(f"{'n/a':>10}" if v is None or (isinstance(v, float) and np.isnan(v)) else f"{v:>10.4f}")
        lines.append(f"{name:<10}" + "".join(cells))
    lines.append(f"Pain following: Spearman(requested pain, mean PSPI of generated frames) = {result.pain_spearman:.3f}")
    lines.append("FRSyn = official TLCC (first reaction, constant-dimension NaN wins argmax); "
                 "FRSyn* = NaN-robust, all K.")
    lines.append(f"FRRea: {result.settings.get('frrea', 'not computed')}")
    return "\n".join(lines)
