"""Build assets/default_head_landmarks.npz: the 68 dlib landmarks embedded on the default head.

The default head comes from ICT Face Model Light, whose ``landmarks68`` (vertex indices in dlib's
68-point order, Multi-PIE convention) the head builder stores as ``landmark_vertices``. Each landmark
is that vertex, written as a triangle of the head containing it (the lowest-numbered one) with a one-hot
barycentric weight. Fit weights: the jaw contour (0-16) depends on the silhouette, so it gets 0 except
the chin (6-10: 0.5); the inner points 17-67 get 1. Deterministic; no detector or render needed.
Usage: python scripts/build_landmark_embedding.py [--head PATH] [--out PATH]
"""

from __future__ import annotations

import argparse

import numpy as np


def embedding_from_head(landmark_vertices: np.ndarray, faces: np.ndarray):
    """LandmarkEmbedding placing landmark i on vertex ``landmark_vertices[i]``."""
    from holo_viewer.tracking.head_model import LandmarkEmbedding

    f = np.asarray(faces, dtype=np.int64)
    tri = np.empty(68, np.int64)
    bary = np.zeros((68, 3))
    for i, vid in enumerate(np.asarray(landmark_vertices, dtype=np.int64)):
        hit = np.argwhere(f == vid)
        if not len(hit):
            raise SystemExit(f"landmark {i}: vertex {vid} is in no triangle of the head")
        tri[i], corner = hit[0]
        bary[i, corner] = 1.0
    w = np.ones(68)
    w[:17] = 0.0
    w[6:11] = 0.5
    return LandmarkEmbedding(tri, bary, w)


def main() -> int:
    from holo_viewer.flame.default_head import default_head_path
    from holo_viewer.tracking.head_model import default_embedding_path

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--head", default=None, help="default head .npz (default: the committed asset)")
    ap.add_argument("--out", default=str(default_embedding_path()))
    args = ap.parse_args()
    with np.load(args.head or default_head_path(build_if_missing=False), allow_pickle=False) as z:
        lv, faces = z["landmark_vertices"], z["f"]
    emb = embedding_from_head(lv, faces)
    emb.save(args.out)
    print(f"wrote {args.out}: 68 landmarks on vertices {lv[:3].tolist()}...")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
