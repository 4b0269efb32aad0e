"""The listener-reaction model of the seed paper, small enough to train on a CPU.

Given the speaker's audio features ``A_s`` and face states ``V_s`` up to frame ``t`` (a window
of ``speaker_window`` frames), the listener's past face states ``V_l`` (``listener_window``
frames up to ``t``) and a pain level ``p``, predict tokens of the listener's next ``k`` frames::

    h_a = F_a(A_s), h_v = F_v(V_s)              causal 1-D conv encoders (second conv stride 2),
                                                 (B, W/2, d) each
    [h_a' | h_v'] = MHA(cat[h_a, h_v]) + res     cross-modal fusion: concatenation along the
                                                 feature axis (2d), multi-head self-attention,
                                                 split back into two d-wide streams
    memory = TransformerEncoder([h_a' ; h_v'])   2W tokens (+ time and modality embeddings)
    z = [F_l(V_l past) ; q_1 .. q_k]             causal 1-D conv over the listener past, then k
                                                 learned query vectors (one per future frame)
    y = TransformerDecoder(z + pos + pain_emb(p), memory)
    logits = W_out(y at the k query positions)   over the codebook tokens, one set per frame

The k frames of a window are predicted in parallel (one decoder pass), which keeps training
and K-sample generation cheap on a CPU. Generation streams window after window, feeding the
generated frames back as the listener past. Decoding: argmax, or temperature / top-k
sampling; by default the k frames of a window share one uniform variate (inverse-CDF
"coupled" sampling), so a sampled window is temporally coherent instead of flickering between
codes, while different windows and different samples still diverge.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import torch
from torch import Tensor, nn

from ..errors import InputError, ReactionError
from ..validation import check_array, check_finite_scalar

__all__ = ["ModelConfig", "ReactionModel", "generate", "sample_tokens", "state_shapes"]


@dataclass(frozen=True)
class ModelConfig:
    """Architecture sizes (frames are 25 fps)."""

    n_mels: int = 40  # width of an audio feature frame: 40 log-mel bands, or the 6 speech channels
    state_dim: int = 24
    n_codes: int = 512
    d_model: int = 64
    n_heads: int = 4
    enc_layers: int = 2
    dec_layers: int = 2
    ff_dim: int = 128
    dropout: float = 0.1
    speaker_window: int = 48
    listener_window: int = 24
    k: int = 8
    #: what the audio frames hold: "log_mel" (:func:`.audio.log_mel`) or "speech" (:mod:`.speech`)
    audio_features: str = "log_mel"

    def to_dict(self) -> dict:
        """Plain dict (JSON / checkpoint)."""
        return asdict(self)


def state_shapes(config: ModelConfig) -> dict[str, tuple[int, ...]]:
    """The shape of every entry of ``ReactionModel(config).state_dict()``, without building it.

    Pure arithmetic on the config (no tensors, no meta device: building on the meta device pulls in
    ``torch._dynamo`` and sympy, seconds of start-up). Kept next to :class:`ReactionModel`; a test
    checks it against real models' state dicts.

    Raises
    ------
    ReactionError
        A config no model can be built from (odd ``speaker_window``, ``n_heads`` not dividing the
        attention widths).
    """
    c = config
    d, f, h = c.d_model, c.ff_dim, c.n_heads
    if c.speaker_window % 2:
        raise ReactionError(f"speaker_window: expected an even number of frames, found {c.speaker_window}")
    if h < 1 or d % h:
        raise ReactionError(f"n_heads: {h} does not divide d_model {d}")
    shapes: dict[str, tuple[int, ...]] = {
        "pos_s": (c.speaker_window // 2, d), "mod": (2, d), "pos_l": (c.listener_window, d), "queries": (c.k, d),
        "audio_mean": (c.n_mels,), "audio_std": (c.n_mels,), "state_scale": (c.state_dim,)}
    for name, in_dim in (("f_a", c.n_mels), ("f_v", c.state_dim), ("f_l", c.state_dim)):
        shapes.update({f"{name}.c1.weight": (d, in_dim, 5), f"{name}.c1.bias": (d,),
                       f"{name}.c2.weight": (d, d, 3), f"{name}.c2.bias": (d,)})

    def attn(prefix: str, e: int) -> dict:
        return {f"{prefix}.in_proj_weight": (3 * e, e), f"{prefix}.in_proj_bias": (3 * e,),
                f"{prefix}.out_proj.weight": (e, e), f"{prefix}.out_proj.bias": (e,)}

    def norms(prefix: str, names, e: int) -> dict:
        return {f"{prefix}.{n}.{w}": (e,) for n in names for w in ("weight", "bias")}

    ff = {"linear1.weight": (f, d), "linear1.bias": (f,), "linear2.weight": (d, f), "linear2.bias": (d,)}
    shapes.update(attn("fusion", 2 * d))
    shapes.update({"fusion_norm.weight": (2 * d,), "fusion_norm.bias": (2 * d,)})
    shapes.update({"pain.weight": (d, 1), "pain.bias": (d,)})
    for i in range(c.enc_layers):
        p = f"encoder.layers.{i}"
        shapes.update(attn(f"{p}.self_attn", d))
        shapes.update({f"{p}.{k}": v for k, v in ff.items()})
        shapes.update(norms(p, ["norm1", "norm2"], d))
    for i in range(c.dec_layers):
        p = f"decoder.layers.{i}"
        shapes.update(attn(f"{p}.self_attn", d))
        shapes.update(attn(f"{p}.multihead_attn", d))
        shapes.update({f"{p}.{k}": v for k, v in ff.items()})
        shapes.update(norms(p, ["norm1", "norm2", "norm3"], d))
    shapes.update({"out_norm.weight": (d,), "out_norm.bias": (d,), "w_out.weight": (c.n_codes, d),
                   "w_out.bias": (c.n_codes,)})
    return shapes


class CausalConv(nn.Module):
    """Two causal 1-D convolutions with GELU: (B, W, in) -> (B, W / stride, d).

    Output ``i`` only sees inputs up to its own (last) frame; with ``stride=2`` the last output
    covers the last two input frames.
    """

    def __init__(self, in_dim: int, d: int, stride: int = 1) -> None:
        super().__init__()
        self.c1 = nn.Conv1d(in_dim, d, 5)
        self.c2 = nn.Conv1d(d, d, 3, stride=stride)
        self.stride = stride
        self.act = nn.GELU()

    def forward(self, x: Tensor) -> Tensor:  # (B, W, in)
        h = x.transpose(1, 2)
        h = self.act(self.c1(nn.functional.pad(h, (4, 0))))
        h = self.act(self.c2(nn.functional.pad(h, (3 - self.stride, 0))))
        return h.transpose(1, 2)


class ReactionModel(nn.Module):
    """Seed-paper reaction model; see the module docstring.

    Buffers ``audio_mean``/``audio_std`` (n_mels,) standardise log-mel inputs and
    ``state_scale`` (S,) scales face states (set them from the training data).
    """

    def __init__(self, config: ModelConfig) -> None:
        super().__init__()
        self.config = config
        c = config
        d = c.d_model
        self.register_buffer("audio_mean", torch.zeros(c.n_mels))
        self.register_buffer("audio_std", torch.ones(c.n_mels))
        self.register_buffer("state_scale", torch.ones(c.state_dim))
        if c.speaker_window % 2:
            raise ReactionError(f"speaker_window: expected an even number of frames, found {c.speaker_window}")
        self.f_a = CausalConv(c.n_mels, d, stride=2)
        self.f_v = CausalConv(c.state_dim, d, stride=2)
        self.f_l = CausalConv(c.state_dim, d)
        self.fusion = nn.MultiheadAttention(2 * d, c.n_heads, dropout=c.dropout, batch_first=True)
        self.fusion_norm = nn.LayerNorm(2 * d)
        self.pos_s = nn.Parameter(torch.randn(c.speaker_window // 2, d) * 0.02)
        self.mod = nn.Parameter(torch.randn(2, d) * 0.02)
        self.pos_l = nn.Parameter(torch.randn(c.listener_window, d) * 0.02)
        self.queries = nn.Parameter(torch.randn(c.k, d) * 0.02)
        self.pain = nn.Linear(1, d)
        enc = nn.TransformerEncoderLayer(d, c.n_heads, c.ff_dim, c.dropout, batch_first=True, norm_first=True)
        self.encoder = nn.TransformerEncoder(enc, c.enc_layers, enable_nested_tensor=False)
        dec = nn.TransformerDecoderLayer(d, c.n_heads, c.ff_dim, c.dropout, batch_first=True, norm_first=True)
        self.decoder = nn.TransformerDecoder(dec, c.dec_layers)
        self.out_norm = nn.LayerNorm(d)
        self.w_out = nn.Linear(d, c.n_codes)

    # -- parts ---------------------------------------------------------------------------------
    def encode_speaker(self, audio: Tensor, speaker: Tensor) -> Tensor:
        """Encoder memory (B, 2W, d) from audio (B, W, n_mels) and speaker states (B, W, S)."""
        a = (audio - self.audio_mean) / self.audio_std
        h_a = self.f_a(a)
        h_v = self.f_v(speaker * self.state_scale)
        h = torch.cat([h_a, h_v], dim=-1)
        f, _ = self.fusion(h, h, h, need_weights=False)
        h = self.fusion_norm(h + f)
        d = self.config.d_model
        h_a, h_v = h[..., :d], h[..., d:]
        W = h_a.shape[1]
        tokens = torch.cat([h_a + self.pos_s[-W:] + self.mod[0], h_v + self.pos_s[-W:] + self.mod[1]], dim=1)
        return self.encoder(tokens)

    def decode(self, memory: Tensor, listener_past: Tensor, pain: Tensor) -> Tensor:
        """Logits (B, k, n_codes) of the k frames after ``listener_past`` (B, Wl, S)."""
        z = self.f_l(listener_past * self.state_scale) + self.pos_l
        q = self.queries.expand(z.shape[0], -1, -1)
        z = torch.cat([z, q], dim=1) + self.pain(pain[:, None])[:, None, :]
        y = self.decoder(z, memory)
        return self.w_out(self.out_norm(y[:, -self.config.k:]))

    def forward(self, audio: Tensor, speaker: Tensor, listener_past: Tensor, pain: Tensor) -> Tensor:
        """Logits of the listener's next k frames.

        Parameters
        ----------
        audio : Tensor, shape (B, Ws, n_mels)    log-mel of speaker frames t-Ws+1 .. t
        speaker : Tensor, shape (B, Ws, S)       speaker face states of the same frames
        listener_past : Tensor, shape (B, Wl, S) listener states t-Wl+1 .. t (decoded tokens)
        pain : Tensor, shape (B,)                pain level in [0, 1]

        Returns
        -------
        Tensor, shape (B, k, n_codes): logits of frames t+1 .. t+k.
        """
        return self.decode(self.encode_speaker(audio, speaker), listener_past, pain)


def sample_tokens(logits: Tensor, temperature: float = 0.0, top_k: int | None = None,
                  generator: torch.Generator | None = None, coupled: bool = True) -> Tensor:
    """Tokens from logits (B, k, C): argmax when ``temperature == 0``, else top-k sampling.

    Parameters
    ----------
    logits : Tensor, shape (B, k, C)
    temperature : float >= 0
    top_k : int, optional
        Keep the ``top_k`` most likely tokens before sampling (None = all).
    generator : torch.Generator, optional
    coupled : bool
        Inverse-CDF sampling with one uniform variate per row ``b`` shared by its k frames
        (temporally coherent windows); False samples every frame independently.

    Returns
    -------
    Tensor, shape (B, k), int64
    """
    temperature = check_finite_scalar(temperature, "temperature", low=0.0)
    if temperature == 0.0:
        return logits.argmax(dim=-1)
    z = logits / temperature
    if top_k is not None:
        if int(top_k) < 1:
            raise InputError(f"top_k: expected >= 1, found {top_k}")
        kth = torch.topk(z, min(int(top_k), z.shape[-1]), dim=-1).values[..., -1:]
        z = z.masked_fill(z < kth, float("-inf"))
    probs = torch.softmax(z, dim=-1)
    if not coupled:
        flat = probs.reshape(-1, probs.shape[-1])
        return torch.multinomial(flat, 1, generator=generator).reshape(probs.shape[:-1])
    cdf = probs.cumsum(dim=-1)
    u = torch.rand(probs.shape[0], 1, 1, generator=generator, dtype=probs.dtype) * cdf[..., -1:]
    tok = torch.searchsorted(cdf, u.expand(-1, probs.shape[1], 1).contiguous())[..., 0]
    return tok.clamp_(max=probs.shape[-1] - 1)


@torch.no_grad()
def generate(model: ReactionModel, centroids: Tensor, audio: Tensor, speaker: Tensor, pain: Tensor,
             listener_past: Tensor | None = None, n_frames: int | None = None, temperature: float = 0.0,
             top_k: int | None = None, seed: int | None = None, start: int = 0, coupled: bool = True,
             stride: int | None = None) -> Tensor:
    """Stream a listener reaction, ``k`` frames per step, feeding generated frames back.

    Parameters
    ----------
    model : ReactionModel (put in eval mode by this function)
    centroids : Tensor, shape (C, S)     codebook states (token -> face state)
    audio : Tensor, shape (B, T, n_mels) speaker log-mel for the whole clip
    speaker : Tensor, shape (B, T, S)    speaker face states
    pain : Tensor, shape (B,)            requested pain in [0, 1]
    listener_past : Tensor, shape (B, P, S), optional
        Listener frames before frame ``start`` (default: none; neutral zeros are used).
    n_frames : int, optional
        Frames to generate from ``start`` (default ``T - start``).
    temperature, top_k, coupled : decoding (temperature 0 = argmax; see :func:`sample_tokens`)
    seed : int, optional  seed of the sampling generator
    start : int           first generated frame index (speaker frames ``< start`` are context)
    stride : int, optional
        Frames kept per step, 1..k (default k): each step predicts k frames and keeps the first
        ``stride``; the next step comes ``stride`` frames later and sees them as listener past.

    Returns
    -------
    Tensor, shape (B, n_frames, S): generated listener face states (codebook centroids).
    """
    cfg = model.config
    model.eval()
    B, T, _ = audio.shape
    if speaker.shape[:2] != (B, T):
        raise InputError(f"speaker: expected shape ({B}, {T}, S) to match audio, found {tuple(speaker.shape)}")
    if pain.shape != (B,):
        raise InputError(f"pain: expected shape ({B},), found {tuple(pain.shape)}")
    check_array(pain, "pain")
    if bool(((pain < 0) | (pain > 1)).any()):
        raise InputError(f"pain: expected values in [0, 1], found range [{float(pain.min())}, {float(pain.max())}]")
    n_frames = T - start if n_frames is None else int(n_frames)
    if start < 0 or n_frames < 1 or start + n_frames > T:
        raise ReactionError(f"n_frames/start: frames [{start}, {start + n_frames}) outside the clip of {T} frames")
    S, Ws, Wl, k = cfg.state_dim, cfg.speaker_window, cfg.listener_window, cfg.k
    stride = k if stride is None else int(stride)
    if not 1 <= stride <= k:
        raise InputError(f"stride: expected 1..{k} (the model's k), found {stride}")
    gen = None
    if temperature > 0:
        gen = torch.Generator().manual_seed(0 if seed is None else int(seed))
    a_pad = torch.cat([model.audio_mean.expand(B, Ws, -1), audio], dim=1)  # padding = mean (normalised 0)
    s_pad = torch.cat([speaker.new_zeros(B, Ws, S), speaker], dim=1)
    hist = speaker.new_zeros(B, Wl, S)
    if listener_past is not None and listener_past.shape[1] > 0:
        hist = torch.cat([hist, listener_past], dim=1)[:, -Wl:]
    out = []
    t = start - 1  # last observed frame
    done = 0
    while done < n_frames:
        lo = t + 1  # speaker frames [t - Ws + 1, t] sit at [t + 1, t + Ws] in padded coordinates
        logits = model(a_pad[:, lo:lo + Ws], s_pad[:, lo:lo + Ws], hist, pain)
        steps = min(stride, n_frames - done)
        # stride < k: the whole k-frame window is sampled (as ReactionStream does), its first frames kept
        tok = sample_tokens(logits if stride < k else logits[:, :steps], temperature, top_k, gen, coupled)[:, :steps]
        block = centroids[tok]
        out.append(block)
        hist = torch.cat([hist, block], dim=1)[:, -Wl:]
        done += steps
        t += steps
    return torch.cat(out, dim=1)
