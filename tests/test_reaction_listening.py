"""Listener-behaviour measures (holo_viewer.reaction.listening) on hand-built sequences."""

from __future__ import annotations

import numpy as np
import pytest

from holo_viewer.errors import InputError
from holo_viewer.reaction.listening import (aversions, count_events, detect_blinks, detect_nods, eyelid_channel,
                                            gaze_angles, gaze_on_target, gaze_yaw_correlation, head_angles_deg,
                                            head_motion_deg, ideal_contingency_p, lag_histogram,
                                            nod_contingency, nod_lags)

FPS = 25


def _bump(T, start, dur, amp):
    t = np.arange(T) / FPS
    m = (t >= start) & (t < start + dur)
    out = np.zeros(T)
    out[m] = amp * np.sin(np.pi * (t[m] - start) / dur) ** 2
    return out


def test_head_motion_composes_root_and_neck():
    T = 100
    rot = np.zeros((T, 3))
    rot[:, 0] = np.radians(3.0) * np.sin(np.linspace(0, 2 * np.pi, T))
    neck = np.zeros((T, 3))
    neck[:, 1] = np.radians(2.0) * np.cos(np.linspace(0, 2 * np.pi, T))
    m = head_motion_deg(rot, neck)
    assert m["pitch"] == pytest.approx(6.0, abs=0.05) and m["yaw"] == pytest.approx(4.0, abs=0.05)
    assert m["max"] == pytest.approx(m["pitch"])
    assert head_motion_deg(rot)["yaw"] == pytest.approx(0.0, abs=1e-9)
    np.testing.assert_allclose(head_angles_deg(rot)[:, 0], np.degrees(rot[:, 0]), atol=1e-9)


def test_nods_found_at_their_onsets_and_small_bumps_ignored():
    T = 500
    pitch = 1.5 * np.sin(np.arange(T) / FPS * 2 * np.pi / 8.0)  # slow sway, 3 deg peak to peak over 8 s
    starts = [2.0, 6.4, 11.0, 15.2]
    for s in starts:
        pitch += _bump(T, s, 0.8, 5.0)
    pitch += _bump(T, 18.0, 0.8, 1.0)  # too small
    pitch -= _bump(T, 8.5, 0.8, 5.0)  # upward: not a nod
    on = detect_nods(pitch)
    assert len(on) == 4
    np.testing.assert_allclose(on / FPS, starts, atol=0.12)


def test_nod_contingency_against_shifts():
    rng = np.random.default_rng(1)
    pauses = [np.sort(rng.uniform(0, 60, 12)) for _ in range(3)]
    locked = [p + 0.5 for p in pauses]
    c = nod_contingency(locked, pauses, [60.0, 60.0, 60.0], n_shifts=500)
    assert c.share == 1.0 and c.n_nods == 36 and c.n_pauses == 36
    assert c.p < 0.01 and c.ratio > 2.5
    # the observed share is counted by hand: nods 0.1, 0.5, 1.2 s after the only pause
    one = nod_contingency([np.array([10.1, 10.5, 11.2])], [np.array([10.0])], [30.0], n_shifts=10)
    assert one.share == pytest.approx(1 / 3)
    unrelated = nod_contingency([np.sort(rng.uniform(0, 60, 40))], [pauses[0]], [60.0], n_shifts=500)
    assert unrelated.p > 0.05
    with pytest.raises(InputError, match="one nod list"):
        nod_contingency([locked[0]], pauses, [60.0])


def test_nod_contingency_pools_realisations_with_one_shift():
    """Realisations of one recording share each shift: 20 copies of one nod train give exactly the
    single train's test (independent shifts would shrink the null's spread and the p-value); nods
    locked to the pauses in every realisation stay significant."""
    rng = np.random.default_rng(3)
    pauses = np.sort(rng.uniform(0, 14, 4))
    nods = np.sort(rng.uniform(0, 14, 3))
    one = nod_contingency([nods], [pauses], [14.0], n_shifts=300, seed=5)
    pooled = nod_contingency([nods] * 20, [pauses] * 20, [14.0] * 20, n_shifts=300, seed=5, groups=[0] * 20)
    assert (pooled.share, pooled.ratio, pooled.p) == pytest.approx((one.share, one.ratio, one.p))
    locked = [np.sort(pauses[rng.choice(4, 2, replace=False)] + rng.uniform(0.3, 0.9, 2)) for _ in range(20)]
    c = nod_contingency(locked, [pauses] * 20, [14.0] * 20, n_shifts=300, groups=[7] * 20)
    assert c.share == 1.0 and c.p < 0.05 and c.ratio > 2
    with pytest.raises(InputError, match="share their length"):
        nod_contingency([nods] * 2, [pauses] * 2, [14.0, 12.0], groups=[0, 0])


