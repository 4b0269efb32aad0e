"""The reaction model streamed frame by frame (no threads, no devices): the live loop's clock calls it.

Frame ``t`` (25 fps) arrives as its speaker state plus the audio up to sample ``640 (t + 1)``.
Whenever ``t + 1`` is a multiple of ``stride`` (default 4, :func:`~.decoding.listening_stride`), one
model step predicts listener frames ``t + 1 .. t + k`` from the speaker's last ``speaker_window``
frames and the listener's last ``listener_window`` frames and keeps ``t + 1 .. t + stride``, exactly
the step of :func:`holo_viewer.reaction.model.generate` with that ``stride`` (the first window is
predicted from the padding alone, as offline).
Log-mel frames come from the last window of audio only (a rolling buffer), so memory stays
flat in long sessions; each frame sees the same samples as offline (frame ``t`` needs audio up to
sample ``640 t + 512``, delivered with the frame). Output is smoothed causally (:func:`~holo_viewer.reaction.api.smooth_states`).
"""

from __future__ import annotations

import time
import weakref
from dataclasses import dataclass

import numpy as np

from ..errors import ReactionError
from ..validation import check_finite_scalar

__all__ = ["ReactionStream", "WindowInfo"]

#: this process's warmed-up traces, model -> {(window shapes, parameter versions): trace}: tracing and warming up
#: cost ~0.3 s of CPU at every stream's start (every live session's); a model changed in place is traced again
_TRACES: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()


@dataclass(frozen=True)
class WindowInfo:
    """One model step: the frames it predicted, the last speaker frame it saw and its cost."""

    index: int
    first_frame: int
    input_end_frame: int
    seconds: float


