"""3DGS PLY I/O in the Inria (graphdeco-inria/gaussian-splatting) layout.

The vertex element holds, per Gaussian (docs/design.md "3DGS forward pass")::

    x y z  nx ny nz  f_dc_0..2  f_rest_0..(3 M - 1)  opacity  scale_0..2  rot_0..3

with ``M = (d + 1)^2 - 1`` higher-order SH coefficients per channel stored
channel-major (all red, then all green, then all blue), ``opacity`` a logit,
``scale_*`` natural-log standard deviations and ``rot_*`` a wxyz quaternion
(``rot_0`` is w, not necessarily normalised in the file).

Reading accepts ``binary_little_endian``, ``binary_big_endian`` and ``ascii``;
the SH degree is inferred from the number of ``f_rest_*`` fields; properties
other than the above (e.g. GaussianAvatars' ``binding_0``) are kept in
:attr:`Gaussians.extra` under their property names with their file dtype.
Normals are dropped unless some are non-zero (then kept as extras ``nx``,
``ny``, ``nz``). Quaternions are normalised on load (rows whose norm already
equals 1 within 1e-6 are left bit-for-bit untouched, so load -> save -> load is
bit-exact). Rows holding NaN/inf are rejected with their indices.

Writing is atomic, binary little-endian, float32 for the standard fields (the
Inria layout), extras in their own dtype (an (N, K) extra becomes properties
``name_0 .. name_{K-1}``).
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import PlyError
from ..fileio import atomic_write
from .gaussians import Gaussians

__all__ = ["load_ply", "save_ply", "PlyHeader", "read_ply_header"]

_PLY_TYPES: dict[str, str] = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}
_NP_TO_PLY: dict[str, str] = {"i1": "char", "u1": "uchar", "i2": "short", "u2": "ushort", "i4": "int",
                              "u4": "uint", "f4": "float", "f8": "double"}
_FORMATS = {"binary_little_endian": "<", "binary_big_endian": ">", "ascii": "ascii"}
_STANDARD = ("x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1", "scale_2",
             "rot_0", "rot_1", "rot_2", "rot_3")
_NORMALS = ("nx", "ny", "nz")
_MAX_HEADER = 1 << 20


@dataclass(frozen=True)
class _Element:
    name: str
    count: int
    props: tuple[tuple[str, str], ...]  # (name, numpy type code without byte order)
    has_list: bool


@dataclass(frozen=True)
class PlyHeader:
    """Parsed PLY header.

    Attributes
    ----------
    format : str
        ``"<"`` (binary little endian), ``">"`` (binary big endian) or ``"ascii"``.
    elements : tuple
        Elements in file order (name, count, properties).
    data_offset : int
        Byte offset of the first data byte.
    comments : tuple of str
        Header ``comment`` lines (without the keyword).
    """

    format: str
    elements: tuple[_Element, ...]
    data_offset: int
    comments: tuple[str, ...] = ()


def read_ply_header(path: str | os.PathLike, data: bytes | None = None) -> PlyHeader:
    """Parse the header of a PLY file (raises :class:`PlyError` naming the file)."""
    path = Path(path)
    if data is None:
        with open(path, "rb") as fh:
            data = fh.read(_MAX_HEADER)
    if not data.startswith(b"ply"):
        raise PlyError(f"{path}: expected a PLY file starting with 'ply', found {data[:16]!r}")
    m = re.search(rb"end_header\r?\n", data[:_MAX_HEADER])
    if m is None:
        raise PlyError(f"{path}: expected 'end_header' within the first {_MAX_HEADER} bytes, found none "
                       "(truncated or not a PLY file)")
    lines = data[: m.start()].decode("ascii", errors="replace").splitlines()
    fmt = None
    elements: list[_Element] = []
    cur: dict[str, Any] | None = None
    comments: list[str] = []

    def close() -> None:
        if cur is not None:
            elements.append(_Element(cur["name"], cur["count"], tuple(cur["props"]), cur["list"]))

    for ln, line in enumerate(lines[1:], start=2):
        tok = line.split()
        if tok and tok[0] == "comment":
            comments.append(line.strip()[len("comment"):].strip())
            continue
        if not tok or tok[0] == "obj_info":
            continue
        if tok[0] == "format":
            if len(tok) < 2 or tok[1] not in _FORMATS:
                raise PlyError(f"{path}: header line {ln}: expected format ascii | binary_little_endian | "
                               f"binary_big_endian, found {line!r}")
            fmt = _FORMATS[tok[1]]
        elif tok[0] == "element":
            close()
            try:
                count = int(tok[2])
            except (IndexError, ValueError):
                raise PlyError(f"{path}: header line {ln}: expected 'element NAME COUNT', found {line!r}") from None
            if count < 0:
                raise PlyError(f"{path}: header line {ln}: expected a non-negative count, found {count}")
            cur = {"name": tok[1], "count": count, "props": [], "list": False}
        elif tok[0] == "property":
            if cur is None:
                raise PlyError(f"{path}: header line {ln}: property before any element: {line!r}")
            if len(tok) >= 2 and tok[1] == "list":
                cur["list"] = True
                cur["props"].append((tok[-1], "list"))
                continue
            if len(tok) != 3 or tok[1] not in _PLY_TYPES:
                raise PlyError(f"{path}: header line {ln}: expected 'property TYPE NAME' with TYPE one of "
                               f"{sorted(set(_PLY_TYPES))}, found {line!r}")
            cur["props"].append((tok[2], _PLY_TYPES[tok[1]]))
        else:
            raise PlyError(f"{path}: header line {ln}: unknown keyword {tok[0]!r}")
    close()
    if fmt is None:
        raise PlyError(f"{path}: expected a 'format' line in the header, found none")
    return PlyHeader(fmt, tuple(elements), m.end(), tuple(comments))


def _vertex_table(path: Path, header: PlyHeader, data: bytes) -> np.ndarray:
    """Structured array of the vertex element (native byte order)."""
    names = [e.name for e in header.elements]
    if "vertex" not in names:
        raise PlyError(f"{path}: expected an element 'vertex', found elements {names}")
    vi = names.index("vertex")
    vert = header.elements[vi]
    if vert.has_list:
        raise PlyError(f"{path}: element 'vertex': expected scalar properties, found a list property")
    if not vert.props:
        raise PlyError(f"{path}: element 'vertex': expected properties (x, y, z, ...), found none")
    dup = {p for p, _ in vert.props if [q for q, _ in vert.props].count(p) > 1}
    if dup:
        raise PlyError(f"{path}: element 'vertex': duplicate properties {sorted(dup)}")
    offset = header.data_offset
    if header.format == "ascii":
        return _ascii_vertices(path, header, data, vi)
    for e in header.elements[:vi]:  # elements before vertex must be skippable
        if e.has_list:
            raise PlyError(f"{path}: element {e.name!r} with list properties precedes 'vertex'; "
                           "expected 'vertex' first")
        offset += e.count * int(np.dtype([(p, header.format + t) for p, t in e.props]).itemsize)
    dtype = np.dtype([(p, header.format + t) for p, t in vert.props])
    need = vert.count * dtype.itemsize
    have = len(data) - offset
    if have < need:
        row = max(have, 0) // dtype.itemsize
        within = max(have, 0) - row * dtype.itemsize
        field = next(p for p in dtype.names if dtype.fields[p][1] + dtype.fields[p][0].itemsize > within)
        raise PlyError(f"{path}: truncated: header declares {vert.count} vertices of {dtype.itemsize} bytes "
                       f"({need} bytes), found {have}; data ends in vertex {row}, field {field!r}")
    if vi == len(header.elements) - 1 and have > need:
        raise PlyError(f"{path}: wrong vertex count: header declares {vert.count} vertices ({need} bytes) "
                       f"but {have} bytes of vertex data follow the header "
                       f"({have / dtype.itemsize:.2f} vertices)")
    arr = np.frombuffer(data, dtype=dtype, count=vert.count, offset=offset)
    return arr.astype(dtype.newbyteorder("="))


def _ascii_vertices(path: Path, header: PlyHeader, data: bytes, vi: int) -> np.ndarray:
    body = data[header.data_offset:].decode("ascii", errors="replace").splitlines()
    start = 0
    for e in header.elements[:vi]:
        start += e.count
    vert = header.elements[vi]
    rows = body[start:start + vert.count]
    n_props = len(vert.props)
    dtype = np.dtype([(p, "=" + t) for p, t in vert.props])
    if len(rows) < vert.count:  # checked before allocating: a header may claim billions of vertices
        raise PlyError(f"{path}: truncated: header declares {vert.count} vertices, found {len(rows)} lines; "
                       f"vertex {len(rows)} missing (first field {vert.props[0][0]!r})")
    out = np.zeros(vert.count, dtype=dtype)
    if vi == len(header.elements) - 1:
        trailing = [r for r in body[start + vert.count:] if r.strip()]
        if trailing:
            raise PlyError(f"{path}: wrong vertex count: header declares {vert.count} vertices, "
                           f"found {len(trailing)} extra non-empty lines after them")
    flat = " ".join(rows).split()
    if len(flat) == vert.count * n_props:
        try:
            vals = np.array(flat, dtype=np.float64).reshape(vert.count, n_props)
        except ValueError:
            vals = None
        if vals is not None:
            for j, (p, t) in enumerate(vert.props):
                out[p] = vals[:, j]
            return out
    for i, line in enumerate(rows):
        tok = line.split()
        if len(tok) != n_props:
            field = vert.props[min(len(tok), n_props - 1)][0]
            raise PlyError(f"{path}: vertex {i}: expected {n_props} values, found {len(tok)} "
                           f"(field {field!r} {'missing' if len(tok) < n_props else 'followed by extra values'})")
        for j, (p, t) in enumerate(vert.props):
            try:
                out[p][i] = float(tok[j]) if t[0] == "f" else int(tok[j])
            except ValueError:
                raise PlyError(f"{path}: vertex {i}, field {p!r}: expected a number, found {tok[j]!r}") from None
    return out


def _f_rest_count(path: Path, names: list[str]) -> int:
    rest = sorted(int(n[len("f_rest_"):]) for n in names if re.fullmatch(r"f_rest_\d+", n))
    if rest != list(range(len(rest))):
        missing = sorted(set(range(max(rest) + 1)) - set(rest)) if rest else []
        raise PlyError(f"{path}: f_rest_*: expected contiguous f_rest_0..f_rest_{len(rest) - 1}, "
                       f"missing {['f_rest_%d' % k for k in missing[:5]]}")
    if len(rest) not in (0, 9, 24, 45):
        raise PlyError(f"{path}: f_rest_*: expected 0, 9, 24 or 45 fields (SH degree 0..3), found {len(rest)}")
    return len(rest)


def load_ply(path: str | os.PathLike, *, normalize_quats: bool = True) -> Gaussians:
    """Read a 3DGS PLY file into numpy :class:`Gaussians` (float32 fields as stored).

    Parameters
    ----------
    path : path-like
        A PLY file in the Inria 3DGS layout (binary either endian, or ASCII).
    normalize_quats : bool
        Normalise ``rot_*`` to unit quaternions (rows already unit within 1e-6 are untouched).

    Returns
    -------
    Gaussians
        numpy-backed; ``extra`` holds every non-standard vertex property by name.

    Raises
    ------
    PlyError
        Missing file, bad header, missing field, truncated data, wrong vertex count, NaN/inf rows
        (with their indices) or zero quaternions; the message names the file and the field.
    """
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise PlyError(f"{path}: cannot read PLY file ({exc.strerror or exc})") from None
    header = read_ply_header(path, data)
    table = _vertex_table(path, header, data)
    names = list(table.dtype.names)
    missing = [f for f in _STANDARD if f not in names]
    if missing:
        raise PlyError(f"{path}: element 'vertex': missing field(s) {missing}; expected the 3DGS layout "
                       f"{list(_STANDARD)} (+ f_rest_*), found {names}")
    n_rest = _f_rest_count(path, names)
    n = table.shape[0]

    def cols(fields: list[str]) -> np.ndarray:
        if not fields:
            return np.zeros((n, 0), np.float32)
        arr = np.stack([table[f] for f in fields], axis=1)
        return arr if arr.dtype.kind == "f" else arr.astype(np.float32)

    std_fields = list(_STANDARD) + [f"f_rest_{k}" for k in range(n_rest)]
    allv = cols(std_fields)
    bad = ~np.isfinite(allv).all(axis=1)
    if bad.any():
        idx = np.flatnonzero(bad)
        colbad = [std_fields[j] for j in np.flatnonzero(~np.isfinite(allv[idx]).all(axis=0))]
        raise PlyError(f"{path}: {idx.size} vertices hold NaN/inf (indices {idx[:10].tolist()}"
                       f"{'...' if idx.size > 10 else ''}; fields {colbad})")
    means = cols(["x", "y", "z"])
    quats = cols(["rot_0", "rot_1", "rot_2", "rot_3"])
    qn = np.linalg.norm(quats.astype(np.float64), axis=1)
    if np.any(qn < 1e-12):
        idx = np.flatnonzero(qn < 1e-12)
        raise PlyError(f"{path}: rot_0..3: expected non-zero quaternions, found {idx.size} zero "
                       f"(indices {idx[:10].tolist()})")
    if normalize_quats:
        fix = np.abs(qn - 1.0) > 1e-6
        if fix.any():
            quats = quats.copy()
            quats[fix] = (quats[fix] / qn[fix, None]).astype(quats.dtype)
    log_scales = cols(["scale_0", "scale_1", "scale_2"])
    opacity = table["opacity"].copy()
    if opacity.dtype.kind != "f":
        opacity = opacity.astype(np.float32)
    m = n_rest // 3
    dc = cols(["f_dc_0", "f_dc_1", "f_dc_2"])
    rest = cols([f"f_rest_{k}" for k in range(n_rest)]).reshape(n, 3, m).transpose(0, 2, 1)
    sh = np.ascontiguousarray(np.concatenate([dc[:, None, :], rest], axis=1))
    known = set(std_fields) | set(_NORMALS)
    extra: dict[str, np.ndarray] = {}
    if all(f in names for f in _NORMALS) and any(np.any(table[f] != 0) for f in _NORMALS):
        known -= set(_NORMALS)
    for f in names:
        if f not in known:
            extra[f] = table[f].copy()
    return Gaussians(means, quats, log_scales, opacity, sh, extra)


def save_ply(gaussians: Gaussians, path: str | os.PathLike, comments: "list[str] | tuple[str, ...]" = ()) -> Path:
    """Write Gaussians as a binary little-endian 3DGS PLY (atomic).

    Standard fields are written as float32 (the Inria layout); normals as zeros unless
    ``extra`` has ``nx``/``ny``/``nz``; each extra (N,) array becomes one property of its own
    dtype, an (N, K) array the properties ``name_0 .. name_{K-1}``.

    ``comments`` are written as header ``comment`` lines (read back by :func:`read_ply_header`).

    Returns
    -------
    pathlib.Path
        The written path.
    """
    g = gaussians.numpy()
    g.validate(context=f"{path}")
    n = len(g)
    m = g.sh.shape[1] - 1
    fields: list[tuple[str, np.ndarray]] = []
    f32 = np.float32
    means = g.means.astype(f32, copy=False)
    fields += [("x", means[:, 0]), ("y", means[:, 1]), ("z", means[:, 2])]
    extra = dict(g.extra)
    for k, name in enumerate(_NORMALS):
        fields.append((name, np.asarray(extra.pop(name)) if name in extra else np.zeros(n, f32)))
    sh = g.sh.astype(f32, copy=False)
    fields += [(f"f_dc_{c}", sh[:, 0, c]) for c in range(3)]
    fields += [(f"f_rest_{c * m + k}", sh[:, 1 + k, c]) for c in range(3) for k in range(m)]
    fields.append(("opacity", g.opacity_logits.astype(f32, copy=False)))
    ls = g.log_scales.astype(f32, copy=False)
    fields += [(f"scale_{k}", ls[:, k]) for k in range(3)]
    q = g.quats.astype(f32, copy=False)
    fields += [(f"rot_{k}", q[:, k]) for k in range(4)]
    used = {f for f, _ in fields}
    for name, arr in extra.items():
        arr = np.asarray(arr)
        if arr.dtype == np.bool_:
            arr = arr.astype(np.uint8)
        if arr.dtype == np.int64 or arr.dtype == np.uint64:
            if arr.size and (arr.min() < np.iinfo(np.int32).min or arr.max() > np.iinfo(np.int32).max):
                raise PlyError(f"{path}: extra[{name!r}]: int64 values do not fit the PLY int type")
            arr = arr.astype(np.int32)
        if arr.dtype.str[1:] not in _NP_TO_PLY:
            raise PlyError(f"{path}: extra[{name!r}]: dtype {arr.dtype} has no PLY property type")
        cols_ = [(name, arr)] if arr.ndim == 1 else [(f"{name}_{k}", arr[:, k]) for k in
                                                      range(int(np.prod(arr.shape[1:])))]
        if arr.ndim > 2:
            flat = arr.reshape(n, -1)
            cols_ = [(f"{name}_{k}", flat[:, k]) for k in range(flat.shape[1])]
        for cname, col in cols_:
            if cname in used:
                raise PlyError(f"{path}: extra[{name!r}]: property {cname!r} clashes with another field")
            used.add(cname)
            fields.append((cname, col))
    dtype = np.dtype([(f, "<" + np.asarray(a).dtype.str[1:]) for f, a in fields])
    table = np.empty(n, dtype=dtype)
    for f, a in fields:
        table[f] = a
    lines = ["ply", "format binary_little_endian 1.0"]
    for c in comments:
        if "\n" in c or "\r" in c:
            raise PlyError(f"{path}: comment: expected a single line, found {c!r}")
        lines.append(f"comment {c}")
    lines.append(f"element vertex {n}")
    lines += [f"property {_NP_TO_PLY[dtype.fields[f][0].str[1:]]} {f}" for f, _ in fields]
    lines.append("end_header")
    with atomic_write(path, "wb") as fh:
        fh.write(("\n".join(lines) + "\n").encode("ascii"))
        fh.write(table.tobytes())
    return Path(path)
