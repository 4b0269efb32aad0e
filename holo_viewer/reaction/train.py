"""Training of the reaction model: seeded, tqdm progress, atomic resumable checkpoints, early stopping.

``train(config, out)`` fits the codebook on the training listeners' frames, then trains the
model with teacher forcing (cross-entropy over the k future tokens) on random windows of the
training split. Every ``eval_every`` steps it measures the validation loss on fixed windows,
keeps the best weights and stops after ``patience`` evaluations without improvement.

Files: ``out`` receives the final, small checkpoint (best weights, codebook, configs; no
optimizer) when training ends; ``out.partial.pt`` holds the resumable state (weights,
optimizer, step, RNG states, best weights so far) and is written atomically at every
evaluation and removed at the end. ``resume=True`` continues from it.
"""

from __future__ import annotations

import json
import math
import os
import time
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ..errors import ReactionError
from ..fileio import atomic_path
from .audio import AudioConfig
from .data import ReactionSplit, SyntheticConfig, make_synthetic_split
from .model import ModelConfig, ReactionModel
from .tokens import Codebook, fit_codebook, state_weights

__all__ = ["TrainConfig", "ReactionBundle", "train", "load_checkpoint", "save_checkpoint", "load_train_config",
           "train_config_from_dict",
           "batch_windows"]

CHECKPOINT_VERSION = 1


@dataclass(frozen=True)
class TrainConfig:
    """Everything that defines a training run (JSON-serialisable; see ``load_train_config``)."""

    seed: int = 0
    data: SyntheticConfig = field(default_factory=SyntheticConfig)
    model: ModelConfig = field(default_factory=ModelConfig)
    n_codes: int = 512
    pose_weight: float = 5.0
    batch_size: int = 32
    max_steps: int = 3000
    lr: float = 2e-3
    weight_decay: float = 0.01
    warmup: int = 100
    label_smoothing: float = 0.05
    eval_every: int = 200
    val_windows: int = 512
    patience: int = 4
    threads: int = 2
    max_minutes: float = 9.0

    def to_dict(self) -> dict:
        """Nested plain dict."""
        return asdict(self)


def _from_dict(cls, d: dict | None, name: str):
    if d is None:
        return cls()
    known = {f.name: f for f in fields(cls)}
    bad = sorted(set(d) - set(known))
    if bad:
        raise ReactionError(f"{name}: unknown keys {bad}; expected some of {sorted(known)}")
    kw = dict(d)
    if cls is SyntheticConfig and "audio" in kw:
        kw["audio"] = _from_dict(AudioConfig, kw["audio"], f"{name}.audio")
    return cls(**kw)


def train_config_from_dict(d: dict) -> TrainConfig:
    """TrainConfig from a (partial) nested dict; unknown keys raise :class:`ReactionError`."""
    d = dict(d)
    data = _from_dict(SyntheticConfig, d.pop("data", None), "data")
    model = _from_dict(ModelConfig, d.pop("model", None), "model")
    top = _from_dict(TrainConfig, d, "config")
    return TrainConfig(**{**{f.name: getattr(top, f.name) for f in fields(TrainConfig)}, "data": data, "model": model})


def load_train_config(path: str | os.PathLike) -> TrainConfig:
    """Read a training config JSON (any subset of :class:`TrainConfig`'s nested fields)."""
    p = Path(path)
    try:
        d = json.loads(p.read_text())
    except FileNotFoundError as exc:
        raise ReactionError(f"{p}: config file not found") from exc
    except json.JSONDecodeError as exc:
        raise ReactionError(f"{p}: not valid JSON ({exc})") from exc
    if not isinstance(d, dict):
        raise ReactionError(f"{p}: expected a JSON object, found {type(d).__name__}")
    return train_config_from_dict(d)


@dataclass
class ReactionBundle:
    """A trained model with everything needed to use it."""

    model: ReactionModel
    codebook: Codebook
    au_names: tuple[str, ...]
    train_config: TrainConfig
    meta: dict[str, Any]

    def centroids(self) -> torch.Tensor:
        """Codebook states (C, S) as a float32 tensor."""
        return torch.from_numpy(self.codebook.centroids)


