"""Regenerate assets/default_head.npz (the embedded default head) from ICT Face Model Light.

Usage: python scripts/build_default_head.py [--ict PATH] [--out assets/default_head.npz] [--renders DIR]

The source is ``ict_facekit_light.npz`` (ICT-FaceKit, MIT): ``--ict``, else ``$HOLO_VIEWER_ICT_FACEKIT``,
else the copy shipped in ``assets/ICT-FaceKit/`` (licence, source commit and sha256 in its ``SOURCE.md``). The build is
deterministic: running it twice gives the same bytes. A head already at ``--out`` is kept when the rebuild is
within 4 ulps of it (another CPU's BLAS: ``assets_build.head.keep_or_write_head``), so the sha256 that
``assets/default_avatar.npz`` is keyed to holds; a head that differs more is written, with a warning that the
default avatar must be refitted. It then paints the head's albedo textures into
the same folder (``default_head_albedo_*.png`` + ``.json``, as scripts/build_head_textures.py; skip with
``--no-textures``). Rebuild the landmark embedding afterwards (scripts/build_landmark_embedding.py).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from holo_viewer.assets_build.head import build_default_head, keep_or_write_head
from holo_viewer.avatar.default_gaussians import fitted_asset_path
from holo_viewer.flame.default_head import _repo_asset


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ict", type=Path, default=None, help="ict_facekit_light.npz (default: see the module docstring)")
    ap.add_argument("--out", type=Path, default=_repo_asset(), help="target .npz (default: the committed asset)")
    ap.add_argument("--renders", type=Path, default=None, help="also write demo renders of the head here")
    ap.add_argument("--no-textures", action="store_true", help="do not paint the albedo textures beside the head")
    args = ap.parse_args()
    t0 = time.perf_counter()
    arrays = build_default_head(args.ict)
    t1 = time.perf_counter()
    written = keep_or_write_head(args.out, arrays)
    path = written.path
    avatar = fitted_asset_path() if path.resolve() == _repo_asset().resolve() else None
    line, loud = written.report(avatar, "python scripts/fit_default_avatar.py")
    print(line, file=sys.stderr if loud else sys.stdout)
    v, f = arrays["v_template"], arrays["f"]
    print(f"  {path.stat().st_size / 1e6:.2f} MB, build {t1 - t0:.1f} s")
    print(f"  vertices {len(v)}, faces {len(f)}, shape {int(arrays['n_shape'])}, expression {int(arrays['n_expr'])}")
    print(f"  extent (m): x {np.ptp(v[:, 0]):.3f}  y {np.ptp(v[:, 1]):.3f}  z {np.ptp(v[:, 2]):.3f}")
    from holo_viewer.flame.model import FlameModel

    model = FlameModel.load(path, n_shape=None, n_expr=None)
    if not args.no_textures:
        from holo_viewer.flame.head_textures import build_head_textures

        t2 = time.perf_counter()
        written = build_head_textures(model, path.parent)
        print(f"painted {len(written)} texture files in {path.parent} in {time.perf_counter() - t2:.1f} s")
    if args.renders is not None:
        from holo_viewer.flame.preview import write_head_renders

        write_head_renders(args.renders, model)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
