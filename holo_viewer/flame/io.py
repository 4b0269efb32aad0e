"""Reading and writing FLAME-format model files (chumpy-free).

Two formats hold the same keys (docs/design.md section 4):

* FLAME 2020 / 2023 ``.pkl`` as distributed. FLAME 2020 stores ``shapedirs`` as a
  chumpy ``Ch`` object and ``J_regressor`` as a scipy sparse matrix. We unpickle
  with ``encoding='latin1'`` and a restricted :class:`pickle.Unpickler` that maps
  every ``chumpy.*`` class to a stub capturing the pickled state (a ``Ch`` pickles
  its ``__dict__``, whose ``'x'`` entry is the ndarray); chumpy is never imported.
  Only an exact allow-list of (module, name) pairs resolves (numpy's array
  reconstructors and dtype, the scipy.sparse csc/csr/coo classes, a few builtin
  types); every other reference is refused before anything is imported, so a
  pickle cannot run code, open files or import modules through this loader.
* Our ``.npz`` (no pickled objects) with the same keys plus extra metadata keys.

Required keys and sizes (V vertices, J = 5 joints, K blend shapes, F faces)::

    v_template (V, 3)   shapedirs (V, 3, K)   posedirs (V, 3, 9 (J - 1))
    J_regressor (J, V)  weights (V, J)        kintree_table (2, J)   f (F, 3), 0 <= f < V

Every other key is passed through as metadata.
"""

from __future__ import annotations

import builtins
import collections
import copyreg
import os
import pickle
import zipfile
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from ..errors import FlameError, InputError
from ..fileio import atomic_write
from ..validation import check_array

__all__ = ["REQUIRED_KEYS", "N_JOINTS", "load_flame_arrays", "save_flame_npz", "validate_flame_arrays",
           "ChumpyStub"]

REQUIRED_KEYS = ("v_template", "shapedirs", "posedirs", "J_regressor", "weights", "kintree_table", "f")
N_JOINTS = 5


# --------------------------------------------------------------------------- pickle


class ChumpyStub:
    """Stand-in for any ``chumpy`` class met while unpickling.

    Captures constructor arguments and the pickled state; :meth:`to_array`
    recovers the ndarray a plain ``Ch`` holds.
    """

    chumpy_name = "chumpy.Ch"

    def __new__(cls, *args: Any, **kwargs: Any) -> "ChumpyStub":
        obj = super().__new__(cls)
        obj._args = args
        obj._state = None
        return obj

    def __init__(self, *args: Any, **kwargs: Any) -> None:  # state arrives via __setstate__
        pass

    def __setstate__(self, state: Any) -> None:
        self._state = state

    def to_array(self, key: str, source: str) -> np.ndarray:
        """The ndarray held by the pickled object (its ``x`` term, or its only array)."""
        state = self._state
        if isinstance(state, tuple) and len(state) == 2 and isinstance(state[0], dict):
            state = state[0]  # (dict, slotstate)
        if isinstance(state, dict):
            if "x" in state:
                return _plain_array(state["x"], key, source)
            arrays = [v for v in state.values() if isinstance(v, (np.ndarray, ChumpyStub))]
            if len(arrays) == 1:
                return _plain_array(arrays[0], key, source)
        elif isinstance(state, (np.ndarray, ChumpyStub)):
            return _plain_array(state, key, source)
        if len(self._args) == 1 and isinstance(self._args[0], np.ndarray):
            return np.asarray(self._args[0])
        raise FlameError(f"{source}: {key}: a pickled {self.chumpy_name} object without a stored array "
                         f"(expected a plain chumpy Ch holding an ndarray in its 'x' term)")


def _plain_array(value: Any, key: str, source: str) -> np.ndarray:
    if isinstance(value, ChumpyStub):
        return value.to_array(key, source)
    return np.asarray(value)


def _numpy_core() -> Any:
    """numpy's core package (``numpy._core`` in numpy 2, ``numpy.core`` in 1.x); already imported."""
    core = getattr(np, "_core", None)
    return core if core is not None else np.core


def _latin1_encode(text: Any, encoding: str = "latin1", errors: str = "strict") -> bytes:
    """``_codecs.encode`` as protocol 0-2 pickles use it for ``bytes``: latin-1 only.

    Any other codec is refused: a codec lookup imports ``encodings.<name>`` modules.
    """
    if not isinstance(text, str) or encoding.lower().replace("_", "-") not in ("latin1", "latin-1", "iso-8859-1"):
        raise pickle.UnpicklingError(f"_codecs.encode with {encoding!r}: a FLAME pickle encodes bytes as latin1")
    return text.encode("latin1", errors)


