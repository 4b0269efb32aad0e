"""Device discovery: simulated HID page protocol, temporary directory as a volume, CLI output."""

import json
import struct

import pytest

from holo_viewer.cli import main
from holo_viewer.display.calibration import default_calibration_path
from holo_viewer.display.usb import PAGE_SIZE, find_volume_calibrations, read_hid_calibration, scan_devices
from holo_viewer.errors import DeviceError

FIXTURE = str(default_calibration_path())


class FakeHid:
    """Implements the page protocol: feature report 0 = [0, cmd, page_hi, page_lo, 64 x 0]."""

    def __init__(self, payload: bytes, *, length: int | None = None, short_page: int | None = None,
                 corrupt_page: int | None = None, report_id_prefix: bool = True):
        n = len(payload) if length is None else length
        self.blob = struct.pack(">I", n) + payload
        self.short_page, self.corrupt_page, self.prefix = short_page, corrupt_page, report_id_prefix
        self.page = None
        self.requests = []

    def send_feature_report(self, data):
        data = bytes(data)
        assert len(data) == 4 + PAGE_SIZE and data[0] == 0 and data[1] == 0 and not any(data[4:])
        self.page = (data[2] << 8) | data[3]
        self.requests.append(self.page)
        return len(data)

    def get_feature_report(self, report_id, length):
        p = self.page
        chunk = self.blob[p * PAGE_SIZE:(p + 1) * PAGE_SIZE].ljust(PAGE_SIZE, b"\0")
        reply = bytes([0, 0, p >> 8, p & 0xFF]) + chunk
        if p == self.corrupt_page:
            reply = bytes([0, 0, (p + 7) >> 8, (p + 7) & 0xFF]) + chunk
        if p == self.short_page:
            reply = reply[:30]
        return (b"\0" + reply) if self.prefix else reply


def _payload() -> bytes:
    with open(FIXTURE, "rb") as fh:
        return fh.read()


@pytest.mark.parametrize("prefix", [True, False])
def test_hid_reads_all_pages(prefix):
    dev = FakeHid(_payload(), report_id_prefix=prefix)
    cal = read_hid_calibration(dev)
    assert cal["serial"] == "LKG-PORT-00000" and cal["pitch"]["value"] == pytest.approx(52.594383239746094)
    assert dev.requests == list(range(len(dev.requests)))
    assert len(dev.requests) == -(-(len(_payload()) + 4) // PAGE_SIZE)


def test_hid_short_corrupt_and_wrong_length():
    with pytest.raises(DeviceError, match="page 2: expected a 68-byte reply, found 31 bytes"):
        read_hid_calibration(FakeHid(_payload(), short_page=2))
    with pytest.raises(DeviceError, match="page 0: expected a 68-byte reply"):
        read_hid_calibration(FakeHid(_payload(), short_page=0, report_id_prefix=False))
    with pytest.raises(DeviceError, match="page 3: reply header .*corrupt"):
        read_hid_calibration(FakeHid(_payload(), corrupt_page=3))
    with pytest.raises(DeviceError, match="length field = 0"):
        read_hid_calibration(FakeHid(_payload(), length=0))
    with pytest.raises(DeviceError, match="length field = 4294967295"):
        read_hid_calibration(FakeHid(_payload(), length=0xFFFFFFFF))
    with pytest.raises(DeviceError, match="not valid JSON"):
        read_hid_calibration(FakeHid(_payload(), length=len(_payload()) - 10))  # truncated JSON
    with pytest.raises(DeviceError, match="not valid JSON"):
        read_hid_calibration(FakeHid(b"\xff\xfe garbage " * 9))


def test_volume_and_hid_scan(tmp_path):
    vol = tmp_path / "user" / "LKG_PORTRAIT"
    (vol / "LKG_calibration").mkdir(parents=True)
    (vol / "LKG_calibration" / "visual.json").write_bytes(_payload())
    bad = tmp_path / "OTHER"
    (bad / "LKG_calibration").mkdir(parents=True)
    (bad / "LKG_calibration" / "visual.json").write_text('{"serial": "LKG-P1", "pitch": {"value": "x"}}')
    found = find_volume_calibrations([tmp_path])
    assert len(found) == 2
    good = [d for d in found if d.calibration is not None][0]
    assert good.serial == "LKG-PORT-00000" and good.model == "Looking Glass Portrait"
    assert "'pitch'" in [d for d in found if d.error][0].error
    scan = scan_devices([tmp_path / "nothing"], hid_devices=[("hid:fake", "S1", FakeHid(_payload())),
                                                             ("hid:broken", "S2", FakeHid(_payload(), short_page=1))])
    assert [d.source for d in scan.devices] == ["hid", "hid"]
    assert scan.devices[0].calibration.quilt.cols == 8 and "page 1" in scan.devices[1].error


def test_cli_devices(tmp_path, capsys):
    assert main(["devices", "--volume-root", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "No Looking Glass device found" in out
    (tmp_path / "V" / "LKG_calibration").mkdir(parents=True)
    (tmp_path / "V" / "LKG_calibration" / "visual.json").write_bytes(_payload())
    assert main(["devices", "--json", "--volume-root", str(tmp_path)]) == 0
    data = json.loads(capsys.readouterr().out)
    vols = [d for d in data["devices"] if d["source"] == "volume"]
    assert vols[0]["serial"] == "LKG-PORT-00000" and vols[0]["quilt"]["cols"] == 8
