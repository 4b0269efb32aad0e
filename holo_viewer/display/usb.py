"""Finding Looking Glass devices and reading their calibration (device I/O lives here only).

Two sources:

* **Volumes** (Portrait, Go, Gen2 and later): the panel mounts a USB mass-storage volume holding
  ``LKG_calibration/visual.json``. :func:`find_volume_calibrations` searches mount roots (default
  :func:`default_volume_roots`; injectable for tests) up to two levels deep.
* **HID** (older "HoloPlay" boards, USB ``04D8:EF7E``): calibration is read page by page with HID
  feature reports (docs/design.md): request = report id 0 + ``[cmd=0 (read), page_hi, page_lo, 64 x 0]``;
  reply = 68 bytes ``[buttons, cmd, page_hi, page_lo, 64 data bytes]``; page 0's data begins with a
  big-endian uint32 JSON length; pages are read until the JSON is complete.
  :func:`read_hid_calibration` takes any object with :class:`FeatureReportDevice`'s two methods,
  so tests use a simulated device; :func:`open_hid_devices` opens real ones with ``hidapi``
  (``pip install hidapi``) or, if that is missing, pyusb with the ``libusb_package`` backend.

``usb`` and ``hid`` are imported lazily inside the functions that need them.
"""

from __future__ import annotations

import errno
import json
import os
import struct
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable, Protocol, Sequence

from ..errors import CalibrationError, DeviceError
from ..fileio import check_json_depth
from .calibration import DisplayCalibration

__all__ = ["VENDOR_ID", "PRODUCT_ID", "PAGE_SIZE", "REPLY_SIZE", "UDEV_RULE", "FeatureReportDevice",
           "FoundDevice", "DeviceScan", "read_hid_calibration", "find_volume_calibrations",
           "default_volume_roots", "open_hid_devices", "scan_devices", "PermissionDeniedError"]

VENDOR_ID = 0x04D8
PRODUCT_ID = 0xEF7E
PAGE_SIZE = 64
REPLY_SIZE = 4 + PAGE_SIZE  # [buttons, cmd, page_hi, page_lo, 64 data]
MAX_JSON_BYTES = 1 << 20
UDEV_RULE = ('SUBSYSTEM=="usb", ATTRS{idVendor}=="04d8", ATTRS{idProduct}=="ef7e", MODE="0666"\n'
             'KERNEL=="hidraw*", ATTRS{idVendor}=="04d8", ATTRS{idProduct}=="ef7e", MODE="0666"')
UDEV_HINT = ("add these udev rules to /etc/udev/rules.d/99-looking-glass.rules, then run "
             "'sudo udevadm control --reload-rules && sudo udevadm trigger' and re-plug the device:\n" + UDEV_RULE)


class PermissionDeniedError(DeviceError):
    """The device exists but this user may not open it (needs a udev rule)."""


class FeatureReportDevice(Protocol):
    """What :func:`read_hid_calibration` needs (hidapi's ``hid.device`` has this interface)."""

    def send_feature_report(self, data: bytes | list[int]) -> int: ...

    def get_feature_report(self, report_id: int, length: int) -> bytes | list[int]: ...


def _request(page: int) -> bytes:
    return bytes([0, 0, (page >> 8) & 0xFF, page & 0xFF]) + bytes(PAGE_SIZE)


def _read_page(dev: FeatureReportDevice, page: int, where: str) -> bytes:
    try:
        dev.send_feature_report(_request(page))
        raw = bytes(dev.get_feature_report(0, REPLY_SIZE + 1))
    except OSError as exc:
        raise DeviceError(f"{where}: reading calibration page {page} failed ({exc})") from exc
    if len(raw) == REPLY_SIZE + 1:  # hidapi prepends the report id
        raw = raw[1:]
    if len(raw) != REPLY_SIZE:
        raise DeviceError(f"{where}: calibration page {page}: expected a {REPLY_SIZE}-byte reply, "
                          f"found {len(raw)} bytes")
    if raw[1] != 0 or raw[2] != (page >> 8) & 0xFF or raw[3] != page & 0xFF:
        raise DeviceError(f"{where}: calibration page {page}: reply header [cmd, page_hi, page_lo] = "
                          f"{list(raw[1:4])}, expected [0, {(page >> 8) & 0xFF}, {page & 0xFF}] (corrupt page)")
    return raw[4:]