_NUMPY_CORE = {  # name -> resolver (the object lives in numpy's core, already imported with numpy)
    "_reconstruct": lambda: _numpy_core().multiarray._reconstruct,
    "scalar": lambda: _numpy_core().multiarray.scalar,
    "_frombuffer": lambda: _numpy_core().numeric._frombuffer,
}
_SPARSE_CLASSES = {"csc": ("csc_matrix", "csc_array"), "csr": ("csr_matrix", "csr_array"),
                   "coo": ("coo_matrix", "coo_array")}
_BUILTINS = ("object", "set", "frozenset", "list", "dict", "tuple", "int", "float", "complex", "bool", "str",
             "bytes", "bytearray", "slice")


def _sparse_class(name: str) -> Any:
    import scipy.sparse  # the only module this loader may import (a listed pair asks for it)

    return getattr(scipy.sparse, name)


def _allowed_globals() -> dict[tuple[str, str], Any]:
    """The exact (module, name) pairs a FLAME 2020/2023 pickle may reference -> resolver.

    Written by Python 2 or 3, numpy 1.x or 2.x, scipy old (``scipy.sparse.csc``) or new
    (``scipy.sparse._csc``), pickle protocols 0 to 5. Nothing else resolves.
    """
    table: dict[tuple[str, str], Any] = {}
    for core in ("numpy.core", "numpy._core"):
        table[(f"{core}.multiarray", "_reconstruct")] = _NUMPY_CORE["_reconstruct"]
        table[(f"{core}.multiarray", "scalar")] = _NUMPY_CORE["scalar"]
        table[(f"{core}.numeric", "_frombuffer")] = _NUMPY_CORE["_frombuffer"]
    table[("numpy", "ndarray")] = lambda: np.ndarray
    table[("numpy", "dtype")] = lambda: np.dtype
    for fmt, names in _SPARSE_CLASSES.items():
        for name in names:
            for module in ("scipy.sparse", f"scipy.sparse.{fmt}", f"scipy.sparse._{fmt}"):
                table[(module, name)] = lambda name=name: _sparse_class(name)
    for module in ("builtins", "__builtin__"):
        for name in _BUILTINS:
            table[(module, name)] = lambda name=name: getattr(builtins, name)
    for module in ("copyreg", "copy_reg"):
        table[(module, "_reconstructor")] = lambda: copyreg._reconstructor
    table[("_codecs", "encode")] = lambda: _latin1_encode
    table[("collections", "OrderedDict")] = lambda: collections.OrderedDict
    return table


_ALLOWED = _allowed_globals()


class _FlameUnpickler(pickle.Unpickler):
    """Unpickler resolving only an exact allow-list of (module, name) pairs.

    ``chumpy.*`` classes become :class:`ChumpyStub` subclasses; every other pair must be
    in ``_ALLOWED`` (numpy's array and scalar reconstructors and ``dtype``, the
    scipy.sparse csc/csr/coo classes, ``copyreg._reconstructor``, latin-1 ``_codecs.encode``,
    ``OrderedDict`` and a few builtin types). The pair is checked before anything is
    imported, so a pickle can neither run code, open files, nor import a module with
    side effects.
    """

    def __init__(self, fh: Any, source: str) -> None:
        super().__init__(fh, encoding="latin1")
        self._source = source

    def find_class(self, module: str, name: str) -> Any:
        if module == "chumpy" or module.startswith("chumpy."):
            if not name.isidentifier():
                raise FlameError(f"{self._source}: the pickle references a chumpy class named {name!r}; refusing "
                                 f"to load it")
            return type(name, (ChumpyStub,), {"chumpy_name": f"{module}.{name}"})
        resolve = _ALLOWED.get((module, name))
        if resolve is None:
            raise FlameError(f"{self._source}: the pickle references {module}.{name}; a FLAME model file holds "
                             f"only numpy arrays, scipy sparse matrices and chumpy arrays, refusing to load it")
        return resolve()

    def persistent_load(self, pid: Any) -> Any:
        raise FlameError(f"{self._source}: the pickle uses persistent ids; a FLAME model file has none, "
                         f"refusing to load it")


