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

import dataclasses
import math
import os
import time
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ..errors import ReactionError
from ..fileio import atomic_path, check_writable, read_json
from .audio import AudioConfig
from .data import ReactionSplit, SyntheticConfig, make_synthetic_split
from .model import ModelConfig, ReactionModel, state_shapes
from .tokens import Codebook, fit_codebook, state_weights

__all__ = ["TrainConfig", "ReactionBundle", "train", "load_checkpoint", "save_checkpoint", "load_train_config",
           "train_config_from_dict", "validate_train_config",
           "batch_windows"]

CHECKPOINT_VERSION = 1
#: parameters a reaction checkpoint may ask for (the shipped model has 0.33 M; 20 M is 80 MB of
#: float32): checked on a meta-device model, before anything is allocated
MAX_REACTION_PARAMETERS = 20_000_000


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
    max_minutes: float = 9.0  # budget in CPU minutes of the training process (not wall: load-independent)

    def to_dict(self) -> dict:
        """Nested plain dict."""
        return asdict(self)


def _from_dict(cls, d: dict | None, name: str):
    if d is None:
        return cls()
    if not isinstance(d, dict):
        raise ReactionError(f"{name}: expected a JSON object of {cls.__name__} fields, found "
                            f"{'null' if d is None else type(d).__name__}")
    known = {f.name: f for f in fields(cls)}
    bad = sorted(set(d) - set(known))
    if bad:
        raise ReactionError(f"{name}: unknown keys {bad}; expected some of {sorted(known)}")
    kw = dict(d)
    if cls is SyntheticConfig and "audio" in kw:
        kw["audio"] = _from_dict(AudioConfig, kw["audio"], f"{name}.audio")
    return cls(**kw)


def train_config_from_dict(d: dict, source: str = "config") -> TrainConfig:
    """TrainConfig from a (partial) nested dict, validated (:func:`validate_train_config`).

    Raises
    ------
    ReactionError
        Unknown keys, a value of the wrong JSON type or out of range (naming ``source`` and the field).
    """
    if not isinstance(d, dict):
        raise ReactionError(f"{source}: expected a JSON object, found {type(d).__name__}")
    d = dict(d)
    data = _from_dict(SyntheticConfig, d.pop("data", None), f"{source}: data")
    model = _from_dict(ModelConfig, d.pop("model", None), f"{source}: model")
    top = _from_dict(TrainConfig, d, source)
    cfg = TrainConfig(**{**{f.name: getattr(top, f.name) for f in fields(TrainConfig)}, "data": data, "model": model})
    return validate_train_config(cfg, source)


# field -> (low, high, low_open); integer-ness follows the field's default value. Unlisted numbers: finite.
_LIMITS: dict[str, tuple[float | None, float | None, bool]] = {
    "seed": (0, None, False), "n_codes": (2, None, False), "pose_weight": (0, None, True),
    "batch_size": (1, None, False), "max_steps": (1, None, False), "lr": (0, 1.0, True),
    "weight_decay": (0, None, False), "warmup": (1, None, False), "label_smoothing": (0, 1, False),
    "eval_every": (1, None, False), "val_windows": (1, None, False), "patience": (1, None, False),
    "threads": (1, 1024, False), "max_minutes": (0, None, True),
    "data.seed": (0, None, False), "data.seconds": (1.0, 3600.0, False), "data.train_contexts": (1, None, False),
    "data.val_contexts": (1, None, False), "data.test_contexts": (1, None, False),
    "data.listeners_per_context": (1, None, False), "data.pain_zero_fraction": (0, 1, False),
    "data.cue_lag_jitter_s": (0, 0.8, False), "data.cue_smile_prob": (0, 1, False),
    "data.audio.sample_rate": (1, None, False), "data.audio.fps": (1, None, False),
    "data.audio.n_fft": (2, None, False), "data.audio.n_mels": (1, None, False), "data.audio.fmin": (0, None, False),
    "data.audio.fmax": (0, None, True), "data.audio.eps": (0, None, True),
    "model.n_mels": (1, None, False), "model.state_dim": (1, None, False), "model.n_codes": (2, None, False),
    "model.d_model": (1, 4096, False), "model.n_heads": (1, None, False), "model.enc_layers": (1, 64, False),
    "model.dec_layers": (1, 64, False), "model.ff_dim": (1, 65536, False), "model.dropout": (0, 1, False),
    "model.speaker_window": (2, None, False), "model.listener_window": (1, None, False), "model.k": (1, None, False),
}