class ReactionStream:
    """Stream listener states (see the module docstring).

    Parameters
    ----------
    bundle : ReactionBundle
    temperature, top_k, seed : decoding (temperature 0 = argmax)
    smoothing : float
        Output smoothing time constant in seconds (0 = raw tokens).
    stride : int, optional
        Frames between model steps, 1..k (default :func:`~.decoding.listening_stride` of k: 4), as
        :func:`~holo_viewer.reaction.api.react`.
    trace : bool
        Run the steps on a TorchScript trace of the model for the stream's fixed window shapes (the live
        loop's; issue 37): ~1.3 instead of ~2.7 ms of CPU a step (single thread), the same logits (tested
        equal to the model's, bit for bit, over a session's steps). Traced and warmed up here (~0.3 s), once per
        process and model (:data:`_TRACES`); if tracing fails the model runs as it is (``trace_error`` says why).
    """

    def __init__(self, bundle, temperature: float = 0.0, top_k: int | None = None, seed: int = 0,
                 smoothing: float = 0.12, stride: int | None = None, trace: bool = False) -> None:
        import torch

        from .audio import AudioConfig

        self.bundle = bundle
        self.model = bundle.model.eval()
        cfg = self.model.config
        self.cfg = cfg
        self.S, self.Ws, self.Wl, self.k = cfg.state_dim, cfg.speaker_window, cfg.listener_window, cfg.k
        from .decoding import listening_stride

        self.stride = listening_stride(self.k) if stride is None else int(stride)
        if not 1 <= self.stride <= self.k:
            raise ReactionError(f"stride: expected 1..{self.k} (the model's k), found {self.stride}")
        self.audio_config = AudioConfig(n_mels=cfg.n_mels)
        self.hop = self.audio_config.hop
        self.temperature = check_finite_scalar(temperature, "temperature", low=0.0)
        self.top_k = top_k
        self._gen = torch.Generator().manual_seed(int(seed)) if temperature > 0 else None
        self._centroids = bundle.centroids()
        self.smoothing = float(smoothing)
        self._audio = np.zeros(0, np.float32)  # rolling: samples [self._audio_start, self._audio_end)
        self._audio_start = 0
        self._speaker = np.zeros((self.Ws, self.S), np.float32)  # last Ws speaker frames (zero padded)
        self._hist = np.zeros((self.Wl, self.S), np.float32)  # last Wl listener frames (raw tokens)
        self._pending: list[np.ndarray] = []  # predicted, not yet emitted (raw)
        self._smoothed: np.ndarray | None = None
        self.t = -1  # last speaker frame received
        self.windows: list[WindowInfo] = []
        self._speech = None
        if getattr(cfg, "audio_features", "log_mel") == "speech":
            from .speech import SpeechTracker

            self._speech = SpeechTracker()
            self._speech_rows: dict[int, np.ndarray] = {}  # frame -> speech channels (the last Ws frames)
        #: the model the steps run (``self.model`` or its trace) and why tracing failed (None: not asked / fine)
        self._run = self.model
        self.trace_error: str | None = None
        if trace:
            self._run = self._traced()

    def _traced(self):
        """A trace of the model for (1, Ws, audio), (1, Ws, S), (1, Wl, S), (1,) inputs, warmed up (the
        profiling executor specialises on its first calls), or the model itself if tracing fails."""
        import warnings

        import torch

        n_audio = int(self.model.audio_mean.shape[0])
        key = (self.Ws, self.Wl, self.S, n_audio, self.model.training,
               tuple(int(t._version) for t in (*self.model.parameters(), *self.model.buffers())))
        kept = _TRACES.get(self.model, {}).get(key)
        if kept is not None:
            return kept
        gen = torch.Generator().manual_seed(0)
        ex = (torch.randn(1, self.Ws, n_audio, generator=gen), torch.randn(1, self.Ws, self.S, generator=gen),
              torch.randn(1, self.Wl, self.S, generator=gen), torch.tensor([0.5]))
        try:
            with torch.no_grad(), warnings.catch_warnings():
                warnings.simplefilter("ignore")  # TracerWarnings of the shape checks, fixed here
                traced = torch.jit.trace(self.model, ex, check_trace=False)
                for _ in range(3):
                    got = traced(*ex)
                if not torch.equal(got, self.model(*ex)):
                    raise ReactionError("the traced model's logits differ from the model's")
        except Exception as exc:  # noqa: BLE001 - the eager model works: run it, say why
            self.trace_error = f"{type(exc).__name__}: {exc}"
            return self.model
        _TRACES[self.model] = {key: traced}
        return traced

    @property
    def audio_samples(self) -> int:
        """Samples received so far."""
        return self._audio_start + len(self._audio)

    def push_audio(self, samples: np.ndarray) -> None:
        """Append audio (16 kHz mono); keeps only what the next window needs."""
        x = np.asarray(samples, dtype=np.float32).reshape(-1)
        if x.size and not np.isfinite(x).all():
            x = np.nan_to_num(x, nan=0.0, posinf=0.0, neginf=0.0)
        if self._speech is not None:
            self._speech.push(x)
        self._audio = np.concatenate([self._audio, x])
        keep = (self.Ws + 2) * self.hop
        if len(self._audio) > keep:
            drop = len(self._audio) - keep
            self._audio = self._audio[drop:]
            self._audio_start += drop

    def _log_mel_window(self) -> np.ndarray:
        """(Ws, n_mels) log-mel of speaker frames t-Ws+1 .. t, padded with the training mean before 0.

        Frame ``i`` is the spectrum of samples ``[640 i - 512, 640 i + 512)``, as in
        :func:`~holo_viewer.reaction.audio.log_mel` (reflect padding before the first sample).
        """
        import torch

        from .audio import mel_filter_bank

        n = min(self.t + 1, self.Ws)
        out = self.model.audio_mean.expand(self.Ws, -1).clone()
        if n <= 0:
            return out
        c = self.audio_config
        half = c.n_fft // 2
        first = self.t + 1 - n
        lo, hi = first * self.hop - half, self.t * self.hop + half  # global sample range
        buf = self._audio
        need_hi = hi - self._audio_start
        if need_hi > len(buf):  # audio not (yet) delivered: silence
            buf = np.concatenate([buf, np.zeros(need_hi - len(buf), np.float32)])
        if lo < 0:  # the clip start: reflect padding, as torch.stft(center=True) does offline
            head = buf[1:1 - lo][::-1] if self._audio_start == 0 else np.zeros(-lo, np.float32)
            seg = np.concatenate([head, buf[:need_hi]])
        else:
            seg = buf[lo - self._audio_start:need_hi]
        if not hasattr(self, "_fb"):
            self._fb = torch.from_numpy(mel_filter_bank(c).astype(np.float32))
            self._win = torch.hann_window(c.n_fft, periodic=True, dtype=torch.float32)
        spec = torch.stft(torch.from_numpy(np.ascontiguousarray(seg, dtype=np.float32)), n_fft=c.n_fft,
                          hop_length=self.hop, win_length=c.n_fft, window=self._win, center=False,
                          return_complex=True)  # (F, n)
        power = spec.real ** 2 + spec.imag ** 2
        out[self.Ws - n:] = torch.log(power[:, :n].T @ self._fb + c.eps)
        return out

    def _speech_window(self):
        """(Ws, 6) speech channels of speaker frames t-Ws+1 .. t, padded with the training mean before 0.

        Rows come from :class:`~holo_viewer.reaction.speech.SpeechTracker` as the audio arrives; a frame
        whose audio has not arrived yet repeats the latest row before it (offline, every frame's audio
        is there and the window equals :func:`~holo_viewer.reaction.speech.speech_features` rows, pitch
        aside: see that module)."""
        import torch

        rows = self._speech.frames()
        first = self._speech.state.frame - rows.shape[0]
        for j, r in enumerate(rows):
            self._speech_rows[first + j] = r
        for f in [f for f in self._speech_rows if f < self.t - self.Ws]:
            del self._speech_rows[f]
        out = self.model.audio_mean.expand(self.Ws, -1).clone()
        last = None
        for j, f in enumerate(range(self.t - self.Ws + 1, self.t + 1)):
            if f < 0:
                continue
            last = self._speech_rows.get(f, last)
            if last is not None:
                out[j] = torch.from_numpy(last)
        return out

    def _step(self, pain: float) -> None:
        import torch

        from .model import sample_tokens

        t0 = time.perf_counter()
        a = (self._log_mel_window() if self._speech is None else self._speech_window())[None]
        s = torch.from_numpy(self._speaker)[None]
        h = torch.from_numpy(self._hist)[None]
        with torch.no_grad():
            logits = self._run(a, s, h, torch.tensor([float(pain)], dtype=torch.float32))
            tok = sample_tokens(logits, self.temperature, self.top_k, self._gen, coupled=True)
        block = self._centroids[tok][0].numpy()[:self.stride]  # (stride, S) of the k predicted
        self._hist = np.concatenate([self._hist, block])[-self.Wl:]
        self._pending.extend(block)
        self.windows.append(WindowInfo(len(self.windows), self.t + 1, self.t, time.perf_counter() - t0))

    def push_frame(self, speaker_state: np.ndarray, pain: float) -> tuple[np.ndarray, int]:
        """Add speaker frame ``t + 1``; returns the listener state for that frame and the index of the
        window that predicted it. Runs one model step when the frame closes a window."""
        st = np.asarray(speaker_state, dtype=np.float32).reshape(-1)
        if st.shape[0] != self.S:
            raise ReactionError(f"speaker_state: expected {self.S} values, found {st.shape[0]}")
        pain = check_finite_scalar(pain, "pain", low=0.0, high=1.0)
        if self.t == -1:  # frames 0 .. stride-1 from the padding alone, as generate() does
            self._step(pain)
        self.t += 1
        self._speaker = np.concatenate([self._speaker[1:], np.nan_to_num(st)[None]])
        raw = self._pending.pop(0)
        window = (self.t // self.stride)
        if self.smoothing > 0:
            a = 1.0 - np.exp(-1.0 / (25.0 * self.smoothing))
            self._smoothed = raw.copy() if self._smoothed is None else self._smoothed + a * (raw - self._smoothed)
            out = self._smoothed.copy()
        else:
            out = raw.copy()
        if (self.t + 1) % self.stride == 0:
            self._step(pain)
        return out, window