def _load_pkl(path: Path) -> dict[str, Any]:
    source = str(path)
    try:
        with open(path, "rb") as fh:
            data = _FlameUnpickler(fh, source).load()
    except FlameError:
        raise
    except FileNotFoundError as exc:
        raise FlameError(f"{source}: file not found") from exc
    except IsADirectoryError as exc:
        raise FlameError(f"{source}: expected a FLAME .pkl or .npz file, found a directory") from exc
    except (pickle.UnpicklingError, EOFError, ValueError, TypeError, AttributeError, IndexError, KeyError,
            ImportError, MemoryError, UnicodeDecodeError, OSError) as exc:
        raise FlameError(f"{source}: not a readable FLAME pickle ({type(exc).__name__}: {exc})") from exc
    if not isinstance(data, dict):
        raise FlameError(f"{source}: expected a pickled dict of FLAME arrays, found {type(data).__name__}")
    out: dict[str, Any] = {}
    for key, value in data.items():
        key = key.decode("latin1") if isinstance(key, bytes) else str(key)
        if isinstance(value, ChumpyStub):
            value = value.to_array(key, source)
        out[key] = value
    return out


def _load_npz(path: Path) -> dict[str, Any]:
    source = str(path)
    try:
        with np.load(path, allow_pickle=False) as npz:
            return {k: npz[k] for k in npz.files}
    except FileNotFoundError as exc:
        raise FlameError(f"{source}: file not found") from exc
    except IsADirectoryError as exc:
        raise FlameError(f"{source}: expected a FLAME .pkl or .npz file, found a directory") from exc
    except (zipfile.BadZipFile, ValueError, OSError, EOFError, KeyError) as exc:
        raise FlameError(f"{source}: not a readable .npz file ({type(exc).__name__}: {exc})") from exc


def load_flame_arrays(path: str | os.PathLike) -> dict[str, Any]:
    """Read a FLAME-format model file and validate it.

    Parameters
    ----------
    path : str or os.PathLike
        FLAME 2020/2023 ``.pkl`` or our ``.npz``. Files with another suffix are
        recognised by content (a zip archive is read as ``.npz``, anything else as a pickle).

    Returns
    -------
    dict
        The required keys (see module docstring) as numpy arrays (``J_regressor``
        dense float64, ``kintree_table`` and ``f`` int64) plus every extra key
        (numpy arrays where possible).

    Raises
    ------
    FlameError
        Missing file, unreadable or corrupt file, missing keys, inconsistent sizes,
        non-finite values or face indices out of range; the message names the file
        and key, the expected and the found.
    """
    p = Path(path)
    if not p.exists():
        raise FlameError(f"{p}: file not found (expected a FLAME .pkl or a holo_viewer .npz model)")
    suffix = p.suffix.lower()
    if suffix == ".npz":
        data = _load_npz(p)
    elif suffix in (".pkl", ".pickle"):
        data = _load_pkl(p)
    else:
        try:
            is_zip = zipfile.is_zipfile(p)
        except OSError as exc:
            raise FlameError(f"{p}: cannot read ({exc})") from exc
        data = _load_npz(p) if is_zip else _load_pkl(p)
    return validate_flame_arrays(data, source=str(p))


# --------------------------------------------------------------------------- validation


def _dense(value: Any) -> np.ndarray:
    if hasattr(value, "toarray") and callable(value.toarray):  # scipy sparse matrix / array
        return np.asarray(value.toarray())
    if isinstance(value, ChumpyStub):
        return value.to_array("J_regressor", "<arrays>")
    return np.asarray(value)


def _check(value: Any, key: str, shape: tuple, sizes: dict[str, int], source: str,
           kind: str = "float") -> np.ndarray:
    """check_array for file data: FlameError naming the file and key."""
    arr = _dense(value)
    if kind == "float":
        if not (np.issubdtype(arr.dtype, np.floating) or np.issubdtype(arr.dtype, np.integer)):
            raise FlameError(f"{source}: {key}: expected a real-valued array of shape "
                             f"{_fmt(shape)}, found dtype {arr.dtype}")
        arr = arr.astype(np.float64)
    else:
        if np.issubdtype(arr.dtype, np.floating):
            if not np.all(np.isfinite(arr)) or np.any(arr != np.round(arr)):
                raise FlameError(f"{source}: {key}: expected integer indices, found non-integer values")
        elif not np.issubdtype(arr.dtype, np.integer):
            raise FlameError(f"{source}: {key}: expected an integer array, found dtype {arr.dtype}")
        arr = arr.astype(np.int64)
    # Only the named sizes this key uses go into the message.
    bound = {k: sizes[k] for k in shape if isinstance(k, str) and k in sizes}
    try:
        check_array(arr, key, shape, sizes=bound, finite=True)
    except InputError as exc:
        raise FlameError(f"{source}: {exc}") from exc
    sizes.update(bound)
    return arr