def _check_fields(obj: Any, prefix: str, source: str) -> None:
    from ..errors import InputError
    from ..validation import check_json_number

    default = type(obj)()
    for f in fields(obj):
        path = prefix + f.name
        value, ref = getattr(obj, f.name), getattr(default, f.name)
        if dataclasses.is_dataclass(ref):
            if not isinstance(value, type(ref)):
                raise ReactionError(f"{source}: {path}: expected an object of {type(ref).__name__} fields, "
                                    f"found {type(value).__name__}")
            _check_fields(value, path + ".", source)
            continue
        if isinstance(ref, bool) or not isinstance(ref, (int, float)):
            continue
        low, high, low_open = _LIMITS.get(path, (None, None, False))
        try:
            check_json_number(value, path, integer=isinstance(ref, int), low=low, high=high, low_open=low_open)
        except InputError as exc:
            raise ReactionError(f"{source}: {exc}") from None


def validate_train_config(cfg: TrainConfig, source: str = "config") -> TrainConfig:
    """Check every field of a :class:`TrainConfig` before any training step; returns it.

    Types (integers where the default is one, numbers elsewhere; no strings, null or
    booleans), ranges (``_LIMITS``: ``batch_size >= 1``, ``max_steps >= 1``, ``0 < lr <= 1``,
    ...) and the relations between fields (``d_model`` divisible by ``n_heads``, an even
    ``speaker_window``, ``fmin < fmax <= sample_rate / 2``, clips longer than ``k`` frames).

    Raises
    ------
    ReactionError
        Naming ``source``, the field (``model.d_model``), the expected and the found.
    """
    if not isinstance(cfg, TrainConfig):
        raise ReactionError(f"{source}: expected a TrainConfig, found {type(cfg).__name__}")
    _check_fields(cfg, "", source)
    m, a = cfg.model, cfg.data.audio
    from .data import check_data_kinds

    check_data_kinds(cfg.data, source)
    if m.audio_features not in ("log_mel", "speech"):
        raise ReactionError(f"{source}: model.audio_features: expected 'log_mel' or 'speech', found {m.audio_features!r}")
    rules = [
        (m.d_model % m.n_heads == 0, f"model.d_model: expected a multiple of model.n_heads ({m.n_heads}), "
                                     f"found {m.d_model}"),
        (m.speaker_window % 2 == 0, f"model.speaker_window: expected an even number of frames, found "
                                    f"{m.speaker_window}"),
        (cfg.n_codes <= m.n_codes, f"n_codes: expected <= model.n_codes ({m.n_codes}), found {cfg.n_codes}"),
        (a.sample_rate // a.fps >= 1, f"data.audio.fps: expected <= data.audio.sample_rate ({a.sample_rate}), "
                                      f"found {a.fps}"),
        (a.fmin < a.fmax <= a.sample_rate / 2, f"data.audio.fmin/fmax: expected 0 <= fmin < fmax <= sample_rate / 2 "
                                               f"({a.sample_rate / 2:g}), found {a.fmin:g}, {a.fmax:g}"),
        (cfg.data.n_frames > m.k, f"data.seconds: expected clips longer than model.k = {m.k} frames, found "
                                  f"{cfg.data.n_frames} frames"),
    ]
    for ok, message in rules:
        if not ok:
            raise ReactionError(f"{source}: {message}")
    return cfg


def load_train_config(path: str | os.PathLike) -> TrainConfig:
    """Read a training config JSON (any subset of :class:`TrainConfig`'s nested fields)."""
    p = Path(path)
    return train_config_from_dict(read_json(p, ReactionError, "training config JSON"), source=str(p))


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


