"""Latency of one streaming k-frame prediction of the reaction model (batch 1, CPU).

For a synthesized 10-s speaker clip the listener is streamed window by window: each window
runs the speaker encoders on the last ``speaker_window`` frames, the decoder on the listener
past, and decodes k tokens. Reported: per-window latency (median, p90) in ms, the window's
real-time duration (k / 25 s) and the real-time factor RTF = latency / duration (< 1 is
faster than real time); the audio-feature cost per window (log-mel, or for a speech-feature model
the streaming ``SpeechTracker``: silero-vad on the new chunks, Praat on the block) is listed separately. Correctness check:
streaming window by window (a new ``generate`` call per window, past fed back) gives the same
frames as one offline call (argmax), max |difference| is reported as ``error``.

Usage: python bench/reaction_latency.py [--checkpoint CKPT] [--threads 1 2] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import platform
import time

import numpy as np
import torch

from holo_viewer.fileio import atomic_write
from holo_viewer.flame.expressions import default_au_map, jaw_for_expression
from holo_viewer.reaction.api import load_default_bundle, speaker_audio_features
from holo_viewer.reaction.audio import AudioConfig, log_mel
from holo_viewer.reaction.data import SyntheticConfig, synth_speaker
from holo_viewer.reaction.model import generate


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--checkpoint", default=None)
    ap.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--json", default=None)
    args = ap.parse_args()

    bundle = load_default_bundle(args.checkpoint)
    model, cent = bundle.model, bundle.centroids()
    cfg = model.config
    au = default_au_map()
    data_cfg = SyntheticConfig(seconds=args.seconds)
    sp = synth_speaker(np.random.default_rng(123), data_cfg, au.names,
                       np.asarray(jaw_for_expression("mouth_open", 1.0), dtype=np.float64))
    T = data_cfg.n_frames
    hop = AudioConfig().hop
    feats = speaker_audio_features(sp.waveform, 16000, T, cfg)[None]
    speech = getattr(cfg, "audio_features", "log_mel") == "speech"
    speaker = torch.from_numpy(sp.state)[None]
    pain = torch.tensor([0.5])
    k = cfg.k
    window_ms = 1000.0 * k / 25.0
    rows = []
    for th in args.threads:
        torch.set_num_threads(th)
        for label, temp, top_k in (("argmax", 0.0, None), ("sample T=1 top-20", 1.0, 20)):
            lat, mel_ms = [], []
            past = torch.zeros(1, 0, cfg.state_dim)
            frames = []
            start = cfg.speaker_window  # a full speaker window of context
            generate(model, cent, feats, speaker, pain, n_frames=k, start=start)  # warm-up
            tracker = None
            if speech:
                from holo_viewer.reaction.speech import SpeechTracker

                tracker = SpeechTracker()
                tracker.push(sp.waveform[:start * hop])
                tracker.frames()
            for t0 in range(start, T - k + 1, k):
                a = time.perf_counter()
                if tracker is not None:  # the new audio of this window through the streaming features
                    tracker.push(sp.waveform[t0 * hop:(t0 + k) * hop])
                    tracker.frames()
                else:
                    log_mel(sp.waveform[max(0, (t0 - 2) * hop):(t0 + 1) * hop], 16000)  # new audio of this window
                b = time.perf_counter()
                out = generate(model, cent, feats, speaker, pain, listener_past=past if past.shape[1] else None,
                               start=t0, n_frames=k, temperature=temp, top_k=top_k, seed=t0)
                c = time.perf_counter()
                mel_ms.append(1000 * (b - a))
                lat.append(1000 * (c - b))
                past = torch.cat([past, out], dim=1)[:, -cfg.listener_window:]
                frames.append(out)
            streamed = torch.cat(frames, dim=1)
            err = None
            if temp == 0.0:
                # same frames from one call over the clip (the past before `start` is neutral in both)
                offline = generate(model, cent, feats, speaker, pain, start=start, n_frames=streamed.shape[1])
                err = float((offline - streamed).abs().max())
            lat_a = np.array(lat)
            rows.append({"threads": th, "decoding": label, "windows": len(lat), "k": k,
                         "latency_ms_median": float(np.median(lat_a)), "latency_ms_p90": float(np.percentile(lat_a, 90)),
                         "logmel_ms_median": float(np.median(mel_ms)), "window_ms": window_ms,
                         "rtf_median": float(np.median(lat_a) / window_ms), "error_stream_vs_offline": err})
    print(f"{'threads':>7} {'decoding':<18} {'median ms':>10} {'p90 ms':>8} {'audio ms':>10} "
          f"{'window ms':>9} {'RTF':>7} {'err':>8}")
    for r in rows:
        e = "-" if r["error_stream_vs_offline"] is None else f"{r['error_stream_vs_offline']:.1e}"
        print(f"{r['threads']:>7} {r['decoding']:<18} {r['latency_ms_median']:>10.2f} {r['latency_ms_p90']:>8.2f} "
              f"{r['logmel_ms_median']:>10.2f} {r['window_ms']:>9.0f} {r['rtf_median']:>7.4f} {e:>8}")
    if args.json:
        out = {"config": {"model": cfg.to_dict(), "seconds": args.seconds, "batch": 1, "torch": torch.__version__,
                          "machine": platform.processor() or platform.machine(),
                          "baseline": "real time: the window's duration k/25 s (ratio = RTF)"},
               "results": rows}
        with atomic_write(args.json, "w") as fh:
            json.dump(out, fh, indent=2)
        print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
