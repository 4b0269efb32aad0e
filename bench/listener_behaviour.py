"""Does the patient listen? Listener behaviour at default settings on real and text-to-speech speech.

Speech: the two real recordings in ``tests/data/speech/`` (librispeech, looked at while choosing the
speech-feature constants; JFK, held out of all tuning) and two text-to-speech voices the reaction
model never heard in training (``reaction.tts.HELD_OUT_VOICES``; fresh sentences, rooms and noise
from this script's own seeds), ``--tts-clips`` clips of ``--tts-seconds`` each, pooled per voice.
The speaker's face is still (a user's still video), so whatever moves comes from the audio.

Each clip goes through ``holo_viewer.pipeline.reactions.react_to_speaker`` (what ``holo-viewer
react`` runs) with the behaviour layers on (the default) and off (``behaviour=None``: the model
alone), with the default decoding and with sampling (temperature 1, top-k 20). The listener is
stochastic, and one 11-14 s recording holds only 3-6 pause onsets and a nod or two, so each real
recording is reacted to by ``--seeds`` seeded listeners (decoding and layers seeded 0..N-1); their
nods are pooled in the contingency test with ONE circular shift per recording and shift, applied to
every realisation alike (``listening.nod_contingency(groups=...)``: the null keeps what the
realisations share, since they hear the same audio), and the per-seed spread is reported. Beside
it per recording: the p with each realisation shifted on its own (the null of a listener deaf to the
audio), the p 20 ideal listeners nodding after every pause would get (``ideal_contingency_p``: the
floor the recording's pauses allow), and both recordings pooled in one test. The TTS
voices (3 min each) use seed 0. Measures
(``holo_viewer.reaction.listening``): head motion peak to peak (max of pitch and yaw), nods per
minute and their contingency on the VAD pause onsets (share of nod onsets 0.2-1.0 s after a pause
onset against 1000 circular shifts: ratio and p), blinks per minute and durations (eyelid >= 0.8
for 100-400 ms), the share of frames with the gaze within 5 deg of the default viewer target
(``gaze_on_trainee``), smiles and brow raises per minute.

Live (unless ``--quick`` / ``--no-live``; ``--live-only`` merges it into an existing JSON): a
``LiveSession`` with the hologram renderer on a webcam replay of a trainee (the default head) who
walks across the cone (15 sin(2 pi t / 12.5 s) deg at 0.6 m) speaking 25 s of the two recordings:
``gaze_on_trainee`` (gaze within 5 deg of the trainee's true eye midpoint), aversions per minute,
``gaze_yaw_r`` (gaze yaw against the trainee's direction), and the speech pause -> backchannel
latency, in the recorded listener and as the first visible change (``live_latency.backchannel_latency``).

Writes ``bench/results/listener_behaviour.json`` (``--out``), a PNG of the behaviour under the
waveform and (unless ``--no-video``) a 15-s listening clip with the speech as its sound track: the
two real recordings back to back (librispeech, 0.5 s of silence, JFK), cut at 15 s, seed 0,
default settings. Prints the table.

    .venv/bin/python bench/listener_behaviour.py [--quick] [--no-video] [--no-live | --live-only] [--seeds 20]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

SPEECH = ROOT / "tests" / "data" / "speech"
REAL = (("librispeech_198-209-0000", "real: librispeech (tuned on)"), ("jfk_inaugural_1961", "real: JFK (held out)"))
TARGETS = {"head_motion_deg": 2.0, "nods_per_min": 3.0, "nod_contingency_ratio": 1.5, "nod_contingency_p": 0.05,
           "smiles_brows_per_min": 1.0, "blinks_per_min": (10.0, 25.0), "model_alone_head_motion_deg": 1.0}


CLIP_SECONDS = 15.0
#: condition -> (behaviour layers on, temperature; None = the default decoding)
CONDITIONS = {"default": (True, None), "model alone": (False, None), "sampling t=1": (True, 1.0),
              "model alone, sampling t=1": (False, 1.0)}
METHOD = ("nod onsets 0.2-1.0 s after a VAD pause onset (>= 200 ms silence after >= 700 ms speech), share "
          "against 1000 circular shifts of the nod times; a real recording is reacted to by N seeded "
          "listeners (seeds 0..N-1: decoding and behaviour layers), pooled, and each shift moves the nod "
          "times of all N realisations of one recording by the SAME offset (uniform over the recording's "
          "length); TTS clips: one realisation each, each clip its own offset; p = (1 + #{shifted share >= "
          "observed}) / (1 + shifts), ratio = observed / mean shifted share")


def tts_clips(n: int, seconds: float):
    """(group, name, waveform) of the held-out voices; seeds of this bench only (never training's)."""
    from holo_viewer.reaction.tts import HELD_OUT_VOICES, tts_clip

    out = []
    for v, voice in enumerate(HELD_OUT_VOICES):
        for i in range(n):
            rng = np.random.default_rng(np.random.SeedSequence([36, 1000 + v, i]))
            wave, _ = tts_clip(rng, seconds, voices=(voice,), augment=True)
            out.append((f"tts: {voice} (held out)", f"{voice}_{i}", wave))
    return out


def react_clip(wave: np.ndarray, tmp: Path, behaviour, temperature: float, top_k, seed: int = 0):
    from holo_viewer.fileio import save_npz
    from holo_viewer.flame.expressions import default_au_map
    from holo_viewer.pipeline.reactions import DEFAULT_BEHAVIOUR, react_to_speaker
    from holo_viewer.reaction.audio import write_wav

    T = wave.shape[0] // 640
    wav, npz = tmp / "speaker.wav", tmp / "speaker.npz"
    write_wav(wav, wave[:T * 640], 16000)
    n_expr = default_au_map().matrix.shape[1]
    save_npz(npz, expr=np.zeros((T, n_expr), np.float32), jaw_pose=np.zeros((T, 3), np.float32),
             rotation=np.zeros((T, 3), np.float32))
    kw = {} if temperature is None else {"temperature": temperature, "top_k": top_k}
    params, _ = react_to_speaker(wav, npz, behaviour=DEFAULT_BEHAVIOUR if behaviour else None, seed=seed, **kw)
    return params


def measure(params: dict, speech: np.ndarray) -> dict:
    """Per-clip events and measures (times in seconds)."""
    from holo_viewer.behaviour import default_target, eye_directions
    from holo_viewer.flame.expressions import default_au_map, estimate_aus
    from holo_viewer.reaction import listening as L
    from holo_viewer.reaction.speech import pause_onsets

    au = default_au_map()
    T = params["expr"].shape[0]
    secs = T / 25.0
    neck = params.get("neck_pose")
    angles = L.head_angles_deg(params["rotation"], neck)
    motion = L.head_motion_deg(params["rotation"], neck)
    nods = L.detect_nods(angles[:, 0]) / 25.0
    pauses = pause_onsets(speech[:T, 0], speech[:T, 1]) / 25.0
    b_on, b_dur = L.detect_blinks(L.eyelid_channel(params["expr"], au))
    aus = np.asarray(estimate_aus(np.asarray(params["expr"], np.float64), au), np.float64)
    names = list(au.names)
    smiles = L.count_events(aus[:, names.index("AU12")], on=1.0)
    brows = L.count_events(0.5 * (aus[:, names.index("AU1")] + aus[:, names.index("AU2")]), on=1.0)
    centres, dirs = eye_directions(params["rotation"], neck if neck is not None else np.zeros((T, 3)),
                                   params.get("eyes_pose", np.zeros((T, 6))), params.get("translation"))
    gaze = L.gaze_angles(centres, dirs, default_target())
    return {"seconds": secs, "head_motion_deg": motion["max"], "head_pitch_ptp_deg": motion["pitch"],
            "head_yaw_ptp_deg": motion["yaw"], "nods": nods, "pauses": pauses, "blinks": b_on / 25.0,
            "blink_durations": b_dur, "smiles": smiles / 25.0, "brows": brows / 25.0,
            "gaze_on_trainee": L.gaze_on_target(gaze), "aversions": L.aversions(gaze) / 25.0,
            "max_au12": float(aus[:, names.index("AU12")].max())}


def pool(rows: list[dict], n_shifts: int = 1000, groups: list | None = None) -> dict:
    """Pooled measures of clips; ``groups``: one label per row, rows of one label (seeded realisations
    of one recording) share each circular shift of the contingency test."""
    from holo_viewer.reaction.listening import lag_histogram, nod_contingency, nod_lags

    mins = sum(r["seconds"] for r in rows) / 60.0
    c = nod_contingency([r["nods"] for r in rows], [r["pauses"] for r in rows], [r["seconds"] for r in rows],
                        n_shifts=n_shifts, seed=0, groups=groups)
    lags = np.concatenate([nod_lags(r["nods"], r["pauses"], 2.0) for r in rows]) if rows else np.zeros(0)
    durs = np.concatenate([r["blink_durations"] for r in rows]) if rows else np.zeros(0)
    # nod onsets per pause onset: in [pause, the next pause or pause + 2 s): 0, 1, 2 or more
    per_pause = [int(((r["nods"] >= q) & (r["nods"] < min(q + 2.0, r["pauses"][i + 1] if i + 1 < len(r["pauses"])
                                                          else np.inf))).sum())
                 for r in rows for i, q in enumerate(r["pauses"])]
    per_pause = np.asarray(per_pause, np.int64)
    n_frames = [r["seconds"] * 25 for r in rows]
    return {
        "minutes": mins, "clips": len(rows),
        "head_motion_deg": float(np.median([r["head_motion_deg"] for r in rows])),
        "head_motion_deg_min": float(np.min([r["head_motion_deg"] for r in rows])),
        "nods_per_min": sum(len(r["nods"]) for r in rows) / mins,
        "pauses_per_min": sum(len(r["pauses"]) for r in rows) / mins,
        "nod_contingency_share": c.share, "nod_contingency_ratio": c.ratio, "nod_contingency_p": c.p,
        # nod onset - the latest pause onset before it (nods within 2 s of one), 0.1-s bins 0..2 s
        "nod_lag_hist_0.1s": lag_histogram(lags, 0.1, 2.0),
        "pauses_by_nod_onsets_0_1_2plus": [int((per_pause == 0).sum()), int((per_pause == 1).sum()),
                                            int((per_pause >= 2).sum())],
        "nod_lag_s_quartiles": [float(x) for x in np.percentile(lags, [25, 50, 75])] if lags.size else None,
        "blinks_per_min": sum(len(r["blinks"]) for r in rows) / mins,
        "blink_duration_s": [float(np.min(durs)), float(np.median(durs)), float(np.max(durs))] if durs.size else None,
        "smiles_per_min": sum(len(r["smiles"]) for r in rows) / mins,
        "brow_raises_per_min": sum(len(r["brows"]) for r in rows) / mins,
        "smiles_brows_per_min": sum(len(r["smiles"]) + len(r["brows"]) for r in rows) / mins,
        "gaze_on_trainee": float(np.average([r["gaze_on_trainee"] for r in rows], weights=n_frames)),
        "aversions_per_min": sum(len(r["aversions"]) for r in rows) / mins,
        "gaze_yaw_r": None,
    }


def per_seed(rows: list[dict], n_shifts: int) -> dict:
    """The spread over seeded realisations of one recording: each seed's own test."""
    from holo_viewer.reaction.listening import nod_contingency

    nods, ratio, p = [], [], []
    for r in rows:
        c = nod_contingency([r["nods"]], [r["pauses"]], [r["seconds"]], n_shifts=n_shifts, seed=0)
        nods.append(60.0 * len(r["nods"]) / r["seconds"])
        ratio.append(c.ratio)
        p.append(c.p)

    def spread(x):
        x = np.asarray(x, np.float64)
        x = x[np.isfinite(x)]
        return [float(x.min()), float(np.median(x)), float(x.max())] if x.size else None

    return {"seeds": len(rows), "nods_per_min_min_median_max": spread(nods),
            "nod_contingency_ratio_min_median_max": spread(ratio), "nod_contingency_p_min_median_max": spread(p),
            "seeds_without_nods": int(sum(len(r["nods"]) == 0 for r in rows)),
            "seeds_p_below_0.05": int(sum(x < 0.05 for x in p)),
            "head_motion_deg_min_median_max": spread([r["head_motion_deg"] for r in rows])}


def plot(path: Path, wave: np.ndarray, speech: np.ndarray, params: dict, m: dict, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from holo_viewer.behaviour import default_target, eye_directions
    from holo_viewer.flame.expressions import default_au_map, estimate_aus
    from holo_viewer.reaction import listening as L

    au = default_au_map()
    T = params["expr"].shape[0]
    t = np.arange(T) / 25.0
    names = list(au.names)
    aus = np.asarray(estimate_aus(np.asarray(params["expr"], np.float64), au))
    ang = L.head_angles_deg(params["rotation"], params.get("neck_pose"))
    centres, dirs = eye_directions(params["rotation"], params["neck_pose"], params["eyes_pose"], params.get("translation"))
    gaze = L.gaze_angles(centres, dirs, default_target())
    fig, ax = plt.subplots(6, 1, figsize=(12, 10), sharex=True)
    ts = np.arange(wave.shape[0]) / 16000.0
    ax[0].plot(ts, wave, lw=0.3, color="0.3")
    ax[0].plot(t, speech[:T, 0] * np.abs(wave).max(), color="tab:green", lw=1, label="VAD")
    for p in m["pauses"]:
        for a in ax:
            a.axvspan(p + 0.2, p + 1.0, color="tab:orange", alpha=0.12, lw=0)
        ax[0].axvline(p, color="tab:orange", lw=1.5)
    ax[0].set_ylabel("speech")
    ax[0].legend(loc="upper right", fontsize=7)
    ax[1].plot(t, ang[:, 0], label="pitch (+ = down)")
    ax[1].plot(t, ang[:, 1], label="yaw", alpha=0.6)
    for n in m["nods"]:
        ax[1].axvline(n, color="tab:red", lw=1)
    ax[1].set_ylabel("head, deg")
    ax[1].legend(loc="upper right", fontsize=7)
    ax[2].plot(t, L.eyelid_channel(params["expr"], au), color="tab:purple")
    ax[2].axhline(0.8, color="0.6", lw=0.5)
    ax[2].set_ylabel("eyelid (AU43)")
    ax[3].plot(t, gaze, color="tab:blue")
    ax[3].axhline(5.0, color="0.6", lw=0.5)
    ax[3].set_ylabel("gaze off\ntarget, deg")
    ax[4].plot(t, aus[:, names.index("AU12")], label="AU12 smile")
    ax[4].plot(t, 0.5 * (aus[:, names.index("AU1")] + aus[:, names.index("AU2")]), label="AU1+2 brows")
    ax[4].axhline(1.0, color="0.6", lw=0.5)
    ax[4].set_ylabel("AU (0-5)")
    ax[4].legend(loc="upper right", fontsize=7)
    ax[5].plot(t, params.get("pain_shown", np.zeros(T)), color="tab:red")
    ax[5].set_ylabel("pain shown")
    ax[5].set_xlabel("s")
    ax[0].set_title(f"{title}: pause onsets (orange lines; shaded 0.2-1.0 s after), nod onsets (red lines)")
    fig.tight_layout()
    from holo_viewer.fileio import atomic_path

    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=80, format="png")
    plt.close(fig)


def render_clip(path: Path, params: dict, wave: np.ndarray, seconds: float = 15.0) -> dict:
    """An mp4 of the listener's head (frontal webcam-like camera), the speech as its sound track."""
    import imageio_ffmpeg

    from holo_viewer.fileio import atomic_path
    from holo_viewer.pipeline.live_support import HeadRenderer, webcam_camera
    from holo_viewer.reaction.audio import write_wav

    T = min(params["expr"].shape[0], int(seconds * 25))
    keys = ("expr", "jaw_pose", "rotation", "neck_pose", "eyes_pose", "translation")
    r = HeadRenderer(n_gaussians=40_000)
    cam = webcam_camera(360, 480, 40.0, 0.55)
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as d:
        wav = Path(d) / "a.wav"
        write_wav(wav, wave[:T * 640], 16000)
        with atomic_path(path) as tmp:
            w = imageio_ffmpeg.write_frames(os.fspath(tmp), (360, 480), fps=25, codec="libx264", quality=8,
                                            macro_block_size=8, audio_path=str(wav), audio_codec="aac",
                                            output_params=["-shortest"], ffmpeg_log_level="error")
            w.send(None)
            for i in range(T):
                w.send(np.ascontiguousarray(r.render({k: params[k][i] for k in keys if k in params}, cam)))
            w.close()
    return {"frames": T, "seconds": T / 25.0, "render_s": time.perf_counter() - t0}


LIVE_SECONDS = 25.0
#: the trainee walks across the cone: angle 15 sin(2 pi t / 12.5) deg at 0.6 m, eyes at the panel centre's height
TRAINEE_AMP_DEG, TRAINEE_PERIOD_S, TRAINEE_DISTANCE_M = 15.0, 12.5, 0.6
WEBCAM_HEIGHT_M = 0.13  # WebcamMount's default position_m[1]


def trainee_angle(t: np.ndarray) -> np.ndarray:
    return TRAINEE_AMP_DEG * np.sin(2 * np.pi * np.asarray(t, np.float64) / TRAINEE_PERIOD_S)


def write_trainee_clip(out: Path, wave: np.ndarray, n_gaussians: int = 20_000) -> dict:
    """speaker.wav + speaker.mp4: the default head as a trainee walking across the webcam's view
    (facing the webcam), rendered where a webcam at the default mount (0.13 m above the panel centre,
    60 deg, looking straight out) sees eyes at ``trainee_angle(t)``, 0.6 m from the panel centre, at
    its height. Cached by the wave's length and this function's constants."""
    from holo_viewer.behaviour import DEFAULT_JOINTS
    from holo_viewer.media import VideoWriter
    from holo_viewer.pipeline.live_support import HeadRenderer, webcam_camera
    from holo_viewer.reaction.audio import write_wav

    files = {"wav": out / "speaker.wav", "video": out / "speaker.mp4"}
    if all(f.exists() for f in files.values()):
        return files
    out.mkdir(parents=True, exist_ok=True)
    T = wave.shape[0] // 640
    write_wav(files["wav"], wave[:T * 640], 16000)
    J0, eye = DEFAULT_JOINTS[0], 0.5 * (DEFAULT_JOINTS[3] + DEFAULT_JOINTS[4])
    d = TRAINEE_DISTANCE_M
    # render world = panel frame mirrored in x and shifted: the camera looks along -z from C
    C = np.array([0.0, WEBCAM_HEIGHT_M, eye[2] + d])
    cam = webcam_camera(480, 360, 60.0, distance=1.0, target=C - np.array([0.0, 0.0, 1.0]))
    r = HeadRenderer(n_gaussians=n_gaussians)
    with VideoWriter(files["video"], 25, content="preview", quality=8, what="trainee video") as w:
        for i in range(T):
            a = np.radians(trainee_angle(i / 25.0))
            M = np.array([-d * np.sin(a), 0.0, eye[2] + d * (1.0 - np.cos(a))])  # eye midpoint, render world
            Ry = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
            tr = M - (Ry @ (eye - J0) + J0)
            w.write(r.render({"rotation": np.array([0.0, a, 0.0]), "translation": tr}, cam))
    return files


def live_listening(wave: np.ndarray, out: Path, cache: Path, render: bool = True, tile_scale: float = 0.5,
                   track_fps: float | None = None) -> dict:
    """``live`` on a webcam replay of a walking trainee speaking ``wave``: gaze on the trainee's true
    eye midpoint (within 5 deg), aversions, gaze-yaw correlation with the trainee's angle, and the
    speech pause -> visible backchannel latency (bench/live_latency.py's visible-change timing)."""
    from holo_viewer.behaviour import eye_directions, viewer_target
    from holo_viewer.flame.expressions import default_au_map, estimate_aus
    from holo_viewer.live import sources
    from holo_viewer.live.loop import LiveSession, LiveSessionConfig
    from holo_viewer.live.render import LiveAvatarRenderer
    from holo_viewer.reaction import listening as L
    from holo_viewer.reaction.speech import pause_onsets, speech_features

    sys.path.insert(0, str(ROOT / "bench"))
    from live_latency import FrameTimes, backchannel_latency

    t_clip = time.perf_counter()
    files = write_trainee_clip(cache, wave)
    t_clip = time.perf_counter() - t_clip
    load0 = os.getloadavg()
    cfg = LiveSessionConfig(out=str(out), tile_scale=tile_scale, write_native_video=False, flush_s=60.0,
                            track_fps=track_fps)
    session = LiveSession(cfg, sources.WavReplay(files["wav"]), sources.VideoReplay(files["video"]))
    renderer = LiveAvatarRenderer(tile_scale=tile_scale) if render else None
    shown = FrameTimes()  # each displayed frame's visible change, in the order shown
    t0, c0 = time.perf_counter(), time.process_time()
    session.run(renderer, on_frame=shown)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    with np.load(out / "tracks.npz") as z:
        tr = {k: z[k] for k in z.files}
    T = tr["time_s"].shape[0]
    t = tr["time_s"]
    true_a = trainee_angle(t)
    target = np.stack([viewer_target(a, TRAINEE_DISTANCE_M) for a in true_a])
    tracked = np.stack([viewer_target(a, dd) for a, dd in zip(tr["viewer_angle_deg"], tr["viewer_distance_m"])])
    lp = {k: tr[f"listener_{k}"] for k in ("expr", "rotation", "neck_pose", "eyes_pose", "translation")}
    centres, dirs = eye_directions(lp["rotation"], lp["neck_pose"], lp["eyes_pose"], lp["translation"])
    skip = 25  # the first second: the tracker finds the face
    gaze = L.gaze_angles(centres, dirs, target)[skip:]
    gaze_tracked = L.gaze_angles(centres, dirs, tracked)[skip:]
    minutes = (T - skip) / 25.0 / 60.0
    # backchannels in the recorded listener and the pauses of the speech it heard
    au = default_au_map()
    names = list(au.names)
    aus = np.asarray(estimate_aus(np.asarray(lp["expr"], np.float64), au))
    nods = L.detect_nods(L.head_angles_deg(lp["rotation"], lp["neck_pose"])[:, 0])
    brows = L.count_events(0.5 * (aus[:, names.index("AU1")] + aus[:, names.index("AU2")]), on=1.0)
    smiles = L.count_events(aus[:, names.index("AU12")], on=1.0)
    f = speech_features(wave[:T * 640], 16000)
    pauses = [int(p) for p in pause_onsets(f[:, 0], f[:, 1])]
    backs = sorted(set(int(x) for x in np.concatenate([nods, brows, smiles])))
    react_lat = []
    for p in pauses:
        later = [b for b in backs if p <= b <= p + 50]
        react_lat.append((later[0] - p) / 25.0 if later else None)
    row = {"clip": f"live: webcam replay, trainee walking +-{TRAINEE_AMP_DEG:g} deg", "condition": "default",
           "minutes": minutes, "gaze_on_trainee": L.gaze_on_target(gaze),
           "gaze_on_tracked_target": L.gaze_on_target(gaze_tracked),
           "aversions_per_min": len(L.aversions(gaze)) / minutes,
           "gaze_yaw_r": L.gaze_yaw_correlation(dirs[skip:], centres[skip:], target[skip:]),
           "tracked_angle_error_deg_median": float(np.median(np.abs(tr["viewer_angle_deg"] - true_a)[skip:])),
           "nods_per_min": len(nods) / minutes, "brow_raises_per_min": len(brows) / minutes,
           "smiles_per_min": len(smiles) / minutes, "pauses": len(pauses)}
    if render:
        vis = backchannel_latency(tr, pauses, backs, shown.change)
        got = [v for v in vis if v is not None]
        row.update({"backchannel_latency_s_median": float(np.median(got)) if got else None,
                    "backchannel_latency_s": vis, "pauses_answered_visibly": len(got),
                    "displayed_fps": len(set(tr["display_frame"].tolist())) / (T / 25.0)})
    got_r = [v for v in react_lat if v is not None]
    row.update({"pause_to_backchannel_onset_s": react_lat,
                "pause_to_backchannel_onset_s_median": float(np.median(got_r)) if got_r else None,
                "session_wall_s": wall, "session_cpu_s": cpu, "track_fps": track_fps,
                "tracked_frames": len(session.tracker_ms), "tracker_ms_median": float(np.median(session.tracker_ms))
                if session.tracker_ms else None, "tracker_cpu_s": float(np.sum(session.tracker_cpu_ms)) / 1000.0,
                "trainee_clip_render_s": t_clip, "load_average_start": load0,
                "load_average_end": os.getloadavg(), "late_reaction_windows": session.late_windows,
                "tile_scale": tile_scale if render else None})
    return row


def real_pair() -> np.ndarray:
    """The two real recordings back to back with 0.5 s of silence between (the clip's and live's speech)."""
    from holo_viewer.reaction.audio import read_wav

    waves = [read_wav(SPEECH / f"{name}.wav")[0] for name, _ in REAL]
    return np.concatenate([waves[0], np.zeros(8000, np.float32), waves[1]]).astype(np.float32)


def run_live(args, pair: np.ndarray) -> dict:
    wave = pair[:int(LIVE_SECONDS * 16000)]
    with tempfile.TemporaryDirectory() as d:
        return live_listening(wave, Path(d) / "session", Path(args.cache) / f"trainee_{LIVE_SECONDS:g}s",
                              render=not args.no_live_render, tile_scale=args.tile_scale, track_fps=args.track_fps)


def print_live(row: dict) -> None:
    print(f"live ({row['minutes'] * 60:.0f} s, load {row['load_average_start'][0]:.1f}): gaze on trainee "
          f"{row['gaze_on_trainee']:.2f} (on the tracked target {row['gaze_on_tracked_target']:.2f}), aversions "
          f"{row['aversions_per_min']:.1f}/min, gaze_yaw_r {row['gaze_yaw_r']:.3f}, tracker error "
          f"{row['tracked_angle_error_deg_median']:.1f} deg; pause -> backchannel onset "
          f"{row['pause_to_backchannel_onset_s_median']} s, visible {row.get('backchannel_latency_s_median')} s "
          f"({row.get('pauses_answered_visibly')} of {row['pauses']} pauses), late windows {row['late_reaction_windows']}")
    if "tracked_frames" in row:
        print(f"  tracker: {row['tracked_frames']} frames tracked (track_fps {row['track_fps']}), "
              f"{row['tracker_cpu_s']:.2f} s of its thread's CPU, session CPU {row['session_cpu_s']:.1f} s")


def run_live_only(args) -> int:
    from holo_viewer.fileio import atomic_write

    row = run_live(args, real_pair())
    path = Path(args.out)
    record = json.loads(path.read_text()) if path.exists() else {"bench": "listener_behaviour", "results": []}
    record["results"] = [r for r in record.get("results", []) if not str(r.get("clip", "")).startswith("live:")]
    record["results"].append(row)
    record["live"] = row
    with atomic_write(path, "w") as fh:
        json.dump(record, fh, indent=1, default=float)
    print_live(row)
    print(f"wrote {path} (live only)")
    return 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--tts-clips", type=int, default=9, help="clips per held-out voice (default 9)")
    ap.add_argument("--tts-seconds", type=float, default=20.0, help="seconds per TTS clip (default 20)")
    ap.add_argument("--seeds", type=int, default=20, help="seeded listeners per real recording (default 20)")
    ap.add_argument("--quick", action="store_true", help="2 TTS clips per voice, 4 seeds, 200 shifts, no video")
    ap.add_argument("--no-video", action="store_true")
    ap.add_argument("--no-live", action="store_true", help="skip the live webcam-replay session")
    ap.add_argument("--live-only", action="store_true",
                    help="only the live session, merged into the existing --out JSON")
    ap.add_argument("--no-live-render", action="store_true",
                    help="live without the hologram renderer (gaze only, no visible backchannel latency)")
    ap.add_argument("--tile-scale", type=float, default=0.5, help="live renderer tile scale (default 0.5)")
    ap.add_argument("--track-fps", type=float, default=None,
                    help="live: track at most this many webcam frames a second (default: every frame)")
    ap.add_argument("--cache", default=os.path.join(tempfile.gettempdir(), "holo_viewer_listener_bench"),
                    help="where the trainee webcam clip is cached")
    ap.add_argument("--condition", action="append", default=None, choices=list(CONDITIONS),
                    help="run this condition (repeatable; default all four)")
    ap.add_argument("--recordings", default="librispeech,jfk,tts",
                    help="comma-separated subset of librispeech, jfk, tts (default all; JFK is held out)")
    ap.add_argument("--out", default=str(ROOT / "bench" / "results" / "listener_behaviour.json"))
    args = ap.parse_args(argv)
    import torch

    torch.set_num_threads(1)
    from holo_viewer.fileio import atomic_write
    from holo_viewer.reaction.audio import read_wav
    from holo_viewer.reaction.speech import speech_features

    if args.live_only:
        return run_live_only(args)
    n_tts = 2 if args.quick else args.tts_clips
    n_shifts = 200 if args.quick else 1000
    n_seeds = min(args.seeds, 4) if args.quick else args.seeds
    t_all, c_all, load0 = time.perf_counter(), time.process_time(), os.getloadavg()
    want = {x.strip() for x in args.recordings.split(",") if x.strip()}
    bad = want - {"librispeech", "jfk", "tts"}
    if bad:
        ap.error(f"--recordings: expected librispeech, jfk, tts; found {sorted(bad)}")
    clips = []
    for name, group in REAL:
        if name.split("_")[0] in want:
            wave, _ = read_wav(SPEECH / f"{name}.wav")
            clips.append((group, name, wave, range(n_seeds)))
    if "tts" in want:
        clips += [(g, n, w, range(1)) for g, n, w in tts_clips(n_tts, args.tts_seconds)]
    conditions = {k: CONDITIONS[k] for k in (args.condition or CONDITIONS)}
    per_clip, groups, labels = [], {}, {}
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        for group, name, wave, seeds in clips:
            speech = speech_features(wave, 16000)
            for cond, (layers, temp) in conditions.items():
                for seed in seeds:
                    params = react_clip(wave, tmp, layers, temp, 20, seed=seed)
                    m = measure(params, speech)
                    groups.setdefault((cond, group), []).append(m)
                    labels.setdefault((cond, group), []).append(name)
                    per_clip.append({"condition": cond, "group": group, "clip": name, "seed": seed,
                                     "seconds": m["seconds"], "head_motion_deg": m["head_motion_deg"],
                                     "nods": len(m["nods"]), "pauses": len(m["pauses"]), "blinks": len(m["blinks"]),
                                     "smiles": len(m["smiles"]), "brow_raises": len(m["brows"]),
                                     "gaze_on_trainee": m["gaze_on_trainee"]})
        # the listening clip: both recordings back to back, 15 s, seed 0, default settings
        pair = real_pair()
        both = pair[:int(CLIP_SECONDS * 16000)]
        both_speech = speech_features(both, 16000)
        both_params = react_clip(both, tmp, True, None, 20, seed=0)
        both_m = measure(both_params, both_speech)
    results = []
    real_names = {g for _, g in REAL}
    for (cond, group), rows in groups.items():
        row = {"clip": group, "condition": cond, **pool(rows, n_shifts, labels[(cond, group)])}
        if group in real_names:
            row["per_seed"] = per_seed(rows, n_shifts)
            row["nod_contingency_p_independent_shifts"] = pool(rows, n_shifts)["nod_contingency_p"]  # not the test
            # the test's floor on this recording: 20 ideal listeners nodding after every pause (lags
            # uniform in 0.2-1.0 s, or bunched in 0.4-0.8 s), pooled as above
            from holo_viewer.reaction.listening import ideal_contingency_p

            q, d = rows[0]["pauses"], rows[0]["seconds"]
            row["nod_contingency_p_ideal_listener"] = ideal_contingency_p(q, d, len(rows), n_shifts=n_shifts)
            row["nod_contingency_p_ideal_listener_bunched"] = ideal_contingency_p(q, d, len(rows), lag=(0.4, 0.8),
                                                                                  n_shifts=n_shifts)
        results.append(row)
    # both real recordings in one test (independent recordings: each its own shift; the seeded
    # listeners of one recording share theirs): how the two recordings' evidence pools
    for cond in conditions:
        if not all((cond, g) in groups for _, g in REAL):
            continue
        rows = [r for _, g in REAL for r in groups[(cond, g)]]
        labs = [g for _, g in REAL for _ in groups[(cond, g)]]
        results.append({"clip": "real: both recordings pooled", "condition": cond,
                        **pool(rows, n_shifts, labs)})
    outdir = Path(args.out).parent
    png = outdir / "listener_behaviour.png"
    plot(png, both, both_speech, both_params, both_m,
         "librispeech + 0.5 s + JFK (the 15-s clip), seed 0, default settings")
    from holo_viewer.reaction.api import load_default_bundle
    from holo_viewer.reaction.decoding import listening_stride

    meta = load_default_bundle().meta
    record = {"bench": "listener_behaviour", "date": time.strftime("%Y-%m-%d"), "quick": bool(args.quick),
              "checkpoint_meta": {k: meta.get(k) for k in ("steps", "best_val_loss", "stopped", "train_minutes")},
              "config": {"seeds_per_real_recording": n_seeds, "tts_clips_per_voice": n_tts,
                         "tts_seconds": args.tts_seconds, "n_shifts": n_shifts, "speaker_face": "still",
                         "held_out": "JFK recording and both TTS voices: never looked at while tuning",
                         "contingency_method": METHOD, "conditions": list(conditions),
                         "recordings": sorted(want), "model_stride_frames": listening_stride(load_default_bundle().model.config.k)},
              "targets": TARGETS, "results": results, "clips": per_clip, "plot": png.name,
              "clip": {"audio": "librispeech_198-209-0000 + 0.5 s silence + jfk_inaugural_1961, cut",
                       "seconds": both_m["seconds"], "nods": len(both_m["nods"]), "pauses": len(both_m["pauses"]),
                       "blinks": len(both_m["blinks"]), "smiles": len(both_m["smiles"]),
                       "brow_raises": len(both_m["brows"]), "head_motion_deg": both_m["head_motion_deg"],
                       "video": None},
              "video": None, "load_average_start": load0, "seconds": time.perf_counter() - t_all}

    def save() -> None:
        with atomic_write(args.out, "w") as fh:
            json.dump(record, fh, indent=1, default=float)

    save()  # the measures are kept whatever happens to the video
    video = None
    if not (args.quick or args.no_video):
        video = render_clip(outdir / "listener_behaviour_clip.mp4", both_params, both, seconds=CLIP_SECONDS)
        record["video"] = record["clip"]["video"] = {"file": "listener_behaviour_clip.mp4", **video}
    if not (args.quick or args.no_live):
        record["live"] = run_live(args, pair)
        results.append(record["live"])
    record["seconds"] = time.perf_counter() - t_all
    record["cpu_seconds"] = time.process_time() - c_all
    record["load_average_end"] = os.getloadavg()
    save()
    cols = ("clip", "condition", "minutes", "head_motion_deg", "nods_per_min", "nod_contingency_ratio",
            "nod_contingency_p", "blinks_per_min", "gaze_on_trainee", "smiles_per_min", "brow_raises_per_min",
            "aversions_per_min")
    print(" | ".join(cols))
    for r in sorted(results, key=lambda r: (r["condition"], r["clip"])):
        print(" | ".join(f"{r.get(c):.3g}" if isinstance(r.get(c), float) else str(r.get(c)) for c in cols))
    if "live" in record:
        print_live(record["live"])
    print(f"wrote {args.out}, {png}" + (f", {video}" if video else "") + f" ({record['seconds']:.0f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