def _check_state_shapes(state: Any, model_cfg: ModelConfig, source: str) -> None:
    """Bound the parameter count and match every weight's shape, from the config alone (no memory).

    The expected shapes come from :func:`.model.state_shapes` (arithmetic; no meta-device build,
    which would import ``torch._dynamo`` and sympy at every ``live`` start).

    Raises
    ------
    ReactionError
        More than :data:`MAX_REACTION_PARAMETERS` parameters, or a missing, extra or
        differently shaped weight (named).
    """
    try:
        expected = state_shapes(model_cfg)
    except ReactionError as exc:
        raise ReactionError(f"{source}: train_config.model cannot build a model ({exc})") from exc
    n_params = sum(math.prod(shape) for shape in expected.values())
    if n_params > MAX_REACTION_PARAMETERS:
        raise ReactionError(f"{source}: train_config.model asks for {n_params:,} parameters, more than the "
                            f"{MAX_REACTION_PARAMETERS:,} accepted (reaction.train.MAX_REACTION_PARAMETERS); "
                            f"refusing to build it")
    if not isinstance(state, dict):
        raise ReactionError(f"{source}: model_state: expected a dict of tensors, found {type(state).__name__}")
    missing, extra = sorted(set(expected) - set(state)), sorted(set(state) - set(expected))
    if missing or extra:
        raise ReactionError(f"{source}: model_state: weights do not match the stored model config "
                            f"(missing {missing[:5]}, unexpected {extra[:5]})")
    for key, shape in expected.items():
        found = tuple(state[key].shape) if isinstance(state[key], torch.Tensor) else type(state[key]).__name__
        if found != shape:
            raise ReactionError(f"{source}: model_state[{key!r}]: expected shape {shape} (from train_config), "
                                f"found {found}")


def _build_model(model_cfg: ModelConfig) -> ReactionModel:
    """The real (allocated) model; called only after :func:`_check_state_shapes`."""
    return ReactionModel(model_cfg)


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
    cfg = train_config_from_dict(d["train_config"], source=f"{p}: train_config")
    _check_state_shapes(d.get("model_state"), cfg.model, str(p))
    model = _build_model(cfg.model)
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
    c_start = time.process_time()  # the max_minutes budget: this process's CPU, not the wall clock
    cfg = validate_train_config(cfg)
    out = Path(out)
    partial = out.with_name(out.name + ".partial.pt")
    check_writable(out, "checkpoint")  # before training, not after it
    check_writable(partial, "resumable checkpoint")
    torch.set_num_threads(int(cfg.threads))
    torch.manual_seed(cfg.seed)
    np.random.seed(cfg.seed)
    if splits is None:
        log("generating synthetic data (train, val) ...")
        splits = {s: make_synthetic_split(s, cfg.data) for s in ("train", "val")}
    tr, va = splits["train"], splits["val"]
    au_names = tr.au_names
    # the state size and mel count follow the data (AU map of the default head, audio config)
    cfg = replace(cfg, model=replace(cfg.model, state_dim=len(au_names) + 6, n_mels=int(tr.audio.shape[2]),
                                     audio_features=cfg.data.audio_features))
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
            # CPU minutes: other jobs on a shared machine must not cut the run short (a wall-clock
            # budget made the documented command train a different model under load)
            if (time.process_time() - c_start) / 60 > cfg.max_minutes:
                stopped = "time_budget"
                break
    bar.close()
    if best_state is None:
        best_state = model.state_dict()
    model.load_state_dict(best_state)
    model.eval()
    meta = {"steps": step, "best_val_loss": best, "stopped": stopped, "history": history,
            "train_minutes": (time.time() - t_start) / 60, "cpu_minutes": (time.process_time() - c_start) / 60,
            "torch": str(torch.__version__)}
    save_checkpoint(out, _bundle_payload(model, codebook, au_names, cfg, meta, best_state))
    if partial.exists():
        partial.unlink()
    log(f"wrote {out} (steps {step}, best val loss {best:.4f}, stopped: {stopped}, "
        f"{meta['train_minutes']:.1f} min)")
    return ReactionBundle(model, codebook, tuple(au_names), cfg, meta)
