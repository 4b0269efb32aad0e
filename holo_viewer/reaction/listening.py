"""How a listener behaves, measured on FLAME parameter sequences (pure functions, 25 fps).

The measures of the listener-behaviour benchmark (``bench/listener_behaviour.py``, issue 36), each a
plain function of arrays so that tests can feed it hand-built sequences:

* :func:`head_motion_deg`: peak-to-peak head pitch / yaw / roll (root ``rotation`` composed with
  ``neck_pose``), degrees.
* :func:`detect_nods`: nods = downward head-pitch bumps (FLAME +x rotation tips the face down) of at
  least 2 deg prominence lasting 0.12-1.6 s (at half prominence); the onset is the left
  half-prominence crossing minus half that width (the start of a raised-sine bump).
* :func:`nod_contingency`: the share of nod onsets 0.2-1.0 s after a pause onset, against 1000
  circular shifts of the nod times within each clip (ratio to the shifted mean, one-sided p).
  :func:`ideal_contingency_p`: the p the same test gives a listener that nods after every pause
  (what a recording's pauses allow at best).
* :func:`eyelid_channel` / :func:`detect_blinks`: the AU43 projection of ``expr`` (1 = shut); a
  blink is a run at >= 0.8 lasting 100-400 ms (longer closures are counted apart).
* :func:`gaze_angles`, :func:`gaze_on_target`, :func:`aversions`, :func:`gaze_yaw_correlation`:
  the angle between each eye's gaze and the direction to a target, the share of frames within
  5 deg, aversions (runs of >= 0.3 s beyond 5 deg), and the correlation of gaze yaw with the
  target's yaw.
* :func:`count_events`: rising crossings of an AU intensity (smiles: AU12 >= 1; brow raises:
  mean of AU1, AU2 >= 1; intensity scale 0-5), with hysteresis.

Pause onsets come from :func:`holo_viewer.reaction.speech.pause_onsets` (VAD: >= 200 ms of silence
after >= 700 ms of speech).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from ..errors import InputError
from ..validation import check_array

__all__ = ["head_angles_deg", "head_motion_deg", "detect_nods", "NodContingency", "nod_contingency",
           "ideal_contingency_p", "eyelid_channel", "detect_blinks", "gaze_angles", "gaze_on_target", "aversions",
           "gaze_yaw_correlation", "count_events", "runs", "nod_lags", "lag_histogram"]

FPS = 25.0


def runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """``[start, stop)`` of each run of True in a 1-D mask."""
    m = np.asarray(mask, bool).astype(np.int8)
    idx = np.flatnonzero(np.diff(np.concatenate([[0], m, [0]])))
    return [(int(a), int(b)) for a, b in zip(idx[::2], idx[1::2])]


def _rotmats(rv: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.from_rotvec(rv).as_matrix()


def head_angles_deg(rotation: np.ndarray, neck_pose: np.ndarray | None = None) -> np.ndarray:
    """Head pitch, yaw, roll (T, 3) in degrees: intrinsic x-y-z angles of ``R(rotation) R(neck_pose)``."""
    from scipy.spatial.transform import Rotation

    rot = np.asarray(check_array(rotation, "rotation", ("T", 3)), dtype=np.float64)
    R = _rotmats(rot)
    if neck_pose is not None:
        neck = np.asarray(check_array(neck_pose, "neck_pose", (rot.shape[0], 3)), dtype=np.float64)
        R = R @ _rotmats(neck)
    return Rotation.from_matrix(R).as_euler("XYZ", degrees=True)


def head_motion_deg(rotation: np.ndarray, neck_pose: np.ndarray | None = None) -> dict[str, float]:
    """Peak-to-peak head pitch, yaw and roll in degrees, and ``max`` of pitch and yaw."""
    a = head_angles_deg(rotation, neck_pose)
    ptp = np.ptp(a, axis=0) if a.shape[0] else np.zeros(3)
    return {"pitch": float(ptp[0]), "yaw": float(ptp[1]), "roll": float(ptp[2]), "max": float(max(ptp[0], ptp[1]))}


def detect_nods(pitch_deg: np.ndarray, fps: float = FPS, min_prominence: float = 2.0,
                width_s: tuple[float, float] = (0.12, 1.6)) -> np.ndarray:
    """Onset frames of nods in a head-pitch sequence (degrees, + = face down); see the module docstring."""
    from scipy.signal import find_peaks, peak_widths

    p = np.asarray(check_array(pitch_deg, "pitch_deg", ("T",)), dtype=np.float64)
    if p.shape[0] < 3:
        return np.zeros(0, np.int64)
    peaks, props = find_peaks(p, prominence=min_prominence, width=(width_s[0] * fps, width_s[1] * fps),
                              wlen=int(4 * fps) | 1)
    if peaks.size == 0:
        return np.zeros(0, np.int64)
    w, _, left, _ = peak_widths(p, peaks, rel_height=0.5, prominence_data=(props["prominences"], props["left_bases"],
                                                                            props["right_bases"]))
    return np.maximum(np.rint(left - w / 2.0), 0).astype(np.int64)


@dataclass(frozen=True)
class NodContingency:
    """Nod onsets after pause onsets against chance (circular shifts)."""

    n_nods: int
    n_pauses: int
    share: float  # observed share of nod onsets lo..hi s after a pause onset
    shifted_mean: float  # mean share over the shifts
    ratio: float  # share / shifted_mean (nan when the shifted mean is 0)
    p: float  # (1 + #{shifted >= observed}) / (1 + n_shifts)


def _share(nods: Sequence[np.ndarray], pauses: Sequence[np.ndarray], lo: float, hi: float) -> tuple[int, int]:
    hit = tot = 0
    for n, q in zip(nods, pauses):
        if n.size == 0:
            continue
        tot += n.size
        if q.size:
            d = n[:, None] - q[None, :]
            hit += int(np.any((d >= lo) & (d <= hi), axis=1).sum())
    return hit, tot


def nod_contingency(nod_times: Sequence[np.ndarray], pause_times: Sequence[np.ndarray], durations: Sequence[float],
                    lo: float = 0.2, hi: float = 1.0, n_shifts: int = 1000, seed: int = 0,
                    groups: Sequence[int] | None = None) -> NodContingency:
    """Contingency of nod onsets on pause onsets, pooled over clips.

    Parameters
    ----------
    nod_times, pause_times : sequences (one per clip) of 1-D arrays of seconds
    durations : clip lengths in seconds (the circle the nod times are shifted around)
    lo, hi : the window after a pause onset, seconds
    n_shifts : circular shifts; each shifts every clip's nod times by its own uniform offset
    seed : seed of the shifts
    groups : one label per clip, optional: clips with the same label (seeded realisations of one
        listener on one recording: the same pauses and length) share one offset per shift, so the
        shifted shares keep whatever the realisations have in common (a conservative null for
        realisations that are not independent); default every clip on its own

    Returns
    -------
    NodContingency
    """
    if not (len(nod_times) == len(pause_times) == len(durations)):
        raise InputError(f"nod_contingency: expected one nod list, pause list and duration per clip, found "
                         f"{len(nod_times)}, {len(pause_times)}, {len(durations)}")
    nods = [np.asarray(n, dtype=np.float64).reshape(-1) for n in nod_times]
    pauses = [np.asarray(q, dtype=np.float64).reshape(-1) for q in pause_times]
    dur = np.asarray(durations, dtype=np.float64)
    hit, tot = _share(nods, pauses, lo, hi)
    n_p = int(sum(q.size for q in pauses))
    if tot == 0:
        return NodContingency(0, n_p, float("nan"), float("nan"), float("nan"), 1.0)
    if groups is not None:
        labels = list(groups)
        if len(labels) != len(nods):
            raise InputError(f"nod_contingency: expected one group label per clip ({len(nods)}), found {len(labels)}")
        uniq = sorted(set(labels), key=labels.index)
        member = np.array([uniq.index(g) for g in labels])
        gdur = np.array([dur[member == k][0] for k in range(len(uniq))])
        if not np.allclose(dur, gdur[member]):
            raise InputError("nod_contingency: expected clips of one group to share their length, found "
                             f"{sorted(set(np.round(dur, 3)))} s")
    rng = np.random.default_rng(seed)
    shifted = np.empty(n_shifts)
    for s in range(n_shifts):
        off = rng.uniform(0.0, dur) if groups is None else rng.uniform(0.0, gdur)[member]
        h, _ = _share([np.mod(n + o, d) for n, o, d in zip(nods, off, dur)], pauses, lo, hi)
        shifted[s] = h / tot
    share = hit / tot
    mean = float(shifted.mean())
    return NodContingency(tot, n_p, share, mean, share / mean if mean > 0 else float("nan"),
                          float((1 + np.sum(shifted >= share)) / (1 + n_shifts)))


def nod_lags(nod_times: np.ndarray, pause_times: np.ndarray, max_lag: float = 2.0) -> np.ndarray:
    """Seconds from the latest pause onset at or before each nod onset to the nod, for the nods that
    come within ``max_lag`` of one (nod onsets and pause onsets in seconds; order kept)."""
    n = np.asarray(nod_times, dtype=np.float64).reshape(-1)
    q = np.sort(np.asarray(pause_times, dtype=np.float64).reshape(-1))
    if n.size == 0 or q.size == 0:
        return np.zeros(0)
    i = np.searchsorted(q, n, side="right") - 1
    ok = i >= 0
    d = n[ok] - q[i[ok]]
    return d[d <= max_lag]


def lag_histogram(lags: np.ndarray, bin_s: float = 0.1, max_lag: float = 2.0) -> list[int]:
    """Counts of ``lags`` in bins of ``bin_s`` from 0 to ``max_lag`` (the last bin closed)."""
    nb = int(round(max_lag / bin_s))
    return np.histogram(np.asarray(lags, np.float64), bins=np.linspace(0.0, max_lag, nb + 1))[0].astype(int).tolist()


def ideal_contingency_p(pause_times: np.ndarray, duration: float, n_listeners: int = 20,
                        lag: tuple[float, float] = (0.2, 1.0), lo: float = 0.2, hi: float = 1.0,
                        n_shifts: int = 1000, seed: int = 0) -> float:
    """The contingency p of an ideal listener on one recording: ``n_listeners`` realisations, each
    nodding once after every pause onset at a lag uniform in ``lag`` (seeded), pooled with one shift
    per recording (``groups``) as the bench pools seeded listeners. A recording with few pauses
    cannot give a smaller p than this to any listener whose lags spread like ``lag`` (with lags
    bunched within the window it is larger): the test's floor on that recording, not a measurement
    of a model. Nods past the recording's end wrap around, as the shifts do."""
    q = np.asarray(pause_times, dtype=np.float64).reshape(-1)
    dur = float(duration)
    if q.size == 0:
        return 1.0
    rng = np.random.default_rng(np.random.SeedSequence([seed, 36]))
    nods = [np.sort(np.mod(q + rng.uniform(lag[0], lag[1], q.size), dur)) for _ in range(int(n_listeners))]
    c = nod_contingency(nods, [q] * len(nods), [dur] * len(nods), lo=lo, hi=hi, n_shifts=n_shifts, seed=seed,
                        groups=[0] * len(nods))
    return c.p


