"""``holo-viewer show FILE [--calibration F] [--monitor N] [--loop]``: fullscreen on the Looking Glass.

FILE is a native image (screenW x screenH), a quilt image (``_qs{c}x{r}a{aspect}`` in its name or
--cols/--rows), a video of quilts or native frames (.mp4 .mov .webm .mkv .avi .gif), or a directory
of images (a sequence, played in name order). Quilts are interleaved with the calibration first.
"""

from __future__ import annotations

import argparse

from ..validation import fps_arg
import sys
from pathlib import Path
from typing import Callable, Iterator

import numpy as np

VIDEO_SUFFIXES = {".mp4", ".mov", ".webm", ".mkv", ".avi", ".gif"}
IMAGE_SUFFIXES = {".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff"}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", help="native image, quilt image, video or image directory")
    parser.add_argument("--calibration", default=None,
                        help="visual.json or preset name (default: the first connected device, else the "
                             "shipped Portrait calibration)")
    parser.add_argument("--monitor", type=int, default=None, help="monitor index (default: the one whose "
                                                                   "resolution matches the calibration)")
    parser.add_argument("--loop", action="store_true", help="loop a video or sequence")
    parser.add_argument("--fps", type=fps_arg, default=30.0, help="frame rate for sequences (videos: their own)")
    parser.add_argument("--cols", type=int, default=None, help="quilt columns (default: from the file name)")
    parser.add_argument("--rows", type=int, default=None, help="quilt rows (default: from the file name)")
    parser.add_argument("--blend", action="store_true", help="two-view blend interleave")
    parser.add_argument("--screenshot", default=None, metavar="PNG",
                        help="show the first frame, save a screenshot of the window to PNG and exit")
    parser.add_argument("--frames", type=int, default=None, help="stop after this many frames")


def _calibration(spec: str | None):
    from ..display.calibration import DisplayCalibration

    if spec is not None:
        return DisplayCalibration.load(spec)
    from ..display.usb import find_volume_calibrations

    for dev in find_volume_calibrations():
        if dev.calibration is not None:
            print(f"using calibration of {dev.model} {dev.serial} at {dev.location}", file=sys.stderr)
            return dev.calibration
    print("no device calibration found; using the shipped Portrait calibration", file=sys.stderr)
    return DisplayCalibration.load(None)


def frame_source(path: Path, cal, cols: int | None, rows: int | None, blend: bool
                 ) -> tuple[Callable[[], Iterator[np.ndarray]], float | None]:
    """(factory of native-frame iterators, the video's fps or None)."""
    from ..display.lenticular import Interleaver
    from ..display.native import views_to_native
    from ..display.quilt import parse_quilt_filename
    from ..errors import InputError
    from ..fileio import load_image
    from ..images import to_uint8

    if not path.exists():
        raise InputError(f"{path}: file not found")
    tagged = None
    if cols is not None and rows is not None:
        tagged = (cols, rows)
    else:
        try:
            c, r, _ = parse_quilt_filename(path.name)
            tagged = (cols or c, rows or r)
        except InputError:
            tagged = None
    cache: dict = {}

    def to_native(frame: np.ndarray) -> np.ndarray:
        f = to_uint8(frame, name=str(path))
        f = f[..., :3]
        if tagged is None and f.shape[:2] == (cal.screen_h, cal.screen_w):
            return f
        if tagged is None:
            raise InputError(f"{path}: {f.shape[1]}x{f.shape[0]} is not the panel's native {cal.screen_w}x"
                             f"{cal.screen_h} and the name has no _qs{{cols}}x{{rows}} quilt tag; pass --cols/--rows")
        key = f.shape
        if key not in cache:
            cache[key] = Interleaver(cal, f.shape, tagged[0], tagged[1], mode="blend" if blend else "nearest")
        return views_to_native(None, cache[key], quilt=np.ascontiguousarray(f)).native

    if path.is_dir():
        files = sorted(p for p in path.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
        if not files:
            raise InputError(f"{path}: directory holds no images ({sorted(IMAGE_SUFFIXES)})")
        return (lambda: (to_native(load_image(p)) for p in files)), None
    if path.suffix.lower() in VIDEO_SUFFIXES:
        import imageio.v2 as imageio

        try:
            meta = imageio.get_reader(str(path)).get_meta_data()
        except Exception as exc:  # imageio raises several types for unreadable files
            raise InputError(f"{path}: cannot read video ({exc})") from exc
        fps = float(meta.get("fps") or 30.0)

        def video() -> Iterator[np.ndarray]:
            reader = imageio.get_reader(str(path))
            try:
                for fr in reader:
                    yield to_native(np.asarray(fr))
            finally:
                reader.close()
        return video, fps
    native = to_native(load_image(path))
    return (lambda: iter([native])), None


def run(args: argparse.Namespace) -> int:
    from ..display.window import NativeWindow, choose_monitor, list_monitors, play
    from ..fileio import save_image

    cal = _calibration(args.calibration)
    frames, fps = frame_source(Path(args.file), cal, args.cols, args.rows, args.blend)
    monitors = list_monitors()
    mon = choose_monitor(monitors, cal.screen_w, cal.screen_h, args.monitor)
    win = NativeWindow(cal.screen_w, cal.screen_h, mon.x, mon.y, title=f"holo-viewer {Path(args.file).name}")
    try:
        if args.screenshot:
            win.show(next(frames()))
            shot = save_image(args.screenshot, win.screenshot())
            print(f"wrote {shot}")
            return 0
        n = play(win, frames, fps or args.fps, loop=args.loop, max_frames=args.frames)
        print(f"shown {n} frame(s)", file=sys.stderr)
    finally:
        win.close()
    return 0
