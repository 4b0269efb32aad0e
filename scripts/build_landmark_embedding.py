"""Build assets/default_head_landmarks.npz: the 68 dlib landmarks embedded on the default head.

Renders the neutral default avatar from the front (and from a few nearby angles), runs the
tracker's own detector on the renders, back-projects every landmark onto the mesh through the
render camera (holo_viewer.tracking.head_model.embed_landmarks) and keeps, per landmark, the
surface point closest to the mean of its back-projections in the head's rest frame. Needs the
[live] extra. Usage: python scripts/build_landmark_embedding.py [--out PATH] [--preview PNG]
"""

from __future__ import annotations

import argparse

import numpy as np


def main() -> int:
    from holo_viewer.pipeline.live_support import HeadRenderer, webcam_camera
    from holo_viewer.tracking.head_model import LandmarkEmbedding, default_embedding_path, embed_landmarks
    from holo_viewer.tracking.landmarks import LandmarkDetector

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(default_embedding_path()))
    ap.add_argument("--preview", help="write the front render with the detected landmarks to this PNG")
    args = ap.parse_args()

    r = HeadRenderer(background=(0.0, 0.0, 0.0))
    model = r.model
    from holo_viewer.flame.default_head import load_default_model

    base = load_default_model()
    n_faces_base = int(base.faces.shape[0])
    nvb = int(base.n_vertices)
    faces = model.faces.numpy()[:n_faces_base]
    det = LandmarkDetector(redetect_every=1, upsample=1)
    v_rest = r.vertices({})[:nvb]
    points = []
    for yaw, pitch in ((0, 0), (-8, 0), (8, 0), (0, -6), (0, 6)):
        cam = webcam_camera(640, 480, 50.0, 0.45, yaw, pitch)
        img = r.render({}, cam)
        faces_found = det(img)
        det.reset()
        if not faces_found:
            raise SystemExit(f"no face found at yaw {yaw}, pitch {pitch}")
        lm = faces_found[0].landmarks
        tri, bary = embed_landmarks(lm, cam.world_to_cam[0], cam.K[0], v_rest, faces)
        points.append(np.einsum("lkc,lk->lc", v_rest[faces[tri]], bary))
        if yaw == 0 and pitch == 0 and args.preview:
            from PIL import Image, ImageDraw

            im = Image.fromarray(img)
            d = ImageDraw.Draw(im)
            for x, y in lm:
                d.ellipse([x - 2, y - 2, x + 2, y + 2], fill=(0, 255, 0))
            im.save(args.preview)
    mean = np.mean(points, axis=0)  # (68, 3)
    spread = np.linalg.norm(np.asarray(points) - mean, axis=2).max(axis=0)
    # snap the mean back onto the surface: project it through a front camera onto the mesh
    cam = webcam_camera(640, 480, 50.0, 0.45)
    pc = mean @ cam.world_to_cam[0][:3, :3].T + cam.world_to_cam[0][:3, 3]
    K = cam.K[0]
    px = pc[:, :2] / pc[:, 2:3] * [K[0, 0], K[1, 1]] + [K[0, 2], K[1, 2]]
    tri, bary = embed_landmarks(px, cam.world_to_cam[0], K, v_rest, faces)
    w = np.ones(68)
    w[:17] = 0.0
    w[6:11] = 0.5
    emb = LandmarkEmbedding(tri, bary, w)
    emb.save(args.out)
    print(f"wrote {args.out}; back-projection spread over 5 views: median {1000 * np.median(spread):.1f} mm, "
          f"max {1000 * spread.max():.1f} mm (landmark {int(np.argmax(spread))}); inner points 17-67: median "
          f"{1000 * np.median(spread[17:]):.1f} mm, max {1000 * spread[17:].max():.1f} mm")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
