"""``holo-viewer devices [--json]``: list connected Looking Glass devices and their calibration."""

from __future__ import annotations

import argparse
import json
import sys


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--json", action="store_true", help="print a JSON list instead of text")
    parser.add_argument("--volume-root", action="append", default=None, metavar="DIR",
                        help="search this directory for LKG_calibration/visual.json (repeatable; "
                             "default: the OS's removable-media mount points)")


def run(args: argparse.Namespace) -> int:
    from ..display.usb import scan_devices

    scan = scan_devices(args.volume_root)
    if args.json:
        print(json.dumps({"devices": [d.to_json() for d in scan.devices],
                          "permission_errors": scan.permission_errors, "notes": scan.notes}, indent=2))
    else:
        if not scan.devices and not scan.permission_errors:
            print("No Looking Glass device found (no HID 04d8:ef7e device, no mounted volume with "
                  "LKG_calibration/visual.json). Connect the display by USB and HDMI and check that its "
                  "volume is mounted; or pass --volume-root DIR.")
        for d in scan.devices:
            head = f"{d.model or 'Looking Glass'}  serial {d.serial or '?'}  ({d.source}: {d.location})"
            print(head)
            if d.calibration is not None:
                print("  " + d.calibration.summary())
            if d.error:
                print(f"  error: {d.error}")
        for n in scan.notes:
            print(f"note: {n}", file=sys.stderr)
    for p in scan.permission_errors:
        print(f"permission denied: {p}", file=sys.stderr)
    return 1 if scan.permission_errors and not scan.devices else 0
