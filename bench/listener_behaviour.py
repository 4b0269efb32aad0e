"""Does the patient listen? Listener behaviour at default settings on real and text-to-speech speech.

Speech: the two real recordings in ``tests/data/speech/`` (librispeech, looked at while choosing the
speech-feature constants; JFK, held out of all tuning) and two text-to-speech voices the reaction
model never heard in training (``reaction.tts.HELD_OUT_VOICES``; fresh sentences, rooms and noise
from this script's own seeds), ``--tts-clips`` clips of ``--tts-seconds`` each, pooled per voice.
The speaker's face is still (a user's still video), so whatever moves comes from the audio.

Each clip goes through ``holo_viewer.pipeline.reactions.react_to_speaker`` (what ``holo-viewer
react`` runs) with the behaviour layers on (the default) and off (``behaviour=None``: the model
alone), with the default decoding and with sampling (temperature 1, top-k 20). Measures
(``holo_viewer.reaction.listening``): head motion peak to peak (max of pitch and yaw), nods per
minute and their contingency on the VAD pause onsets (share of nod onsets 0.2-1.0 s after a pause
onset against 1000 circular shifts: ratio and p), blinks per minute and durations (eyelid >= 0.8
for 100-400 ms), the share of frames with the gaze within 5 deg of the default viewer target
(``gaze_on_trainee``; the live webcam measure ``gaze_yaw_r`` is not taken here: null), smiles and
brow raises per minute.

Writes ``bench/results/listener_behaviour.json`` (``--out``), a PNG of the behaviour under the
waveform of one recording and (unless ``--no-video``) a 15-s listening clip with the speech as its
sound track. Prints the table.

    .venv/bin/python bench/listener_behaviour.py [--quick] [--no-video]
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


def pool(rows: list[dict], n_shifts: int = 1000) -> dict:
    from holo_viewer.reaction.listening import nod_contingency

    mins = sum(r["seconds"] for r in rows) / 60.0
    c = nod_contingency([r["nods"] for r in rows], [r["pauses"] for r in rows], [r["seconds"] for r in rows],
                        n_shifts=n_shifts, seed=0)
    durs = np.concatenate([r["blink_durations"] for r in rows]) if rows else np.zeros(0)
    n_frames = [r["seconds"] * 25 for r in rows]
    return {
        "minutes": mins, "clips": len(rows),
        "head_motion_deg": float(np.median([r["head_motion_deg"] for r in rows])),
        "head_motion_deg_min": float(np.min([r["head_motion_deg"] for r in rows])),
        "nods_per_min": sum(len(r["nods"]) for r in rows) / mins,
        "pauses_per_min": sum(len(r["pauses"]) for r in rows) / mins,
        "nod_contingency_share": c.share, "nod_contingency_ratio": c.ratio, "nod_contingency_p": c.p,
        "blinks_per_min": sum(len(r["blinks"]) for r in rows) / mins,
        "blink_duration_s": [float(np.min(durs)), float(np.median(durs)), float(np.max(durs))] if durs.size else None,
        "smiles_per_min": sum(len(r["smiles"]) for r in rows) / mins,
        "brow_raises_per_min": sum(len(r["brows"]) for r in rows) / mins,
        "gaze_on_trainee": float(np.average([r["gaze_on_trainee"] for r in rows], weights=n_frames)),
        "aversions_per_min": sum(len(r["aversions"]) for r in rows) / mins,
        "gaze_yaw_r": None,
    }


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


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--tts-clips", type=int, default=9, help="clips per held-out voice (default 9)")
    ap.add_argument("--tts-seconds", type=float, default=20.0, help="seconds per TTS clip (default 20)")
    ap.add_argument("--quick", action="store_true", help="2 TTS clips per voice, 200 shifts, no video")
    ap.add_argument("--no-video", action="store_true")
    ap.add_argument("--out", default=str(ROOT / "bench" / "results" / "listener_behaviour.json"))
    args = ap.parse_args(argv)
    import torch

    torch.set_num_threads(1)
    from holo_viewer.fileio import atomic_write
    from holo_viewer.reaction.audio import read_wav
    from holo_viewer.reaction.speech import speech_features

    n_tts = 2 if args.quick else args.tts_clips
    n_shifts = 200 if args.quick else 1000
    t_all = time.perf_counter()
    clips = []
    for name, group in REAL:
        wave, _ = read_wav(SPEECH / f"{name}.wav")
        clips.append((group, name, wave))
    clips += tts_clips(n_tts, args.tts_seconds)
    conditions = {"default": (True, None), "model alone": (False, None), "sampling t=1": (True, 1.0),
                  "model alone, sampling t=1": (False, 1.0)}
    per_clip, groups, first = [], {}, {}
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        for group, name, wave in clips:
            speech = speech_features(wave, 16000)
            for cond, (layers, temp) in conditions.items():
                params = react_clip(wave, tmp, layers, temp, 20)
                m = measure(params, speech)
                groups.setdefault((cond, group), []).append(m)
                per_clip.append({"condition": cond, "group": group, "clip": name, "seconds": m["seconds"],
                                 "head_motion_deg": m["head_motion_deg"], "nods": len(m["nods"]),
                                 "pauses": len(m["pauses"]), "blinks": len(m["blinks"]),
                                 "smiles": len(m["smiles"]), "brow_raises": len(m["brows"]),
                                 "gaze_on_trainee": m["gaze_on_trainee"]})
                if name == REAL[0][0] and cond == "default":
                    first = {"wave": wave, "speech": speech, "params": params, "m": m}
    results = []
    for (cond, group), rows in groups.items():
        results.append({"clip": group, "condition": cond, **pool(rows, n_shifts)})
    outdir = Path(args.out).parent
    png = outdir / "listener_behaviour.png"
    plot(png, first["wave"], first["speech"], first["params"], first["m"], "librispeech, default settings")
    from holo_viewer.reaction.api import load_default_bundle

    meta = load_default_bundle().meta
    record = {"bench": "listener_behaviour", "date": time.strftime("%Y-%m-%d"), "quick": bool(args.quick),
              "checkpoint_meta": {k: meta.get(k) for k in ("steps", "best_val_loss", "stopped", "train_minutes")},
              "targets": TARGETS, "results": results, "clips": per_clip, "plot": png.name,
              "video": None, "seconds": time.perf_counter() - t_all}

    def save() -> None:
        with atomic_write(args.out, "w") as fh:
            json.dump(record, fh, indent=1, default=float)

    save()  # the measures are kept whatever happens to the video
    video = None
    if not (args.quick or args.no_video):
        video = render_clip(outdir / "listener_behaviour_clip.mp4", first["params"], first["wave"])
        record["video"] = {"file": "listener_behaviour_clip.mp4", **video}
        record["seconds"] = time.perf_counter() - t_all
        save()
    cols = ("clip", "condition", "minutes", "head_motion_deg", "nods_per_min", "nod_contingency_ratio",
            "nod_contingency_p", "blinks_per_min", "gaze_on_trainee", "smiles_per_min", "brow_raises_per_min")
    print(" | ".join(cols))
    for r in sorted(results, key=lambda r: (r["condition"], r["clip"])):
        print(" | ".join(f"{r[c]:.3g}" if isinstance(r[c], float) else str(r[c]) for c in cols))
    print(f"wrote {args.out}, {png}" + (f", {video}" if video else "") + f" ({record['seconds']:.0f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
