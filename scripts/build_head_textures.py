"""Paint the default head's albedo textures and write them to assets/ (shipped with the head).

Usage: python scripts/build_head_textures.py [--head assets/default_head.npz] [--out assets] [--seed 0]
                                             [--renders DIR]

Writes ``default_head_albedo_{face,head,hair,eye_left,eye_right,lashes}.png``,
``default_head_albedo_lashes_alpha.png`` and the manifest ``default_head_albedo.json`` (appearance
version, seed, sizes and the hash of the mesh they were painted for). Deterministic: the same head
and seed give the same bytes. Run it after ``scripts/build_default_head.py`` (which calls
:func:`holo_viewer.flame.head_textures.build_head_textures` itself); when the shipped textures do not
match the head, the textures are painted on first use and cached instead (see docs/appearance.md).
"""

from __future__ import annotations

import argparse
import hashlib
import time
from pathlib import Path

from holo_viewer.flame.default_head import _repo_asset
from holo_viewer.flame.head_textures import assets_dir, build_head_textures


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--head", type=Path, default=_repo_asset(), help="the head .npz (default: the committed asset)")
    ap.add_argument("--out", type=Path, default=assets_dir(), help="output folder (default: assets/)")
    ap.add_argument("--seed", type=int, default=0, help="noise and strand seed (default 0)")
    ap.add_argument("--renders", type=Path, default=None, help="also write the textured demo renders here")
    args = ap.parse_args()
    from holo_viewer.flame.model import FlameModel

    model = FlameModel.load(args.head, n_shape=None, n_expr=None)
    t0 = time.perf_counter()
    paths = build_head_textures(model, args.out, seed=args.seed)
    total = sum(p.stat().st_size for p in paths)
    print(f"painted in {time.perf_counter() - t0:.1f} s; {total / 1e6:.2f} MB in {len(paths)} files:")
    for p in paths:
        print(f"  {p}  {p.stat().st_size / 1e3:.0f} kB  sha256 {hashlib.sha256(p.read_bytes()).hexdigest()[:16]}")
    if args.renders is not None:
        from holo_viewer.flame.preview import write_head_renders

        write_head_renders(args.renders, model)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