# ---- data -> tensors -----------------------------------------------------------------------------
@dataclass
class _Tensors:
    audio: torch.Tensor  # (C, Ws + T, F) padded with the audio mean at the front
    speaker: torch.Tensor  # (N, Ws + T, S) padded with zeros
    listener: torch.Tensor  # (N, Wl + T, S) decoded tokens, padded with zeros
    tokens: torch.Tensor  # (N, T)
    context: torch.Tensor  # (N,)
    pain: torch.Tensor  # (N,)


def _tensors(split: ReactionSplit, codebook: Codebook, audio_mean: np.ndarray, cfg: ModelConfig) -> _Tensors:
    N, T, S = split.listener_state.shape
    tokens = codebook.encode(split.listener_state)
    dec = codebook.decode(tokens)
    C = split.audio.shape[0]
    a = np.concatenate([np.broadcast_to(audio_mean, (C, cfg.speaker_window, split.audio.shape[2])), split.audio], 1)
    sp = np.concatenate([np.zeros((N, cfg.speaker_window, S), np.float32), split.speaker_state], 1)
    li = np.concatenate([np.zeros((N, cfg.listener_window, S), np.float32), dec], 1)
    return _Tensors(torch.from_numpy(np.ascontiguousarray(a, dtype=np.float32)), torch.from_numpy(sp),
                    torch.from_numpy(np.ascontiguousarray(li, dtype=np.float32)), torch.from_numpy(tokens),
                    torch.from_numpy(split.context), torch.from_numpy(split.pain))


def batch_windows(t: _Tensors, clip: torch.Tensor, last: torch.Tensor, cfg: ModelConfig):
    """Training windows: for clip i and last observed frame ``last`` (-1 .. T-k-1), the model inputs and targets."""
    Ws, Wl, k = cfg.speaker_window, cfg.listener_window, cfg.k
    s_idx = (last + 1)[:, None] + torch.arange(Ws)[None, :]  # frames last-Ws+1 .. last, padded coordinates
    audio = t.audio[t.context[clip][:, None], s_idx]
    speaker = t.speaker[clip[:, None], s_idx]
    l_idx = (last + 1)[:, None] + torch.arange(Wl)[None, :]  # frames last-Wl+1 .. last, padded coordinates
    past = t.listener[clip[:, None], l_idx]
    target = t.tokens[clip[:, None], (last + 1)[:, None] + torch.arange(k)[None, :]]
    return audio, speaker, past, t.pain[clip], target


# ---- checkpoints ---------------------------------------------------------------------------------
def save_checkpoint(path: str | os.PathLike, payload: dict) -> Path:
    """``torch.save`` written atomically."""
    with atomic_path(path) as tmp:
        torch.save(payload, tmp)
    return Path(path)


def _bundle_payload(model: ReactionModel, codebook: Codebook, au_names, cfg: TrainConfig, meta: dict,
                    state_dict: dict | None = None) -> dict:
    return {"version": CHECKPOINT_VERSION, "kind": "holo_viewer.reaction",
            "model_state": state_dict if state_dict is not None else model.state_dict(),
            "codebook": codebook.to_tensors(), "au_names": list(au_names), "train_config": cfg.to_dict(),
            "meta": meta}