def eyelid_channel(expr: np.ndarray, au_map) -> np.ndarray:
    """AU43 (eye closure, 1 = shut) of expression coefficients: least-squares projection on AU43's row."""
    m = np.asarray(au_map.matrix, dtype=np.float64)
    names = list(au_map.names)
    if "AU43" not in names:
        raise InputError(f"au_map: expected an AU43 (eyelid) row, found {names}")
    row = m[names.index("AU43")]
    e = np.asarray(check_array(expr, "expr", ("T", None)), dtype=np.float64)
    if e.shape[1] < row.shape[0]:
        e = np.concatenate([e, np.zeros((e.shape[0], row.shape[0] - e.shape[1]))], axis=1)
    return e[:, :row.shape[0]] @ row / float(row @ row)


def detect_blinks(eyelid: np.ndarray, fps: float = FPS, threshold: float = 0.8,
                  duration_s: tuple[float, float] = (0.1, 0.4)) -> tuple[np.ndarray, np.ndarray]:
    """Blinks in an eyelid channel: ``(onset frames, durations in s)`` of runs at >= ``threshold``
    lasting ``duration_s``; closures outside that range are not blinks."""
    e = np.asarray(check_array(eyelid, "eyelid", ("T",)), dtype=np.float64)
    on, dur = [], []
    for a, b in runs(e >= threshold):
        d = (b - a) / fps
        if duration_s[0] - 1e-9 <= d <= duration_s[1] + 1e-9:
            on.append(a)
            dur.append(d)
    return np.asarray(on, np.int64), np.asarray(dur, np.float64)