def read_hid_calibration(dev: FeatureReportDevice, *, where: str = "HID 04d8:ef7e") -> dict:
    """Read the calibration JSON from a HID device by the page protocol.

    Returns
    -------
    dict
        The parsed visual.json object.

    Raises
    ------
    DeviceError
        Short or corrupt pages, an impossible length, or bytes that are not JSON.
    """
    first = _read_page(dev, 0, where)
    (length,) = struct.unpack(">I", first[:4])
    if length == 0 or length > MAX_JSON_BYTES:
        raise DeviceError(f"{where}: calibration length field = {length} bytes, expected 1..{MAX_JSON_BYTES}")
    data = bytearray(first[4:])
    page = 1
    while len(data) < length:
        data += _read_page(dev, page, where)
        page += 1
    blob = bytes(data[:length])
    check_json_depth(blob, DeviceError, where, "the device's calibration JSON")
    try:
        obj = json.loads(blob.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise DeviceError(f"{where}: calibration is not valid JSON after {length} bytes ({exc})") from exc
    if not isinstance(obj, dict):
        raise DeviceError(f"{where}: calibration JSON is a {type(obj).__name__}, expected an object")
    return obj


@dataclass
class FoundDevice:
    """One Looking Glass found on this machine."""

    source: str  # "volume" or "hid"
    location: str  # mount path or USB path
    serial: str = ""
    model: str = ""
    calibration: DisplayCalibration | None = None
    error: str = ""

    def to_json(self) -> dict:
        d = {"source": self.source, "location": self.location, "serial": self.serial, "model": self.model,
             "error": self.error or None}
        d["calibration"] = self.calibration.to_json() if self.calibration is not None else None
        if self.calibration is not None:
            q = self.calibration.quilt
            d["quilt"] = {"cols": q.cols, "rows": q.rows, "width": q.width, "height": q.height, "aspect": q.aspect}
        return d


@dataclass
class DeviceScan:
    devices: list[FoundDevice] = field(default_factory=list)
    permission_errors: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)


def default_volume_roots() -> list[Path]:
    """Where removable volumes are mounted on this OS."""
    user = os.environ.get("USER") or os.environ.get("USERNAME") or ""
    if sys.platform == "darwin":
        return [Path("/Volumes")]
    if sys.platform.startswith("win"):
        return [Path(f"{d}:\\") for d in "DEFGHIJKLMNOPQRSTUVWXYZ"]
    roots = [Path("/media") / user, Path("/run/media") / user, Path("/media"), Path("/mnt")]
    return [r for r in roots if str(r) not in ("/media/", "/run/media/")]


def find_volume_calibrations(roots: Sequence[os.PathLike | str] | None = None) -> list[FoundDevice]:
    """Volumes under ``roots`` (or :func:`default_volume_roots`) holding ``LKG_calibration/visual.json``.

    A root itself, its children and grandchildren are checked. Unreadable or invalid files are
    reported in ``FoundDevice.error`` rather than raised.
    """
    found: list[FoundDevice] = []
    seen: set[str] = set()
    for root in (default_volume_roots() if roots is None else [Path(r) for r in roots]):
        candidates = [Path(root)]
        try:
            for child in sorted(Path(root).iterdir()):
                if child.is_dir():
                    candidates.append(child)
                    try:
                        candidates.extend(sorted(g for g in child.iterdir() if g.is_dir()))
                    except OSError:
                        pass
        except OSError:
            continue
        for vol in candidates:
            f = vol / "LKG_calibration" / "visual.json"
            try:
                if not f.is_file():
                    continue
            except OSError:
                continue
            key = str(f.resolve())
            if key in seen:
                continue
            seen.add(key)
            dev = FoundDevice("volume", str(vol))
            try:
                cal = DisplayCalibration.from_file(f)
                dev.calibration, dev.serial, dev.model = cal, cal.serial, cal.model
            except CalibrationError as exc:
                dev.error = str(exc)
            found.append(dev)
    return found