def load_checkpoint(path: str | os.PathLike) -> ReactionBundle:
    """Load a final checkpoint written by :func:`train` (``weights_only`` safe loading)."""
    p = Path(path)
    if not p.is_file():
        raise ReactionError(f"{p}: checkpoint not found (train one with `holo-viewer train-reaction --out {p}`)")
    try:
        d = torch.load(p, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises many types for corrupt files
        raise ReactionError(f"{p}: not a readable torch checkpoint ({type(exc).__name__}: {exc})") from exc
    if not isinstance(d, dict) or d.get("kind") != "holo_viewer.reaction":
        raise ReactionError(f"{p}: not a holo_viewer reaction checkpoint (missing kind='holo_viewer.reaction')")
    if d.get("version") != CHECKPOINT_VERSION:
        raise ReactionError(f"{p}: checkpoint version {d.get('version')}, expected {CHECKPOINT_VERSION}")
    cfg = train_config_from_dict(d["train_config"])
    model = ReactionModel(cfg.model)
    try:
        model.load_state_dict(d["model_state"])
    except RuntimeError as exc:
        raise ReactionError(f"{p}: weights do not match the stored model config ({exc})") from exc
    model.eval()
    return ReactionBundle(model, Codebook.from_tensors(d["codebook"]), tuple(d["au_names"]), cfg, dict(d["meta"]))


# ---- training ------------------------------------------------------------------------------------
def _val_loss(model, tv: _Tensors, clips, lasts, cfg: TrainConfig, lossf) -> float:
    model.eval()
    tot, n = 0.0, 0
    with torch.no_grad():
        for s in range(0, clips.numel(), 256):
            a, sp, lp, pn, tg = batch_windows(tv, clips[s:s + 256], lasts[s:s + 256], cfg.model)
            logits = model(a, sp, lp, pn)
            tot += float(lossf(logits.reshape(-1, logits.shape[-1]), tg.reshape(-1))) * tg.numel()
            n += tg.numel()
    model.train()
    return tot / n


def train(cfg: TrainConfig, out: str | os.PathLike, resume: bool = False, progress: bool = True,
          splits: dict[str, ReactionSplit] | None = None, log=print) -> ReactionBundle:
    """Train the reaction model and write the final checkpoint to ``out``.

    Parameters
    ----------
    cfg : TrainConfig
    out : path of the final checkpoint (``out.partial.pt`` holds the resumable state)
    resume : continue from ``out.partial.pt`` when it exists
    progress : show a tqdm bar
    splits : optional pre-generated {"train", "val"} splits (else generated from ``cfg.data``)
    log : callable for one-line messages

    Returns
    -------
    ReactionBundle with the best weights.
    """
    from tqdm import tqdm

    t_start = time.time()
    torch.set_num_threads(max(1, int(cfg.threads)))
    out = Path(out)
    partial = out.with_name(out.name + ".partial.pt")
    torch.manual_seed(cfg.seed)
    np.random.seed(cfg.seed)
    if splits is None:
        log("generating synthetic data (train, val) ...")
        splits = {s: make_synthetic_split(s, cfg.data) for s in ("train", "val")}
    tr, va = splits["train"], splits["val"]
    au_names = tr.au_names
    # the state size and mel count follow the data (AU map of the default head, audio config)
    cfg = replace(cfg, model=replace(cfg.model, state_dim=len(au_names) + 6, n_mels=int(tr.audio.shape[2])))
    state = None
    if resume and partial.is_file():
        state = torch.load(partial, map_location="cpu", weights_only=True)
        codebook = Codebook.from_tensors(state["codebook"])
        log(f"resuming from {partial} at step {state['step']}")
    else:
        log(f"fitting the {cfg.n_codes}-code codebook ...")
        codebook = fit_codebook(tr.listener_state.reshape(-1, tr.listener_state.shape[2]), cfg.n_codes, seed=cfg.seed,
                                weights=state_weights(len(au_names), cfg.pose_weight))
    audio_mean = tr.audio.mean(axis=(0, 1)).astype(np.float32)
    audio_std = (tr.audio.std(axis=(0, 1)) + 1e-3).astype(np.float32)
    ttr = _tensors(tr, codebook, audio_mean, cfg.model)
    tva = _tensors(va, codebook, audio_mean, cfg.model)
    model = ReactionModel(cfg.model)
    model.audio_mean.copy_(torch.from_numpy(audio_mean))
    model.audio_std.copy_(torch.from_numpy(audio_std))
    model.state_scale.copy_(torch.from_numpy(codebook.weights))
    opt = torch.optim.AdamW(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    lossf = torch.nn.CrossEntropyLoss(label_smoothing=cfg.label_smoothing)
    T, k = tr.n_frames, cfg.model.k
    g = torch.Generator().manual_seed(cfg.seed)
    gv = torch.Generator().manual_seed(cfg.seed + 1)
    v_clips = torch.randint(0, va.n_clips, (cfg.val_windows,), generator=gv)
    v_last = torch.randint(-1, T - k, (cfg.val_windows,), generator=gv)
    step, best, bad, best_state, history = 0, math.inf, 0, None, []
    if state is not None:
        model.load_state_dict(state["model_state"])
        opt.load_state_dict(state["opt_state"])
        step, best, bad, history = int(state["step"]), float(state["best"]), int(state["bad"]), list(state["history"])
        best_state = state["best_state"]
        g.set_state(state["rng"])
        torch.set_rng_state(state["torch_rng"])
    sched = lambda s: min(1.0, (s + 1) / cfg.warmup) * 0.5 * (1 + math.cos(math.pi * min(s, cfg.max_steps) / cfg.max_steps))  # noqa: E731
    model.train()
    bar = tqdm(total=cfg.max_steps, initial=step, disable=not progress, desc="train-reaction", unit="step")
    stopped = "max_steps"
    while step < cfg.max_steps:
        for grp in opt.param_groups:
            grp["lr"] = cfg.lr * sched(step)
        clips = torch.randint(0, tr.n_clips, (cfg.batch_size,), generator=g)
        last = torch.randint(-1, T - k, (cfg.batch_size,), generator=g)
        a, sp, lp, pn, tg = batch_windows(ttr, clips, last, cfg.model)
        logits = model(a, sp, lp, pn)
        loss = lossf(logits.reshape(-1, logits.shape[-1]), tg.reshape(-1))
        opt.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), 1.0)
        opt.step()
        step += 1
        bar.update(1)
        bar.set_postfix(loss=f"{float(loss.detach()):.3f}", best=f"{best:.3f}")
        if step % cfg.eval_every == 0 or step == cfg.max_steps:
            vl = _val_loss(model, tva, v_clips, v_last, cfg, lossf)
            history.append({"step": step, "train_loss": float(loss.detach()), "val_loss": vl,
                            "minutes": (time.time() - t_start) / 60})
            if vl < best - 1e-4:
                best, bad = vl, 0
                best_state = {kk: v.detach().clone() for kk, v in model.state_dict().items()}
            else:
                bad += 1
            save_checkpoint(partial, {"step": step, "model_state": model.state_dict(), "opt_state": opt.state_dict(),
                                      "best": best, "bad": bad, "best_state": best_state, "history": history,
                                      "rng": g.get_state(), "torch_rng": torch.get_rng_state(),
                                      "codebook": codebook.to_tensors()})
            if not progress:
                log(f"step {step}: train loss {float(loss.detach()):.4f}, val loss {vl:.4f}, "
                    f"{(time.time() - t_start) / 60:.1f} min")
            if bad >= cfg.patience:
                stopped = "early_stopping"
                break
            if (time.time() - t_start) / 60 > cfg.max_minutes:
                stopped = "time_budget"
                break
    bar.close()
    if best_state is None:
        best_state = model.state_dict()
    model.load_state_dict(best_state)
    model.eval()
    meta = {"steps": step, "best_val_loss": best, "stopped": stopped, "history": history,
            "train_minutes": (time.time() - t_start) / 60, "torch": str(torch.__version__)}
    save_checkpoint(out, _bundle_payload(model, codebook, au_names, cfg, meta, best_state))
    if partial.exists():
        partial.unlink()
    log(f"wrote {out} (steps {step}, best val loss {best:.4f}, stopped: {stopped}, "
        f"{meta['train_minutes']:.1f} min)")
    return ReactionBundle(model, codebook, tuple(au_names), cfg, meta)
