"""``holo-viewer quilt-to-native QUILT.png --calibration visual.json --out native.png [--blend]``."""

from __future__ import annotations

import argparse
import time


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("quilt", help="quilt image, named ..._qs{cols}x{rows}a{aspect}.png (or pass --cols/--rows)")
    parser.add_argument("--calibration", default=None,
                        help="visual.json of the panel, or a preset name (default: the shipped Portrait fixture)")
    parser.add_argument("--out", required=True, help="native PNG to write (screenW x screenH)")
    parser.add_argument("--blend", action="store_true", help="blend the two nearest views instead of nearest view")
    parser.add_argument("--cols", type=int, default=None, help="quilt columns (default: from the file name)")
    parser.add_argument("--rows", type=int, default=None, help="quilt rows (default: from the file name)")
    parser.add_argument("--views", type=int, default=None, help="number of views (default: cols x rows)")


def run(args: argparse.Namespace) -> int:

    from ..display.calibration import DisplayCalibration
    from ..display.export import save_native_png
    from ..display.lenticular import Interleaver
    from ..display.native import views_to_native
    from ..display.quilt import parse_quilt_filename
    from ..errors import InputError
    from ..fileio import load_image
    from ..images import to_uint8

    cal = DisplayCalibration.load(args.calibration)
    cols, rows = args.cols, args.rows
    if cols is None or rows is None:
        c, r, _ = parse_quilt_filename(args.quilt)
        cols = c if cols is None else cols
        rows = r if rows is None else rows
    if cols < 1 or rows < 1:
        raise InputError(f"--cols/--rows: expected positive integers, found {cols}x{rows}")
    quilt = to_uint8(load_image(args.quilt), name=str(args.quilt))
    t0 = time.perf_counter()
    il = Interleaver(cal, quilt.shape, cols, rows, args.views, mode="blend" if args.blend else "nearest")
    native = views_to_native(None, il, quilt=quilt).native
    dt = time.perf_counter() - t0
    path = save_native_png(args.out, native)
    print(f"wrote {path} ({native.shape[1]}x{native.shape[0]}, {cols}x{rows} quilt, "
          f"{'blend' if args.blend else 'nearest'}, {dt * 1e3:.0f} ms incl. index precompute)")
    return 0