def _fmt(shape: tuple) -> str:
    return "(" + ", ".join(str(s) for s in shape) + ")"


def validate_flame_arrays(arrays: Mapping[str, Any], source: str = "<arrays>") -> dict[str, Any]:
    """Check keys, sizes and values of FLAME-format arrays and normalise their types.

    Parameters
    ----------
    arrays : mapping
        Key -> array (numpy, scipy sparse for ``J_regressor``, or a chumpy stub).
    source : str
        Name used in error messages (usually the file path).

    Returns
    -------
    dict
        Required keys as float64 / int64 numpy arrays (``J_regressor`` dense,
        ``kintree_table[0, 0]`` set to -1), extras passed through (``np.asarray``
        where possible).

    Raises
    ------
    FlameError
        Naming the key, the expected and the found.
    """
    if not isinstance(arrays, Mapping):
        raise FlameError(f"{source}: expected a mapping of FLAME arrays, found {type(arrays).__name__}")
    missing = [k for k in REQUIRED_KEYS if k not in arrays]
    if missing:
        raise FlameError(f"{source}: missing key{'s' if len(missing) > 1 else ''} "
                         f"{', '.join(repr(k) for k in missing)} (a FLAME model needs {', '.join(REQUIRED_KEYS)}; "
                         f"found keys {sorted(arrays)})")
    sizes: dict[str, int] = {}
    n_j, n_p = N_JOINTS, 9 * (N_JOINTS - 1)
    out: dict[str, Any] = {}
    out["v_template"] = _check(arrays["v_template"], "v_template", ("V", 3), sizes, source)
    out["shapedirs"] = _check(arrays["shapedirs"], "shapedirs", ("V", 3, "K"), sizes, source)
    out["posedirs"] = _check(arrays["posedirs"], "posedirs", ("V", 3, n_p), sizes, source)
    out["J_regressor"] = _check(arrays["J_regressor"], "J_regressor", (n_j, "V"), sizes, source)
    out["weights"] = _check(arrays["weights"], "weights", ("V", n_j), sizes, source)
    kin = _dense(arrays["kintree_table"])
    if np.issubdtype(kin.dtype, np.unsignedinteger):
        kin = kin.astype(np.int64)  # FLAME stores the root's parent as 2**32 - 1
        kin[kin > np.iinfo(np.int32).max] = -1
    out["kintree_table"] = _check(kin, "kintree_table", (2, n_j), sizes, source, kind="int")
    out["kintree_table"][0, 0] = -1
    parents = out["kintree_table"][0]
    for k in range(1, N_JOINTS):
        if not 0 <= parents[k] < k:
            raise FlameError(f"{source}: kintree_table: expected parent of joint {k} in [0, {k}), "
                             f"found {parents[k]} (parents {parents.tolist()})")
    f = _check(arrays["f"], "f", ("F", 3), sizes, source, kind="int")
    n_v = sizes["V"]
    if f.size and (f.min() < 0 or f.max() >= n_v):
        bad = int(f.max()) if f.max() >= n_v else int(f.min())
        raise FlameError(f"{source}: f: expected vertex indices in [0, {n_v}), found {bad}")
    out["f"] = f
    for key, value in arrays.items():
        if key in out:
            continue
        try:
            out[key] = _dense(value)
        except Exception:  # noqa: BLE001 - odd extras are passed through unchanged
            out[key] = value
    return out


# --------------------------------------------------------------------------- npz writer


def save_flame_npz(path: str | os.PathLike, arrays: Mapping[str, Any]) -> Path:
    """Validate FLAME-format arrays and write them as an ``.npz`` atomically.

    Parameters
    ----------
    path : str or os.PathLike
        Target file (conventionally ``*.npz``).
    arrays : mapping
        Required keys plus extras (numpy arrays, numbers or strings; no Python objects).

    Returns
    -------
    pathlib.Path
        The written path.

    Raises
    ------
    FlameError
        Invalid arrays, or an extra key that cannot be stored without pickling.
    """
    data = validate_flame_arrays(arrays, source=str(path))
    out: dict[str, np.ndarray] = {}
    for key, value in data.items():
        arr = np.asarray(value)
        if arr.dtype == object:
            raise FlameError(f"{path}: {key}: expected a numeric or string array, found Python objects "
                             f"({type(value).__name__}); an .npz model stores no pickled objects")
        out[key] = arr
    target = Path(path)
    with atomic_write(target) as fh:
        np.savez(fh, **out)
    return target