def test_ideal_contingency_p_is_the_floor_of_few_pauses():
    """Many pauses: an ideal listener reaches the smallest p; three pauses with lags bunched in
    0.4-0.8 s cannot get below ~0.05 (the shifts that keep the nods in their windows)."""
    many = ideal_contingency_p(np.arange(1.0, 60.0, 3.0), 60.0, n_shifts=300)
    assert many <= 2 / 301
    few = np.array([2.16, 7.56, 10.6])
    bunched = ideal_contingency_p(few, 11.0, lag=(0.4, 0.8), n_shifts=300)
    assert bunched >= 0.04
    assert ideal_contingency_p(np.zeros(0), 11.0) == 1.0


def test_blinks_by_duration():
    e = np.zeros(300)
    e[10:15] = 1.0  # 0.2 s: a blink
    e[50:52] = 0.9  # 0.08 s: too short
    e[100:115] = 1.0  # 0.6 s: a closure, not a blink
    e[200:210] = 0.85  # 0.4 s: a blink
    e[250:255] = 0.7  # below threshold
    on, dur = detect_blinks(e)
    assert on.tolist() == [10, 200]
    np.testing.assert_allclose(dur, [0.2, 0.4])


def test_eyelid_channel_projects_au43():
    class Map:
        names = ("AU1", "AU43")
        matrix = np.array([[1.0, 0.0, 0.0], [0.0, 0.5, 0.5]])

    expr = np.array([[0.3, 0.5, 0.5], [0.0, 0.25, 0.25]])
    np.testing.assert_allclose(eyelid_channel(expr, Map()), [1.0, 0.5])


def test_gaze_measures():
    T = 200
    centres = np.zeros((T, 2, 3))
    centres[:, 0, 0], centres[:, 1, 0] = 0.03, -0.03
    x = np.linspace(-0.5, 0.5, T)
    target = np.stack([x, np.zeros(T), np.ones(T)], axis=1)  # walks across in front
    want = target[:, None, :] - centres
    dirs = want / np.linalg.norm(want, axis=-1, keepdims=True)
    ang = gaze_angles(centres, dirs, target)
    assert ang.max() < 1e-6
    off = dirs.copy()
    off[100:120] = [0.0, np.sin(np.radians(20)), np.cos(np.radians(20))]  # looks up for 0.8 s
    a2 = gaze_angles(centres, off, target)
    assert gaze_on_target(a2) == pytest.approx(180 / 200)
    assert aversions(a2).tolist() == [100]
    assert gaze_yaw_correlation(dirs, centres, target) == pytest.approx(1.0)
    assert gaze_on_target(a2, mask=np.arange(T) < 100) == 1.0


def test_events_with_hysteresis():
    x = np.array([0, 1.2, 0.8, 1.1, 0.3, 1.0, 1.0, 0.0])
    assert count_events(x, on=1.0).tolist() == [1, 5]


def test_nod_lags_from_the_latest_pause_and_their_histogram():
    lags = nod_lags(np.array([0.5, 2.35, 3.05, 9.0, 4.15]), np.array([4.0, 2.0, 1.0]), max_lag=2.0)
    np.testing.assert_allclose(lags, [0.35, 1.05, 0.15])  # 0.5: before any pause; 9.0: 5 s after the last
    assert nod_lags(np.zeros(0), np.array([1.0])).size == 0 and nod_lags(np.array([1.0]), np.zeros(0)).size == 0
    h = lag_histogram(lags, 0.1, 2.0)
    assert len(h) == 20 and sum(h) == 3 and h[1] == 1 and h[3] == 1 and h[10] == 1