class _PyUsbFeatureDevice:
    """HID feature reports over pyusb control transfers (SET_REPORT / GET_REPORT, interface 0)."""

    def __init__(self, dev) -> None:  # pragma: no cover - needs hardware
        self.dev = dev

    def send_feature_report(self, data: bytes | list[int]) -> int:  # pragma: no cover
        data = bytes(data)
        return self.dev.ctrl_transfer(0x21, 0x09, (3 << 8) | data[0], 0, data[1:])

    def get_feature_report(self, report_id: int, length: int) -> bytes:  # pragma: no cover
        return bytes(self.dev.ctrl_transfer(0xA1, 0x01, (3 << 8) | report_id, 0, length - 1))


def open_hid_devices() -> tuple[list[tuple[str, str, FeatureReportDevice]], list[str], list[str]]:
    """Open every 04D8:EF7E device: ([(location, serial, device)], permission errors, notes)."""
    opened: list[tuple[str, str, FeatureReportDevice]] = []
    perms: list[str] = []
    notes: list[str] = []
    try:
        import hid  # hidapi
        if not hasattr(hid, "enumerate"):
            raise ImportError("the 'hid' module found is not hidapi")
    except ImportError:
        hid = None
    if hid is not None:
        for info in hid.enumerate(VENDOR_ID, PRODUCT_ID):  # pragma: no cover - needs hardware
            path = info.get("path", b"")
            loc = path.decode(errors="replace") if isinstance(path, bytes) else str(path)
            d = hid.device()
            try:
                d.open_path(path)
            except OSError as exc:
                perms.append(f"{loc}: cannot open ({exc}); {UDEV_HINT}")
                continue
            opened.append((loc, info.get("serial_number") or "", d))
        return opened, perms, notes
    try:
        import libusb_package
        import usb.core
    except ImportError:
        notes.append("neither hidapi nor pyusb+libusb-package is installed; HID devices not searched")
        return opened, perms, notes
    try:
        backend = libusb_package.get_libusb1_backend()
        devs = list(usb.core.find(find_all=True, idVendor=VENDOR_ID, idProduct=PRODUCT_ID, backend=backend))
    except usb.core.NoBackendError:  # pragma: no cover
        notes.append("libusb backend unavailable; HID devices not searched")
        return opened, perms, notes
    for dev in devs:  # pragma: no cover - needs hardware
        loc = f"usb bus {dev.bus} address {dev.address}"
        try:
            serial = usb.util.get_string(dev, dev.iSerialNumber) or ""
            if dev.is_kernel_driver_active(0):
                dev.detach_kernel_driver(0)
        except usb.core.USBError as exc:
            if exc.errno in (errno.EACCES, errno.EPERM):
                perms.append(f"{loc}: permission denied; {UDEV_HINT}")
                continue
            notes.append(f"{loc}: {exc}")
            continue
        opened.append((loc, serial, _PyUsbFeatureDevice(dev)))
    return opened, perms, notes


def scan_devices(volume_roots: Sequence[os.PathLike | str] | None = None, *, hid_devices: Iterable[
        tuple[str, str, FeatureReportDevice]] | None = None) -> DeviceScan:
    """Find Looking Glass devices: mounted calibration volumes and HID boards.

    ``hid_devices`` (location, serial, device) replaces real HID enumeration (tests).
    """
    scan = DeviceScan()
    scan.devices.extend(find_volume_calibrations(volume_roots))
    if hid_devices is None:
        hid_devices, perms, notes = open_hid_devices()
        scan.permission_errors.extend(perms)
        scan.notes.extend(notes)
    for loc, serial, dev in hid_devices:
        found = FoundDevice("hid", loc, serial=serial)
        try:
            raw = read_hid_calibration(dev, where=loc)
            cal = DisplayCalibration.from_json(raw, source=f"{loc} calibration")
            found.calibration, found.serial, found.model = cal, cal.serial or serial, cal.model
        except PermissionError as exc:  # pragma: no cover - needs hardware
            scan.permission_errors.append(f"{loc}: {exc}; {UDEV_HINT}")
            continue
        except (DeviceError, CalibrationError) as exc:
            found.error = str(exc)
        scan.devices.append(found)
    return scan
