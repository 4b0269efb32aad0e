"""One-Euro filter (Casiez, Roussel and Vogel, CHI 2012) and a lag measurement (pure numpy).

A speed-adaptive low-pass: per dimension, with sample period ``Te``::

    alpha(fc) = 1 / (1 + 1 / (2 pi fc Te))
    dx_hat    = lowpass((x - x_hat_prev) / Te, alpha(d_cutoff))
    fc        = min_cutoff + beta |dx_hat|
    x_hat     = lowpass(x, alpha(fc))

Still signals get the ``min_cutoff`` low-pass (little jitter); fast motion raises the cutoff
(little lag). :func:`measure_lag` reports the delay it adds on a test signal.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ..validation import check_array, check_finite_scalar

__all__ = ["OneEuroConfig", "OneEuroFilter", "measure_lag"]


@dataclass(frozen=True)
class OneEuroConfig:
    """``min_cutoff`` (Hz), ``beta`` (1 / signal unit) and ``d_cutoff`` (Hz) of a One-Euro filter."""

    min_cutoff: float = 1.5
    beta: float = 0.5
    d_cutoff: float = 1.0

    def __post_init__(self) -> None:
        check_finite_scalar(self.min_cutoff, "min_cutoff", low=0.0, low_open=True)
        check_finite_scalar(self.beta, "beta", low=0.0)
        check_finite_scalar(self.d_cutoff, "d_cutoff", low=0.0, low_open=True)


def _alpha(cutoff: np.ndarray, dt: float) -> np.ndarray:
    tau = 1.0 / (2.0 * math.pi * cutoff)
    return 1.0 / (1.0 + tau / dt)


class OneEuroFilter:
    """Vector One-Euro filter; ``config`` may differ per dimension (pass a sequence).

    Parameters
    ----------
    dim : int
    config : OneEuroConfig or sequence of OneEuroConfig (one per dimension)
    """

    def __init__(self, dim: int, config: OneEuroConfig | list[OneEuroConfig] = OneEuroConfig()) -> None:
        cfgs = [config] * int(dim) if isinstance(config, OneEuroConfig) else list(config)
        if len(cfgs) != int(dim):
            raise InputError(f"config: expected {dim} OneEuroConfig, found {len(cfgs)}")
        self.dim = int(dim)
        self._min = np.array([c.min_cutoff for c in cfgs])
        self._beta = np.array([c.beta for c in cfgs])
        self._dcut = np.array([c.d_cutoff for c in cfgs])
        self.reset()

    def reset(self, value: np.ndarray | None = None, t: float | None = None) -> None:
        """Forget the history (the next sample passes through unchanged), or restart from ``value``
        at time ``t`` (the next sample is filtered from there)."""
        self._x = None if value is None else np.asarray(value, dtype=np.float64).copy()
        self._dx = np.zeros(self.dim)
        self._t: float | None = None if value is None else t

    def lag_s(self) -> np.ndarray:
        """(dim,) seconds the output trails a steady ramp at the current cutoff: a first-order
        low-pass at cutoff f_c trails ``v / (2 pi f_c)`` behind a signal moving at speed ``v``
        (exact for the discrete update at a constant step, once the cutoff has settled)."""
        return 1.0 / (2.0 * math.pi * (self._min + self._beta * np.abs(self._dx)))

    def __call__(self, x: np.ndarray, t: float) -> np.ndarray:
        """Filter sample ``x`` (dim,) taken at time ``t`` seconds; returns the filtered (dim,)."""
        x = np.asarray(check_array(x, "x", (self.dim,)), dtype=np.float64)
        t = check_finite_scalar(t, "t")
        if self._x is None or self._t is None:
            self._x, self._t = x.copy(), t
            return x.copy()
        dt = t - self._t
        if dt <= 0:  # a repeated or out-of-order stamp: hold
            return self._x.copy()
        dx = (x - self._x) / dt
        self._dx = self._dx + _alpha(self._dcut, dt) * (dx - self._dx)
        cutoff = self._min + self._beta * np.abs(self._dx)
        self._x = self._x + _alpha(cutoff, dt) * (x - self._x)
        self._t = t
        return self._x.copy()


def measure_lag(config: OneEuroConfig, fps: float = 25.0, frequency_hz: float = 1.0, amplitude: float = 0.2,
                seconds: float = 8.0) -> float:
    """Delay (seconds) the filter adds to a sine of ``frequency_hz`` and ``amplitude``.

    Found as the lag maximising the cross-correlation between input and output (sub-frame by a
    parabola through the peak), after the first second.
    """
    fps = check_finite_scalar(fps, "fps", low=0.0, low_open=True)
    n = int(round(seconds * fps))
    t = np.arange(n) / fps
    x = amplitude * np.sin(2 * math.pi * frequency_hz * t)
    f = OneEuroFilter(1, config)
    y = np.array([f(np.array([v]), ti)[0] for v, ti in zip(x, t)])
    s = int(fps)
    xs, ys = x[s:] - x[s:].mean(), y[s:] - y[s:].mean()
    max_lag = int(fps / frequency_hz / 2)
    c = np.array([np.dot(xs[: len(xs) - k], ys[k:]) for k in range(max_lag)])
    k = int(np.argmax(c))
    if 0 < k < max_lag - 1:
        den = c[k - 1] - 2 * c[k] + c[k + 1]
        k = k + (0.5 * (c[k - 1] - c[k + 1]) / den if den != 0 else 0.0)
    return float(k / fps)