def gaze_angles(centres: np.ndarray, directions: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Angle (deg) per frame between the gaze and the direction to the target, mean of the two eyes.

    Parameters
    ----------
    centres, directions : numpy.ndarray, shape (T, 2, 3): eye centres and gaze directions
        (:func:`holo_viewer.behaviour.eye_directions`)
    target : numpy.ndarray, shape (3,) or (T, 3): the point looked at, same frame
    """
    c = np.asarray(check_array(centres, "centres", ("T", 2, 3)), dtype=np.float64)
    d = np.asarray(check_array(directions, "directions", (c.shape[0], 2, 3)), dtype=np.float64)
    t = np.asarray(target, dtype=np.float64)
    t = np.broadcast_to(t.reshape(-1, 1, 3) if t.ndim == 2 else t.reshape(1, 1, 3), c.shape)
    want = t - c
    cross = np.linalg.norm(np.cross(want, d), axis=-1)
    return np.degrees(np.arctan2(cross, np.sum(want * d, axis=-1))).mean(axis=1)


def gaze_on_target(angles_deg: np.ndarray, within: float = 5.0, mask: np.ndarray | None = None) -> float:
    """Share of frames (where ``mask``, e.g. the listening frames) with the gaze within ``within`` deg."""
    a = np.asarray(check_array(angles_deg, "angles_deg", ("T",)), dtype=np.float64)
    m = np.ones(a.shape[0], bool) if mask is None else np.asarray(mask, bool)
    return float(np.mean(a[m] <= within)) if m.any() else float("nan")


def aversions(angles_deg: np.ndarray, fps: float = FPS, beyond: float = 5.0, min_s: float = 0.3) -> np.ndarray:
    """Onset frames of gaze aversions: runs beyond ``beyond`` deg lasting at least ``min_s``."""
    a = np.asarray(check_array(angles_deg, "angles_deg", ("T",)), dtype=np.float64)
    return np.asarray([s for s, e in runs(a > beyond) if (e - s) / fps >= min_s - 1e-9], np.int64)


def gaze_yaw_correlation(directions: np.ndarray, centres: np.ndarray, target: np.ndarray) -> float:
    """Pearson r between the gaze yaw and the target's yaw seen from the eyes (both eyes averaged)."""
    d = np.asarray(directions, dtype=np.float64).mean(axis=1)
    c = np.asarray(centres, dtype=np.float64).mean(axis=1)
    t = np.broadcast_to(np.asarray(target, dtype=np.float64).reshape(-1, 3), c.shape)
    w = t - c
    gy, ty = np.arctan2(d[:, 0], d[:, 2]), np.arctan2(w[:, 0], w[:, 2])
    if np.std(gy) == 0 or np.std(ty) == 0:
        return float("nan")
    return float(np.corrcoef(gy, ty)[0, 1])


def count_events(intensity: np.ndarray, on: float = 1.0, off: float | None = None) -> np.ndarray:
    """Onset frames where ``intensity`` rises to ``on`` after having fallen below ``off``
    (default ``on / 2``): smiles (AU12), brow raises (mean of AU1 and AU2)."""
    x = np.asarray(check_array(intensity, "intensity", ("T",)), dtype=np.float64)
    off = on / 2.0 if off is None else float(off)
    out, up = [], False
    for i, v in enumerate(x):
        if not up and v >= on:
            out.append(i)
            up = True
        elif up and v < off:
            up = False
    return np.asarray(out, np.int64)
